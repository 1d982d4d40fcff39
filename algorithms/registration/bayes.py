"""Localization with a prior: the maximum a posteriori pose from laser points and a belief.

Where the points alone fix the pose only weakly in some direction (the first lines of an
active scan), least squares wanders along it and can settle in a wrong minimum that fits the
points as well as the true pose. A fixture places the part within a known scatter of its
nominal pose; that belief, ``T = T_prior exp(xi)`` with ``xi ~ N(0, P^-1)`` (twist
``[omega, v]`` in the workpiece frame, as in :mod:`algorithms.registration.uncertainty`),
is information too.

A laser displacement sensor's error is not only white noise. Its linearity error is a
systematic curve of the reading ``d``: the same offset along the beam for every point read
at the same distance, whichever line it is on. Ignoring it makes the Cramer-Rao bound of the
points far too optimistic: the curve does not average out over the points read at one
distance. So the points are grouped by reading (the caller bins ``d``), each group ``g``
carries an unknown offset ``b_g ~ N(0, bias_sigma^2)`` along each point's own beam ``u_i``,
estimated with the pose (the sensor's curve calibrated in passing); and with
``incidence_noise`` a point's noise grows as ``sigma / cos(theta)`` with its angle of
incidence. The objective:

    sum_i r_i^2 / sigma_i^2  +  xi^T P xi  +  sum_g b_g^2 / bias_sigma^2,
    r_i = n_i . (T^-1 (y_i - b_g(i) u_i) - f_i)

(point-to-plane residuals at the closest points ``f_i`` with normals ``n_i``). It is
minimised by damped Gauss-Newton (Levenberg-Marquardt: a step is taken only if it lowers the
objective, else the damping grows: undamped, the first steps from a few weakly constraining
points can propose a large rotation), the biases eliminated by their Schur complement. The
posterior covariance of the pose is the inverse of that complement: where the points say
nothing it is the prior's, where they fix the pose it is their Cramer-Rao bound with the
biases unknown.

Outliers are cut by the two-stage ``"mad"`` rule of :mod:`algorithms.registration.robust`:
until the iteration first converges only points beyond ``max(8 MAD-sigmas, 1 % of the
model's size)`` go (systematic misfit far from the minimum is not noise; cutting it early
traps the fit in minima that shed the points they cannot fit), then
``max(5 MAD-sigmas, FLOOR_SIGMAS sigma)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from algorithms.arraytypes import ArrayLike, BoolArray, FloatArray, IntArray, Pose
from algorithms.errors import AlgorithmError
from algorithms.geometry.edges import SharpEdges
from algorithms.geometry.mesh_index import MeshIndex, NearFaces
from algorithms.geometry.se3 import as_pose, exp_se3, inv_pose, log_se3
from algorithms.registration.robust import OUTLIER_COARSE_FLOOR_REL, OUTLIER_K_COARSE, inlier_mask

__all__ = ["MapResult", "localize_map", "normalized_innovations"]

#: Stop when an update moves the pose by less than this many posterior standard deviations
#: (``sqrt(delta^T S delta)``, S the posterior information).
STEP_TOL_SIGMAS = 1e-4
MAX_ITERATIONS = 50
#: The outlier cut never goes below this many sigmas.
FLOOR_SIGMAS = 4.0
#: A point farther than this from its closest face's plane, sideways, lies beyond an edge [m].
OFF_FACE_M = 1e-7
#: The truncation of the objective reported for comparing starts [sigmas].
OBJECTIVE_CUT_SIGMAS = 5.0
#: Levenberg-Marquardt damping (relative to the diagonal of the normal matrix): start, give up.
LM_LAMBDA0 = 1e-9
LM_LAMBDA_MAX = 1e9
#: Smallest cosine of incidence used to scale the noise (a grazing point weighs ~nothing).
MIN_COS_INCIDENCE = 1e-3

#: Points (biases removed, workpiece frame), normals, residuals [m], dr/db and weights [m^-2].
_Residuals = tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]


@dataclass(frozen=True)
class MapResult:
    """The maximum a posteriori pose.

    Attributes:
        T_world_workpiece: (4, 4) the estimate.
        covariance: (6, 6) posterior covariance of the twist ``[omega, v]`` (workpiece frame).
        information: (6, 6) the points' information at the estimate, the biases marginalised
            (posterior information minus the prior).
        biases_m: (K,) estimated bias of each group along its beam [m].
        converged: the last update was below ``STEP_TOL_SIGMAS`` posterior sigmas (or no
            update lowered the objective).
        iterations: Gauss-Newton updates made.
        rmse_m: RMS point-to-plane residual of the inliers [m] (biases removed).
        inliers: (N,) bool over the input rows.
        near_edge: (N,) bool, the rows left out for lying near a sharp edge (``edge_band_m``).
        prior_mahalanobis: ``sqrt(xi^T P xi)`` of the estimate from the prior mean (4.74 is
            the 99.9 % bound of 6 DOF).
        objective: the objective at the estimate with every residual truncated at
            ``OBJECTIVE_CUT_SIGMAS`` sigmas (the same cut for every start, so the results of
            several starts compare: a wrong minimum that sheds points pays for them).
    """

    T_world_workpiece: Pose
    covariance: FloatArray
    information: FloatArray
    biases_m: FloatArray
    converged: bool
    iterations: int
    rmse_m: float
    inliers: BoolArray = field(repr=False)
    near_edge: BoolArray = field(repr=False)
    prior_mahalanobis: float
    objective: float


@dataclass(frozen=True)
class _Problem:
    Y: FloatArray            # (N, 3) finite points [m], world
    groups: IntArray         # (N,) bias group of each point
    beams: FloatArray        # (N, 3) unit beam direction of each point, world
    n_groups: int
    index: MeshIndex
    T_prior_inv: Pose        # T_workpiece_world of the prior mean
    P: FloatArray            # (6, 6) prior information
    sigma_m: float
    bias_sigma_m: float
    incidence_noise: bool
    offset_m: float = 0.0
    # each point's nearest faces, kept between the queries of one fit (MeshIndex.query_near)
    near: list[NearFaces | None] = field(default_factory=lambda: [None])
    # the residuals of the last (T, b) asked for: an accepted trial step is linearised next
    last: dict[str, Any] = field(default_factory=dict)
    # (N,) points the fit may use (False: near a sharp edge at the start, see localize_map)
    usable: BoolArray = field(default_factory=lambda: np.ones(0, dtype=bool))


def localize_map(points: ArrayLike, index: MeshIndex, T_prior: ArrayLike, prior_information: ArrayLike,
                 sigma_m: float, init: ArrayLike | None = None, groups: ArrayLike | None = None,
                 beams: ArrayLike | None = None, bias_sigma_m: float = 0.0, incidence_noise: bool = False,
                 edges: SharpEdges | None = None, edge_band_m: float = 0.0, offset_m: float = 0.0,
                 max_iterations: int = MAX_ITERATIONS) -> MapResult:
    """The maximum a posteriori ``T_world_workpiece`` (module docstring).

    Args:
        points: (N, 3) [m] measured points, world frame (NaN rows dropped; N may be 0).
        index: the model's :class:`MeshIndex` (workpiece frame).
        T_prior: (4, 4) the prior mean (the nominal pose).
        prior_information: (6, 6) symmetric positive-definite inverse prior covariance.
        sigma_m: the points' noise along the beam at normal incidence [m] (> 0).
        init: (4, 4) start of the iteration (default ``T_prior``).
        groups: (N,) int in [0, K): the bias group of each point (its bin of readings; default
            one group).
        beams: (N, 3) unit beam direction of each point, world frame (needed with
            ``bias_sigma_m > 0`` or ``incidence_noise``).
        bias_sigma_m: prior sigma of each group's offset along the beams [m] (0: no bias).
        incidence_noise: scale each point's sigma by 1 / cos(incidence).
        edges, edge_band_m: points whose closest point at the start pose lies within
            ``edge_band_m`` of a sharp edge of the model are left out of the fit (outliers
            for the whole call): with the pose unsure by that much, their face is unsure.
        offset_m: the points lie this far outside the surface [m] (touch-probe ball centres:
            the effective ball radius); the residual is ``n . (T^-1 y - f) - offset_m``, with
            ``n`` along ``T^-1 y - f`` where the closest point ``f`` is on an edge or a vertex.
        max_iterations: cap on Gauss-Newton updates (>= 1).

    Raises:
        AlgorithmError: a bad shape or value (the message says which and what is allowed).
    """
    if not (np.isfinite(offset_m) and offset_m >= 0):
        raise AlgorithmError(f"offset_m must be a finite number >= 0, got {offset_m!r}")
    prob, rows = _check(points, index, T_prior, prior_information, sigma_m, groups, beams, bias_sigma_m,
                        incidence_noise, offset_m)
    if int(max_iterations) < 1:
        raise AlgorithmError(f"max_iterations must be >= 1, got {max_iterations}")
    T = inv_pose(prob.T_prior_inv) if init is None else as_pose(init, name="init")
    if edges is not None and edge_band_m > 0 and len(prob.Y):
        M, _, _, _, _ = _compute_residuals(prob, T, np.zeros(prob.n_groups))
        cp = index.query(M)
        prob.usable[:] = edges.distance(cp.foot) > edge_band_m
    b = np.zeros(prob.n_groups)
    converged = False
    iterations = 0
    lam = LM_LAMBDA0
    coarse = True
    while iterations < int(max_iterations) and not converged:
        iterations += 1
        lin = _linearise(prob, T, b, coarse)
        while True:
            dxi, db = lin.step(lam)
            T_try, b_try = T @ exp_se3(dxi), b + db
            if dxi @ lin.schur() @ dxi < STEP_TOL_SIGMAS**2:
                T, b, converged = T_try, b_try, True
                break
            if _objective(prob, T_try, b_try, lin.cut) < lin.cost:
                T, b = T_try, b_try
                lam = max(lam / 10, LM_LAMBDA0)
                break
            lam *= 10
            if lam > LM_LAMBDA_MAX:
                converged = True   # no step lowers the objective: a minimum at this precision
                break
        if converged and coarse:
            coarse, converged, lam = False, False, LM_LAMBDA0
    lin = _linearise(prob, T, b, False)
    S = lin.schur()
    covariance = np.linalg.inv(S)
    xi = log_se3(prob.T_prior_inv @ T)
    inliers = np.zeros(len(np.asarray(points, dtype=np.float64).reshape(-1, 3)), dtype=bool)
    inliers[rows[lin.mask]] = True
    near_edge = np.zeros(len(inliers), dtype=bool)
    near_edge[rows[~prob.usable]] = True
    r = lin.r[lin.mask]
    return MapResult(T, 0.5 * (covariance + covariance.T), S - prob.P, b, converged, iterations,
                     float(np.sqrt(np.mean(r**2))) if len(r) else 0.0, inliers, near_edge,
                     float(np.sqrt(xi @ prob.P @ xi)),
                     _objective(prob, T, b, OBJECTIVE_CUT_SIGMAS * prob.sigma_m))


def _check(points: ArrayLike, index: MeshIndex, T_prior: ArrayLike, prior_information: ArrayLike, sigma_m: float,
           groups: ArrayLike | None, beams: ArrayLike | None, bias_sigma_m: float, incidence_noise: bool,
           offset_m: float) -> tuple[_Problem, IntArray]:
    Y = np.asarray(points, dtype=np.float64)
    if Y.size == 0:
        Y = Y.reshape(0, 3)
    if Y.ndim != 2 or Y.shape[1] != 3:
        raise AlgorithmError(f"points must be (N, 3), got {Y.shape}")
    T_prior = as_pose(T_prior, name="T_prior")
    P = np.asarray(prior_information, dtype=np.float64)
    if P.shape != (6, 6) or not np.all(np.isfinite(P)) or not np.allclose(P, P.T) or np.linalg.eigvalsh(P)[0] <= 0:
        raise AlgorithmError("prior_information must be a symmetric positive-definite (6, 6) matrix")
    if not (np.isfinite(sigma_m) and sigma_m > 0):
        raise AlgorithmError(f"sigma_m must be a finite number > 0, got {sigma_m!r}")
    if not (np.isfinite(bias_sigma_m) and bias_sigma_m >= 0):
        raise AlgorithmError(f"bias_sigma_m must be a finite number >= 0, got {bias_sigma_m!r}")
    g = np.zeros(len(Y), dtype=np.int64) if groups is None else np.asarray(groups)
    if g.shape != (len(Y),) or not np.issubdtype(g.dtype, np.integer) or (len(g) and g.min() < 0):
        raise AlgorithmError(f"groups must be (N,) = ({len(Y)},) integers >= 0, got shape {g.shape}")
    k = int(g.max()) + 1 if len(g) else 1
    if beams is None:
        if bias_sigma_m > 0 or incidence_noise:
            raise AlgorithmError("beams (N, 3) are needed with bias_sigma_m > 0 or incidence_noise")
        U = np.zeros((len(Y), 3))
    else:
        U = np.asarray(beams, dtype=np.float64)
        if U.shape != (len(Y), 3) or not np.allclose(np.linalg.norm(U, axis=1), 1.0):
            raise AlgorithmError(f"beams must be (N, 3) = ({len(Y)}, 3) unit vectors, one per point, got {U.shape}")
    rows = np.flatnonzero(np.all(np.isfinite(Y), axis=1))
    return _Problem(Y[rows], g[rows], U[rows], k, index, inv_pose(T_prior), P, float(sigma_m),
                    float(bias_sigma_m), bool(incidence_noise), float(offset_m),
                    usable=np.ones(len(rows), dtype=bool)), rows


class _Linear:
    """The problem linearised at (T, b): residuals, Jacobians, weights, the inlier set."""

    def __init__(self, prob: _Problem, T: Pose, b: FloatArray, M: FloatArray, n: FloatArray, r: FloatArray,
                 c: FloatArray, w: FloatArray, mask: BoolArray, cut: float, xi: FloatArray) -> None:
        self.prob, self.T, self.b = prob, T, b
        self.r, self.mask, self.cut = r, mask, cut
        m, nn = M[mask], n[mask]
        self.J = -np.hstack([np.cross(m, nn), nn])          # dr/dxi
        self.c = c[mask]                                     # dr/db of its group
        self.w = w[mask]
        self.g = prob.groups[mask]
        self.ri = r[mask]
        self.xi = xi
        k = prob.n_groups
        wJ = self.w[:, None] * self.J
        self.A = wJ.T @ self.J + prob.P
        self.grad = wJ.T @ self.ri + prob.P @ xi
        if prob.bias_sigma_m > 0:
            self.Hxb = np.zeros((6, k))
            np.add.at(self.Hxb.T, self.g, wJ * self.c[:, None])
            self.Hbb = np.bincount(self.g, self.w * self.c**2, k) + prob.bias_sigma_m**-2
            self.gb = np.bincount(self.g, self.w * self.c * self.ri, k) + b / prob.bias_sigma_m**2
        self.cost = float(np.sum(self.w * self.ri**2)) + float(np.sum(w[~mask])) * cut**2 + float(xi @ prob.P @ xi) \
            + (float(b @ b) / prob.bias_sigma_m**2 if prob.bias_sigma_m > 0 else 0.0)

    def schur(self, lam: float = 0.0) -> FloatArray:
        """The pose block of the normal matrix with the biases eliminated (damped by ``lam``)."""
        S = self.A.copy()
        if self.prob.bias_sigma_m > 0:
            S -= (self.Hxb / self.Hbb) @ self.Hxb.T
        return S + lam * np.diag(np.diag(S))

    def step(self, lam: float) -> tuple[np.ndarray, np.ndarray]:
        """The damped update (pose twist, group biases [m]) from the current linearisation."""
        S = self.schur(lam)
        if self.prob.bias_sigma_m > 0:
            rhs = self.grad - self.Hxb @ (self.gb / self.Hbb)
            dxi = -np.linalg.solve(S, rhs)
            db = -(self.gb + self.Hxb.T @ dxi) / (self.Hbb * (1 + lam))
            return dxi, db
        return -np.linalg.solve(S, self.grad), np.zeros_like(self.b)


def _residuals(prob: _Problem, T: Pose, b: FloatArray) -> _Residuals:
    """Points (biases removed) in the workpiece frame, normals, residuals, dr/db and weights."""
    key = (T.tobytes(), b.tobytes())
    if prob.last.get("key") != key:
        prob.last["key"] = key
        prob.last["value"] = _compute_residuals(prob, T, b)
    return prob.last["value"]


def _compute_residuals(prob: _Problem, T: Pose, b: FloatArray) -> _Residuals:
    T_inv = inv_pose(T)
    U = prob.beams
    M = (prob.Y - b[prob.groups][:, None] * U) @ T_inv[:3, :3].T + T_inv[:3, 3]
    cp, prob.near[0] = prob.index.query_near(M, prob.near[0])
    n, r, fits = _offset_residuals(M - cp.foot, cp.normal, prob.offset_m)
    # a surface point whose closest point is on a face's boundary (beyond an edge) has no
    # tangent plane: it counts as an outlier (the objective charges it the cut; it adds no
    # information)
    r = np.where(fits & prob.usable, r, np.inf)
    u_wp = U @ T_inv[:3, :3].T
    c = -np.einsum("ij,ij->i", n, u_wp)
    sigma = prob.sigma_m / np.maximum(np.abs(c), MIN_COS_INCIDENCE) if prob.incidence_noise \
        else np.full(len(M), prob.sigma_m)
    return M, n, r, c, sigma**-2


def _offset_residuals(e: FloatArray, face_normal: FloatArray,
                      offset_m: float) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Signed distances of points to the surface offset by ``offset_m``, from their offsets
    ``e`` to their closest points on the model and those points' face normals: (normals, residuals
    [m], usable). With no offset a point must lie over its face (``OFF_FACE_M``); with one (ball
    centres) a closest point on an edge or a vertex is where the ball touches a convex edge of
    the tessellation, and the distance to it along ``e`` is the exact residual."""
    r = np.einsum("ij,ij->i", e, face_normal)
    on_face = np.einsum("ij,ij->i", e, e) - r * r <= OFF_FACE_M**2
    if offset_m == 0:
        return face_normal, r, on_face
    dist = np.linalg.norm(e, axis=1)
    beyond = ~on_face & (dist > 0)
    n = np.where(beyond[:, None], e / np.where(dist > 0, dist, 1.0)[:, None], face_normal)
    return n, np.where(beyond, dist, r) - offset_m, np.ones(len(e), dtype=bool)


def _linearise(prob: _Problem, T: Pose, b: FloatArray, coarse: bool) -> _Linear:
    xi = log_se3(prob.T_prior_inv @ T)
    if len(prob.Y) == 0:
        z = np.zeros((0, 3))
        return _Linear(prob, T, b, z, z, np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0, dtype=bool), 0.0, xi)
    M, n, r, c, w = _residuals(prob, T, b)
    d = np.abs(r)
    finite = np.isfinite(d)
    d = np.where(finite, d, np.max(d[finite], initial=0.0) * 10 + 1.0)
    if coarse:
        mask = inlier_mask(d, "mad", max(OUTLIER_COARSE_FLOOR_REL * prob.index.extent, FLOOR_SIGMAS * prob.sigma_m),
                           OUTLIER_K_COARSE)
    else:
        mask = inlier_mask(d, "mad", FLOOR_SIGMAS * prob.sigma_m)
    if isinstance(mask, slice):
        mask = np.ones(len(M), dtype=bool)
    mask = mask & finite
    cut = float(d[mask].max()) if mask.any() else FLOOR_SIGMAS * prob.sigma_m
    return _Linear(prob, T, b, M, n, r, c, w, mask, cut, xi)


def _objective(prob: _Problem, T: Pose, b: FloatArray, cut: float) -> float:
    """The objective at (T, b) with each residual truncated at ``cut`` [m]."""
    xi = log_se3(prob.T_prior_inv @ T)
    out = float(xi @ prob.P @ xi)
    if prob.bias_sigma_m > 0:
        out += float(b @ b) / prob.bias_sigma_m**2
    if len(prob.Y) == 0:
        return out
    _, _, r, _, w = _residuals(prob, T, b)
    return out + float(np.sum(w * np.minimum(r * r, cut * cut)))


def normalized_innovations(points: ArrayLike, beams: ArrayLike, index: MeshIndex, T_world_workpiece: ArrayLike,
                           covariance: ArrayLike, sigma_m: float, bias_sigma_m: float = 0.0,
                           incidence_noise: bool = False, offset_m: float = 0.0) -> FloatArray:
    """How well an estimate predicts points it has not seen: each point's point-to-plane
    residual at ``T_world_workpiece`` divided by its predicted spread (noise, the reading's
    unknown linearity offset and the pose's ``covariance`` carried to the point). About 1 in
    RMS when the estimate and its covariance are right; far above when it sits in a wrong
    minimum.

    Args:
        points: (N, 3) [m] world frame; beams: (N, 3) unit beam directions, world frame.
        index: the model's :class:`MeshIndex` (workpiece frame).
        T_world_workpiece: (4, 4) the estimate to test.
        covariance: (6, 6) of the twist ``[omega, v]`` (workpiece frame), e.g.
            :attr:`MapResult.covariance`.
        sigma_m, bias_sigma_m, incidence_noise: as for :func:`localize_map`.
        offset_m: the points lie this far outside the surface [m] (touch-probe ball centres),
            as for :func:`localize_map`: the residual is ``n . (T^-1 y - f) - offset_m``.

    Returns:
        (N,) normalised residuals (dimensionless).

    Raises:
        AlgorithmError: beams that do not match the points, or a negative or non-finite offset.
    """
    if not (np.isfinite(offset_m) and offset_m >= 0):
        raise AlgorithmError(f"offset_m must be a finite number >= 0, got {offset_m!r}")
    Y = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    U = np.asarray(beams, dtype=np.float64).reshape(-1, 3)
    if U.shape != Y.shape:
        raise AlgorithmError(f"beams must match points, (N, 3) each; got {U.shape} and {Y.shape}")
    T_inv = inv_pose(as_pose(T_world_workpiece, name="T_world_workpiece"))
    M = Y @ T_inv[:3, :3].T + T_inv[:3, 3]
    cp = index.query(M)
    n, r, _ = _offset_residuals(M - cp.foot, cp.normal, offset_m)
    cos_inc = np.abs(np.einsum("ij,ij->i", n, U @ T_inv[:3, :3].T))
    sigma = sigma_m / np.maximum(cos_inc, MIN_COS_INCIDENCE) if incidence_noise else np.full(len(Y), sigma_m)
    J = np.hstack([np.cross(M, n), n])
    var = sigma**2 + (bias_sigma_m * cos_inc) ** 2 + np.einsum("ij,jk,ik->i", J, np.asarray(covariance), J)
    return r / np.sqrt(var)

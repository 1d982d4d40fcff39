"""Symmetric localization: document 000's Algorithm 2, symmetry found from the data, and
discrete symmetries (every equally good pose).

Algorithm 2 (document 000, section 4.2). A feature with symmetry subgroup ``G_0`` (see
:mod:`algorithms.registration.symmetric.features`) fixes the pose only on ``SE(3)/G_0``. Its points make the linear
systems of the Tangent and Hong-Tan updates singular (the ``G_0`` directions carry no
information). Algorithm 2 never forms them: with a basis ``eta_1..eta_q`` of the complement
``m_0`` (``q = dim SE(3)/G_0``) it

1. starts from ``g^0`` (``k = 0``), feet ``x_i^0`` = closest points of ``(g^0)^-1 y_i``;
2. ``e_0`` = mean squared point-to-feature distance;
3. ``k = k + 1``: solves the point-to-plane least squares *in m_0 only*:
   ``m = argmin sum_i (s_i - J_i B^T m)^2`` with ``J_i = [y_i x n_i, n_i]`` (model frame),
   ``s_i = <y_i - x_i, n_i>`` and ``B`` the (q, 6) basis; a q x q system of full rank;
4. ``g^k = g^(k-1) exp(m_1 eta_1 + ... + m_q eta_q)`` (halving the step while the residual
   would rise, as Algorithm 1 does);
5. new feet, ``e_k``; stop when ``1 - e_k / e_(k-1) < delta`` or at the numerical floor.

The pose along ``G_0`` is never moved: it stays where the initial pose put it (for a real cell,
the nominal pose), and the result says so: ``free_directions`` (the ``G_0`` basis) and
``fixed_directions`` (the ``m_0`` basis), both in the workpiece frame.

Symmetry from the data (:func:`detect_symmetry`). At the pose found by Algorithm 1 the feet
and the ideal-surface normals give the scaled Fisher information of
:func:`algorithms.registration.uncertainty.observability`; a direction is **free** when its eigenvalue is
below ``DETECTION_TOL`` (1e-4) times the largest, i.e. when the points fix it more than 100
times worse (in standard deviation, over the part's size) than the best-fixed direction.
The free subspace is then matched to a subgroup of document 000's table (plane, cylinder,
sphere, cone, extruded, free-form) by its structure: how many rotations it holds, their
axis, pitch and the translations beside them (tolerances ``MATCH_TOL``). A subspace the
table does not name (a screw, say) is used as it is (``kind = "other"``).

Discrete symmetries (:func:`model_symmetries`). A model that a finite set of rigid motions
maps onto itself (a cube: 24; a square plate with four identical blind holes: 4, with
through holes 8) gives the same
residual at ``T S`` as at ``T`` for every such ``S``: no measurement on the model can tell
them apart. The candidates are the motions about the surface centroid that map the largest
flat-face normal clusters onto clusters of equal area (and the principal-axis flips and
turns); a candidate is accepted when it maps the surface onto itself within
``SYMMETRY_TOL_REL`` of the model's size. :func:`localize_symmetric` reports every distinct
equally good pose in ``solutions`` (distinct modulo ``G_0``: two poses differing by a free
motion are the same solution), the one nearest the initial pose first.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from algorithms.geometry.mesh_index import MeshIndex
from algorithms.errors import AlgorithmError
from algorithms.registration.symmetric.features import (
    FEATURE_TABLE,
    Feature,
    SymmetryGroup,
    check_feature_type,
    other_group,
    symmetry_group,
)
from algorithms.registration.local import OUTLIER_K, OUTLIER_K_COARSE, localize
from algorithms.registration.local import _outlier_config as _outlier_mode
from algorithms.geometry.se3 import as_pose, exp_se3, inv_pose, rotation_error_rad, transform_points
from algorithms.registration.uncertainty import OBSERVABILITY_TOL, Observability, observability

__all__ = [
    "DETECTION_TOL",
    "MATCH_TOL",
    "SYMMETRY_TOL_REL",
    "SymmetricResult",
    "SymmetryDetection",
    "algorithm2",
    "detect_symmetry",
    "model_symmetries",
    "localize_symmetric",
    "SYMMETRIC_CHOICES",
    "pseudo_normals",
]

#: A pose direction is free when its scaled information eigenvalue is below this fraction
#: of the largest (same scale as :data:`algorithms.registration.uncertainty.OBSERVABILITY_TOL`).
DETECTION_TOL = OBSERVABILITY_TOL
#: Matching a free subspace to the table: dimensionless (angles in rad, lengths / L).
MATCH_TOL = 1e-3
#: A motion is a symmetry of the model when it moves no surface sample farther than this
#: fraction of the model's bounding-box diagonal from the surface (generated meshes deviate
#: from their design surfaces by 1e-5 m; real asymmetries move the surface by millimetres).
SYMMETRY_TOL_REL = 5e-4
#: Detection uses only points whose offset from their foot, and the pseudo-normal there, are
#: within 10 degrees of the face normal (points on or beside a sharp edge measure the edge).
EDGE_COS = float(np.cos(np.radians(10.0)))
#: ... and whose foot is farther than this many noise sigmas from a sharp edge of its face.
EDGE_BAND_SIGMA = 4.0
#: Two equally good poses are the same solution when they differ by a motion within this
#: angle [rad] (and this fraction of the model's size) of G_0: the detected G_0 carries the
#: measurement's uncertainty (an axis tilted by 1e-4 rad, say), while distinct discrete
#: symmetries differ by tens of degrees or millimetres.
SAME_SOLUTION_TOL = 1e-2
#: ``symmetric=`` choices besides a feature type.
SYMMETRIC_CHOICES = ("auto", "none")
#: Stopping rule and iteration cap of Algorithm 2.
TOLERANCE = 1e-10
MAX_ITERATIONS = 100
#: RMS below this fraction of the data's size is an exact fit.
FLOOR_REL = 1e-12
OUTLIER_FLOOR_REL = 1e-6
MIN_POINTS = 3


@dataclass(frozen=True)
class SymmetryDetection:
    """Which subgroup the data leave free.

    Attributes:
        group: the matched :class:`SymmetryGroup` (its ``kind`` names the table feature, or
            ``"other"``; ``freeform`` when nothing is free).
        observability: the information analysis it rests on (relative eigenvalues, weak
            directions, tolerance).
        match_error: how far the free subspace is from the matched group's ``g_0``
            (largest principal-angle sine, scaled units); 0 for free-form.
    """

    group: SymmetryGroup
    observability: Observability
    match_error: float


@dataclass(frozen=True)
class SymmetricResult:
    """Result of :func:`algorithm2` and :func:`localize_symmetric`.

    Attributes:
        T_world_workpiece: (4, 4) pose (the solution nearest the initial pose).
        solutions: (K, 4, 4) every distinct equally good pose (K = 1 without a discrete
            symmetry); ``solutions[0]`` is ``T_world_workpiece``.
        solution_rmse_m: (K,) RMS point-to-model distance at each solution [m].
        feature: the table feature whose ``G_0`` was used ("freeform": none), or "other".
        group: the :class:`SymmetryGroup` used.
        free_dofs: dim G_0: pose directions the points cannot fix (0: fully fixed).
        free_directions: (free_dofs, 6) unit twists ``[omega, v]`` (workpiece frame, about
            its origin) spanning ``G_0``; the pose along them stays at the initial pose.
        fixed_directions: (q, 6) unit twists spanning ``m_0``: the directions solved.
        covariance_fixed: (q, q) covariance of the pose coordinates along
            ``fixed_directions`` (``T_true = T_est exp(sum m_j eta_j)``; rad^2, rad m, m^2),
            from the point-to-plane information with ``sigma_m``; None with too few points.
        converged, iterations, status, rmse_m, history: as for Algorithm 1.
        sigma_m: noise sigma along the normals [m] (given, or estimated from residuals).
        general_system_rank: rank of the 6x6 (3x3 planar) matrix of Tangent/Hong-Tan at the
            result (scaled, relative tolerance ``DETECTION_TOL``): below 6 (3) the general
            updates are singular here.
        general_system_condition: its condition number (inf when singular).
        relative_eigenvalues: scaled information eigenvalues / the largest, ascending.
        detection_tol: the tolerance that decided which directions are free.
        algorithm: "2" (Algorithm 2) or "1" (``symmetric="none"``: Algorithm 1 only).
        n_points_used, n_outliers: inliers and rejected finite points at the result.
        inliers: (N,) bool over the input rows.
        time_s: wall time [s].
    """

    T_world_workpiece: np.ndarray
    solutions: np.ndarray
    solution_rmse_m: np.ndarray
    feature: str
    group: SymmetryGroup
    free_dofs: int
    free_directions: np.ndarray
    fixed_directions: np.ndarray
    covariance_fixed: np.ndarray | None
    converged: bool
    iterations: int
    status: str
    rmse_m: float
    history: tuple
    sigma_m: float
    general_system_rank: int
    general_system_condition: float
    relative_eigenvalues: np.ndarray
    detection_tol: float
    algorithm: str
    n_points_used: int
    n_outliers: int
    inliers: np.ndarray = field(repr=False)
    time_s: float = 0.0


# ----------------------------------------------------------------------------- models
class _Model:
    """Closest points on a Feature or a mesh, with normals (N, m, 3)."""

    def __init__(self, model):
        self.feature = None
        self.index = None
        if isinstance(model, Feature):
            self.feature = model
            if model.index is not None:
                self.index = model.index
        elif isinstance(model, MeshIndex):
            self.index = model
        elif hasattr(model, "vertices") and hasattr(model, "faces"):
            self.index = MeshIndex(model)
        else:
            raise AlgorithmError(
                f"model must be a Feature, a triangle mesh or a MeshIndex, got {type(model).__name__}"
            )
        self.planar = bool(self.feature is not None and self.feature.planar)

    def closest(self, Ym):
        """(foot, normals (N, m, 3), distance >= 0, smooth normals (N, m, 3))."""
        if self.feature is not None and self.feature.index is None:
            p = self.feature.closest(Ym)
            return p.foot, p.normals, np.abs(p.distance), p.normals, None
        cp = self.index.query(Ym)
        smooth = self.index.smooth_normals(cp.face, cp.foot)
        return cp.foot, cp.normal[:, None, :], cp.distance, smooth[:, None, :], cp.face


def _rows(Ym, foot, normals):
    """Point-to-plane rows J (N*m, 6) about the origin and residuals s (N*m,)."""
    m = normals.shape[1]
    Y = np.repeat(Ym, m, axis=0)
    F = np.repeat(foot, m, axis=0)
    n = normals.reshape(-1, 3)
    J = np.hstack([np.cross(Y, n), n])
    s = np.einsum("ij,ij->i", Y - F, n)
    return J, s


def _lstsq_scaled(A, b):
    """Least squares with column scaling; returns (x, rank, smallest relative sv)."""
    d = np.linalg.norm(A, axis=0)
    d[d == 0] = 1.0
    x, _, rank, sv = np.linalg.lstsq(A / d, b, rcond=1e-12)
    rel = float(sv[-1] / sv[0]) if len(sv) and sv[0] > 0 else 0.0
    return x / d, int(rank), rel


def _scaled_information(feet, normals, planar: bool):
    """Eigenvalues (ascending, relative) of the scaled information (see uncertainty)."""
    m = normals.shape[1]
    P = np.repeat(feet, m, axis=0)
    n = normals.reshape(-1, 3)
    c = P.mean(axis=0)
    d = P - c
    L = float(np.sqrt(np.mean(np.einsum("ij,ij->i", d, d)))) or 1.0
    H = np.hstack([np.cross(d, n) / L, n])
    if planar:
        H = H[:, [2, 3, 4]]
    w = np.clip(np.linalg.eigvalsh(H.T @ H / len(H)), 0.0, None)
    return w / (w[-1] if w[-1] > 0 else 1.0)


def _inlier_mask(d, mode, floor, k):
    if mode is None:
        return np.ones(len(d), dtype=bool)
    if mode == "mad":
        med = float(np.median(d))
        thr = max(k * 1.4826 * med, floor)
    else:
        thr = float(mode)
    mask = d <= thr
    if mask.sum() < MIN_POINTS:
        mask = d <= np.median(d)
    return mask


def _check_points(points, planar):
    P = np.asarray(points, dtype=np.float64)
    if planar and P.ndim == 2 and P.shape[1] == 2:
        P = np.hstack([P, np.zeros((len(P), 1))])
    if P.ndim != 2 or P.shape[1] != 3:
        raise AlgorithmError(f"points must be (N, 3){' or (N, 2)' if planar else ''}, got {P.shape}")
    finite = np.all(np.isfinite(P), axis=1)
    return P, finite


# ----------------------------------------------------------------------- Algorithm 2
def algorithm2(
    points,
    model,
    group: SymmetryGroup | None = None,
    init=None,
    sigma: float | None = None,
    max_iterations: int = MAX_ITERATIONS,
    tolerance: float = TOLERANCE,
    outlier="mad",
) -> SymmetricResult:
    """Document 000's Algorithm 2: localize on ``SE(3)/G_0``, updating only along ``m_0``.

    Args:
        points: (N, 3) [m] measured points, world frame ((N, 2) for a 2D feature); NaN rows
            are dropped.
        model: a :class:`Feature` (explicit or from mesh faces), a triangle mesh or a
            :class:`MeshIndex`, in the workpiece frame [m].
        group: ``G_0``; default: the feature's own (required for a mesh).
        init: initial ``T_world_workpiece`` (4x4 rigid), default identity. The pose along
            ``G_0`` stays where ``init`` puts it.
        sigma: noise sigma along the normals [m] for ``covariance_fixed`` (estimated when
            None).
        max_iterations: cap on pose updates.
        tolerance: ``delta`` of ``1 - e_k/e_(k-1) < delta``.
        outlier: ``"mad"`` (robust cut: 8 sigma until converged, then 4), a distance [m],
            or None.

    Returns:
        SymmetricResult (``solutions`` holds the one pose; ``algorithm = "2"``).

    Raises:
        AlgorithmError: bad points, model, group, init or options.
    """
    t0 = time.perf_counter()
    mdl = _Model(model)
    if group is None:
        if mdl.feature is None:
            raise AlgorithmError("give the symmetry group G_0 (a SymmetryGroup) for a mesh model")
        group = mdl.feature.group
    if not isinstance(group, SymmetryGroup):
        raise AlgorithmError(f"group must be a SymmetryGroup, got {type(group).__name__}")
    if mdl.feature is not None and mdl.feature.planar != group.planar:
        raise AlgorithmError("a 2D (planar) feature needs a planar group and vice versa")
    P, finite = _check_points(points, group.planar)
    q = group.quotient_dim
    if finite.sum() < max(MIN_POINTS, q):
        raise AlgorithmError(
            f"points must have at least {max(MIN_POINTS, q)} finite rows to fix {q} directions, "
            f"got {int(finite.sum())}"
        )
    if int(max_iterations) < 1:
        raise AlgorithmError(f"max_iterations must be >= 1, got {max_iterations}")
    if not (np.isfinite(tolerance) and tolerance >= 0):
        raise AlgorithmError(f"tolerance must be a finite number >= 0, got {tolerance}")
    if sigma is not None and not (np.isfinite(sigma) and sigma > 0):
        raise AlgorithmError(f"sigma must be a positive length [m] or None, got {sigma}")
    mode = _outlier_mode(outlier)
    T = np.eye(4) if init is None else as_pose(init, name="init")
    if group.planar:
        _check_planar_pose(T)
    rows = np.nonzero(finite)[0]
    Y = P[rows]
    size = float(np.linalg.norm(np.ptp(Y, axis=0))) or 1.0
    floor2 = (FLOOR_REL * size) ** 2
    out_floor = OUTLIER_FLOOR_REL * size
    B = group.m0

    def evaluate(T_):
        Ym_ = transform_points(inv_pose(T_), Y)
        return (Ym_,) + tuple(mdl.closest(Ym_))

    Ym, foot, normals, dist, smooth, _ = evaluate(T)
    k_out = OUTLIER_K_COARSE
    mask = _inlier_mask(dist, mode, out_floor, k_out)

    def mse(d, mk):
        return float(np.mean(d[mk] ** 2))

    e_prev = mse(dist, mask)
    history = [float(np.sqrt(e_prev))]
    converged, status = False, f"not converged: reached max_iterations = {max_iterations}"
    it = 0
    while True:
        while True:
            if e_prev <= floor2:
                converged = True
                status = f"converged: residual at the numerical floor (RMS {np.sqrt(e_prev):.3g} m)"
                break
            if it >= max_iterations:
                converged = False
                status = f"not converged: reached max_iterations = {max_iterations}"
                break
            J, s = _rows(Ym[mask], foot[mask], normals[mask])
            mu, _, _ = _lstsq_scaled(J @ B.T, s)
            xi = B.T @ mu
            cand = evaluate(T @ exp_se3(xi))
            e_new = mse(cand[3], mask)
            halvings = 0
            while e_new > e_prev and halvings < 12:
                # overshoot far from the minimum: halve the motion
                xi = 0.5 * xi
                cand = evaluate(T @ exp_se3(xi))
                e_new = mse(cand[3], mask)
                halvings += 1
            if e_new > e_prev:
                converged = e_new <= e_prev * (1.0 + 1e-6)
                status = ("converged: no further decrease" if converged else
                          "not converged: stalled, no step along m_0 lowers the residual")
                break
            it += 1
            T = T @ exp_se3(xi)
            Ym, foot, normals, dist, smooth, _ = cand
            history.append(float(np.sqrt(e_new)))
            rel = 1.0 - e_new / e_prev if e_prev > 0 else 0.0
            new_mask = _inlier_mask(dist, mode, out_floor, k_out)
            changed = not np.array_equal(new_mask, mask)
            mask = new_mask
            e_prev = mse(dist, mask)
            if not changed and rel < tolerance:
                converged = True
                status = f"converged: relative decrease 1 - e_k/e_(k-1) = {rel:.3g} < delta = {tolerance:g}"
                break
        # converged: tighten the outlier cut once; go on if that changes the inliers
        if converged and mode == "mad" and k_out != OUTLIER_K:
            k_out = OUTLIER_K
            new_mask = _inlier_mask(dist, mode, out_floor, k_out)
            if not np.array_equal(new_mask, mask):
                mask = new_mask
                e_prev = mse(dist, mask)
                converged = False
                continue
        break

    n_used = int(mask.sum())
    J, s = _rows(Ym[mask], foot[mask], normals[mask])
    A = J @ B.T
    dof = max(len(s) - q, 1)
    sigma_used = float(sigma) if sigma is not None else float(np.sqrt(np.sum(s * s) / dof))
    cov = None
    N = A.T @ A
    if q and np.linalg.matrix_rank(N / np.max(np.abs(N)) if np.max(np.abs(N)) > 0 else N) == q:
        cov = np.linalg.inv(N) * sigma_used**2
        cov = 0.5 * (cov + cov.T)
    rel_eig = _scaled_information(foot[mask], smooth[mask], group.planar)
    rank6 = int(np.sum(rel_eig >= DETECTION_TOL))
    cond = float(1.0 / rel_eig[0]) if rel_eig[0] > 0 and rank6 == len(rel_eig) else float("inf")
    deficient = max(0, (len(rel_eig) - rank6) - group.dim)
    if deficient:
        status += (f"; WARNING: the points leave {deficient} direction(s) of m_0 unfixed as well "
                   "(more symmetric than the group given): minimum-norm steps were taken")
    inliers = np.zeros(len(P), dtype=bool)
    inliers[rows[mask]] = True
    rmse = float(np.sqrt(np.mean(dist[mask] ** 2)))
    return SymmetricResult(
        T_world_workpiece=T,
        solutions=T[None].copy(),
        solution_rmse_m=np.array([rmse]),
        feature=group.kind,
        group=group,
        free_dofs=group.dim,
        free_directions=group.g0.copy(),
        fixed_directions=group.m0.copy(),
        covariance_fixed=cov,
        converged=converged,
        iterations=it,
        status=status,
        rmse_m=rmse,
        history=tuple(history),
        sigma_m=sigma_used,
        general_system_rank=rank6,
        general_system_condition=cond,
        relative_eigenvalues=rel_eig,
        detection_tol=DETECTION_TOL,
        algorithm="2",
        n_points_used=n_used,
        n_outliers=int(len(Y) - n_used),
        inliers=inliers,
        time_s=time.perf_counter() - t0,
    )


def _check_planar_pose(T):
    R = T[:3, :3]
    if abs(R[2, 2] - 1.0) > 1e-9 or abs(T[2, 3]) > 1e-12:
        raise AlgorithmError("a 2D feature needs a planar init (rotation about z, no z translation)")


# ---------------------------------------------------------------- symmetry detection
def detect_symmetry(feet, normals, tol: float = DETECTION_TOL) -> SymmetryDetection:
    """Find the subgroup ``G_0`` that measured points leave free, and match it to the table.

    Args:
        feet: (N, 3) [m] the points' feet on the model (workpiece frame), at a fitted pose.
        normals: (N, 3) unit normals of the ideal surface there (smooth normals on a mesh,
            :meth:`MeshIndex.smooth_normals`; facet normals would fake information).
        tol: relative eigenvalue below which a direction is free (``DETECTION_TOL``).

    Returns:
        SymmetryDetection.
    """
    obs = observability(feet, normals, tol)
    W = obs.weak_directions
    c0 = obs.centroid
    L = obs.characteristic_length_m
    k = len(W)
    if k == 0:
        return SymmetryDetection(symmetry_group("freeform", c0), obs, 0.0)
    # scaled twists about the centroid: [L omega, v_c]; rows orthonormal
    S = np.hstack([W[:, :3] * L, W[:, 3:] + np.cross(W[:, :3], c0)])
    S, _ = np.linalg.qr(S.T)
    S = S.T
    group = _match(S, c0, L, k)
    if group is None:
        return SymmetryDetection(other_group(W, c0, L), obs, 0.0)
    err = _subspace_error(S, group, c0, L)
    if err > 10 * MATCH_TOL:
        return SymmetryDetection(other_group(W, c0, L), obs, err)
    return SymmetryDetection(group, obs, err)


def _subspace_error(S, group, c0, L) -> float:
    G = np.hstack([group.g0[:, :3] * L, group.g0[:, 3:] + np.cross(group.g0[:, :3], c0)])
    G, _ = np.linalg.qr(G.T)
    # sines of the principal angles between span(S) and span(G)
    resid = G - S.T @ (S @ G)
    return float(np.linalg.norm(resid, 2)) if resid.size else 0.0


def _match(S, c0, L, k) -> SymmetryGroup | None:
    """Match an orthonormal free subspace (scaled, about c0) to a table subgroup."""
    Om = S[:, :3]  # L * omega
    U, sv, Vt = np.linalg.svd(Om)
    rot_rank = int(np.sum(sv > MATCH_TOL))
    # basis of the free subspace split into rotational and translational parts
    if rot_rank == 0:
        if k == 1:
            return symmetry_group("extruded", c0, S[0, 3:])
        return None
    if rot_rank == 3 and k == 3:
        # sphere: every element is a rotation about the centre: v_c = (c - c0) x omega
        w = Om / L
        A = np.vstack([-_hat(wi) for wi in w])  # v_c = -omega x (c - c0)
        b = S[:, 3:].reshape(-1)
        d, *_ = np.linalg.lstsq(A, b, rcond=None)
        resid = np.linalg.norm(A @ d - b)
        if resid > MATCH_TOL:
            return None
        return symmetry_group("sphere", c0 + d)
    if rot_rank != 1:
        return None
    # the rotational element: combination U[:, 0] of the rows
    rot = U[:, 0] @ S
    trans = (U[:, 1:].T @ S) if k > 1 else np.zeros((0, 6))
    axis = rot[:3] / np.linalg.norm(rot[:3])
    # normalise to |omega| = 1 (omega = axis), unscale
    scale = np.dot(rot[:3], axis) / L
    v_c = rot[3:] / scale  # velocity of c0 for a unit rotation about the axis
    # remove from v_c the parts that are translations in the subspace
    T_dirs = trans[:, 3:] if len(trans) else np.zeros((0, 3))
    if np.any(np.linalg.norm(trans[:, :3], axis=1) > MATCH_TOL) if len(trans) else False:
        return None
    if len(T_dirs):
        Qt, _ = np.linalg.qr(T_dirs.T)
        v_c = v_c - Qt @ (Qt.T @ v_c)
    pitch = float(np.dot(v_c, axis))
    if abs(pitch) > MATCH_TOL * L:
        return None  # a screw motion: not in the table
    # point on the axis: v_c = a x (c0 - p), so c0 + a x v_c = p + (a.(c0 - p)) a
    p = c0 + np.cross(axis, v_c)
    if k == 1:
        return symmetry_group("cone", p, axis)
    if k == 2:
        t = T_dirs[0] / np.linalg.norm(T_dirs[0])
        if np.linalg.norm(np.cross(t, axis)) > MATCH_TOL:
            return None
        return symmetry_group("cylinder", p, axis)
    if k == 3:
        if np.max(np.abs(T_dirs @ axis)) / max(np.min(np.linalg.norm(T_dirs, axis=1)), 1e-300) > MATCH_TOL:
            return None
        # a plane: rotations about any axis along the normal; reference point: the centroid
        return symmetry_group("plane", c0, axis)
    return None


def _hat(w):
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


# ---------------------------------------------------------------- discrete symmetries
def model_symmetries(mesh, tol_rel: float = SYMMETRY_TOL_REL, index: MeshIndex | None = None) -> np.ndarray:
    """Rigid motions (K, 4, 4) of the workpiece frame that map the model onto itself.

    Always holds the identity first. Candidates: rotations about the area centroid of the
    surface that map the two largest flat-face normal clusters onto clusters of the same
    area and angle, the flips about the principal axes of the surface's second moment and,
    when two principal moments agree, the turns by 2 pi / n (n <= 12) about the third axis.
    A candidate is kept when none of 4000 area-uniform surface samples moves farther than
    ``tol_rel`` of the bounding-box diagonal from the surface.

    Args:
        mesh: the model (workpiece frame, metres).
        tol_rel: tolerance relative to the model's size.
        index: a prebuilt :class:`MeshIndex` of ``mesh``.
    """
    index = index if index is not None else MeshIndex(mesh)
    V = index.vertices
    tri = V[index.faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    total = area.sum()
    if not total > 0:
        raise AlgorithmError("the model has zero surface area")
    cen = tri.mean(axis=1)
    c = (area @ cen) / total
    d = cen - c
    M = (d * area[:, None]).T @ d / total
    evals, evecs = np.linalg.eigh(M)
    cands = [np.eye(3)]
    # flat-face normal clusters
    key = np.round(index.face_normals, 4)
    uniq, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    c_area = np.bincount(inv, weights=area, minlength=len(uniq))
    normals = np.zeros((len(uniq), 3))
    np.add.at(normals, inv, index.face_normals * area[:, None])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    big = np.nonzero(c_area >= 0.01 * total)[0]
    big = big[np.argsort(-c_area[big], kind="stable")]
    if len(big) >= 2:
        i0 = big[0]
        others = [j for j in big[1:] if abs(np.dot(normals[i0], normals[j])) < 0.99]
        if others:
            j0 = others[0]
            F0 = _frame(normals[i0], normals[j0])
            ang0 = np.dot(normals[i0], normals[j0])
            same_i = [k for k in big if abs(c_area[k] - c_area[i0]) <= 0.01 * c_area[i0]]
            same_j = [k for k in big if abs(c_area[k] - c_area[j0]) <= 0.01 * c_area[j0]]
            for a in same_i:
                for b in same_j:
                    if a != b and abs(np.dot(normals[a], normals[b]) - ang0) < 1e-3:
                        cands.append(_frame(normals[a], normals[b]) @ F0.T)
    scale = max(evals[-1], 1e-300)
    gaps = np.diff(evals) / scale
    degenerate = gaps < 1e-3
    if not degenerate.all():
        # principal axes are defined (up to turns about a unique axis): flips about them
        for i in range(3):
            cands.append(2.0 * np.outer(evecs[:, i], evecs[:, i]) - np.eye(3))
        for j in np.nonzero(degenerate)[0]:
            # degenerate pair (j, j+1): turns by 2 pi m / n about the unique axis
            u = evecs[:, 2 if j == 0 else 0]
            for n in range(2, 13):
                for m in range(1, n):
                    cands.append(_axis_angle(u, 2 * np.pi * m / n))
    # dedupe and validate
    keep = []
    # area-uniform surface samples (fixed seed: the answer must not vary between calls)
    rng = np.random.default_rng(20010)
    f = rng.choice(len(area), size=4000, p=area / total)
    u, v = rng.random(4000), rng.random(4000)
    flip = u + v > 1.0
    u[flip], v[flip] = 1.0 - u[flip], 1.0 - v[flip]
    samples = tri[f, 0] + u[:, None] * (tri[f, 1] - tri[f, 0]) + v[:, None] * (tri[f, 2] - tri[f, 0])
    tol = tol_rel * index.extent
    for R in cands:
        # candidates closer than the tolerance to a kept one are the same motion
        if any(np.max(np.abs(R - K)) * index.extent < tol for K in keep):
            continue
        S = np.eye(4)
        S[:3, :3] = R
        S[:3, 3] = c - R @ c
        if np.max(np.abs(R - np.eye(3))) < 1e-12:
            keep.append(R)
            continue
        # a few samples first: most candidates fail at once
        if index.query(transform_points(S, samples[::25])).distance.max() > tol:
            continue
        if index.query(transform_points(S, samples)).distance.max() <= tol:
            keep.append(R)
    out = np.empty((len(keep), 4, 4))
    for i, R in enumerate(keep):
        out[i] = np.eye(4)
        out[i, :3, :3] = R
        out[i, :3, 3] = c - R @ c
    return out


def _axis_angle(u, a):
    K = _hat(u)
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


def _frame(a, b):
    e1 = a / np.linalg.norm(a)
    e2 = b - np.dot(b, e1) * e1
    e2 /= np.linalg.norm(e2)
    return np.column_stack([e1, e2, np.cross(e1, e2)])


# ------------------------------------------------------------------ pseudo-normals
_PSEUDO_CACHE: dict = {}


class _PseudoNormalTable:
    """Angle-weighted pseudo-normals of the faces, edges and vertices of a mesh."""

    def __init__(self, index: MeshIndex):
        V, F = index.vertices, index.faces
        fn = index.face_normals
        tri = V[F]
        ang = np.empty((len(F), 3))
        for k in range(3):
            e1 = tri[:, (k + 1) % 3] - tri[:, k]
            e2 = tri[:, (k + 2) % 3] - tri[:, k]
            cosang = np.einsum("ij,ij->i", e1, e2) / np.maximum(
                np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1), 1e-300)
            ang[:, k] = np.arccos(np.clip(cosang, -1.0, 1.0))
        vn = np.zeros_like(V)
        for k in range(3):
            np.add.at(vn, F[:, k], fn * ang[:, k:k + 1])
        self.vertex = vn / np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-300)
        # local edge k of face f joins corners k and k+1
        edges = np.sort(np.stack([F, np.roll(F, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
        _, inv = np.unique(edges, axis=0, return_inverse=True)
        inv = inv.reshape(-1)
        en = np.zeros((inv.max() + 1, 3))
        np.add.at(en, inv, np.repeat(fn, 3, axis=0))
        en /= np.maximum(np.linalg.norm(en, axis=1, keepdims=True), 1e-300)
        self.edge = en[inv].reshape(len(F), 3, 3)
        # sharp edges: dihedral angle above 10 degrees, or a border (one face only)
        count = np.bincount(inv)
        tilt = np.einsum("fkj,fj->fk", self.edge, fn)
        self.sharp = (tilt < np.cos(np.radians(5.0))) | (count[inv].reshape(len(F), 3) == 1)
        self.face = fn
        self.faces = F
        self.V = V

    def at(self, face: np.ndarray, foot: np.ndarray) -> np.ndarray:
        F = self.faces[face]
        a, b, c = self.V[F[:, 0]], self.V[F[:, 1]], self.V[F[:, 2]]
        ab, ac, ap = b - a, c - a, foot - a
        d00 = np.einsum("ij,ij->i", ab, ab)
        d01 = np.einsum("ij,ij->i", ab, ac)
        d11 = np.einsum("ij,ij->i", ac, ac)
        d20 = np.einsum("ij,ij->i", ap, ab)
        d21 = np.einsum("ij,ij->i", ap, ac)
        den = d00 * d11 - d01 * d01
        with np.errstate(divide="ignore", invalid="ignore"):
            v = (d11 * d20 - d01 * d21) / den
            w = (d00 * d21 - d01 * d20) / den
        u = 1.0 - v - w
        bary = np.column_stack([u, v, w])
        zero = np.abs(bary) < 1e-9
        zero[~np.isfinite(bary)] = False
        out = self.face[face].copy()
        nz = zero.sum(axis=1)
        rows = np.arange(len(face))
        # one zero coordinate: on the edge opposite that corner (local edge (k+1) % 3)
        e_rows = nz == 1
        if e_rows.any():
            k = np.argmax(zero[e_rows], axis=1)
            out[e_rows] = self.edge[face[e_rows], (k + 1) % 3]
        # two zeros: at the corner with the non-zero coordinate
        v_rows = nz >= 2
        if v_rows.any():
            k = np.argmax(~zero[v_rows], axis=1)
            out[v_rows] = self.vertex[F[rows[v_rows], k]]
        return out


    def sharp_edge_distance(self, face: np.ndarray, foot: np.ndarray) -> np.ndarray:
        """(N,) distance [m] from feet to the nearest sharp edge of their face (inf: none)."""
        F = self.faces[face]
        out = np.full(len(face), np.inf)
        for k in range(3):
            sharp = self.sharp[face, k]
            if not sharp.any():
                continue
            a = self.V[F[sharp, k]]
            b = self.V[F[sharp, (k + 1) % 3]]
            ab = b - a
            t = np.clip(np.einsum("ij,ij->i", foot[sharp] - a, ab) / np.maximum(
                np.einsum("ij,ij->i", ab, ab), 1e-300), 0.0, 1.0)
            dist = np.linalg.norm(foot[sharp] - (a + t[:, None] * ab), axis=1)
            out[sharp] = np.minimum(out[sharp], dist)
        return out


def pseudo_normals(index: MeshIndex) -> _PseudoNormalTable:
    """The (cached) angle-weighted pseudo-normal table of a mesh index."""
    key = id(index)
    hit = _PSEUDO_CACHE.get(key)
    if hit is None or hit[0] is not index:
        if len(_PSEUDO_CACHE) > 8:
            _PSEUDO_CACHE.clear()
        hit = (index, _PseudoNormalTable(index))
        _PSEUDO_CACHE[key] = hit
    return hit[1]


# ---------------------------------------------------------------------- the pipeline
def localize_symmetric(
    points,
    mesh,
    symmetric="auto",
    init=None,
    rng: np.random.Generator | None = None,
    sigma: float | None = None,
    outlier="mad",
    tol: float = DETECTION_TOL,
    index: MeshIndex | None = None,
    discrete: bool = True,
    method: str = "hong_tan",
) -> SymmetricResult:
    """Localize with the symmetry the data leave free: Algorithm 1, detection, Algorithm 2.

    1. Algorithm 1 (Hong-Tan by default; its minimum-norm solve tolerates the singular
       systems) from ``init`` gives a pose and the feet.
    2. ``symmetric="auto"``: :func:`detect_symmetry` on the feet and smooth normals picks
       ``G_0``; a feature type (``"cylinder"``, ...): the primitive of that type is fitted to
       the model faces the points landed on and its ``G_0`` used (an error when they are not
       such a surface); a :class:`Feature` or :class:`SymmetryGroup`: used as given;
       ``"none"``: Algorithm 1's result is returned as it is (its weak directions reported).
    3. Algorithm 2 along ``m_0`` from Algorithm 1's pose.
    4. ``discrete``: every model symmetry ``S`` (:func:`model_symmetries`) gives the equally
       good pose ``T S``; distinct ones (modulo ``G_0``) go to ``solutions``, the one
       nearest ``init`` first.

    Args:
        points: (N, 3) [m] measured points, world frame.
        mesh: the CAD model (workpiece frame, metres).
        symmetric: "auto", "none", a feature type, a Feature or a SymmetryGroup.
        init: initial pose (4x4), "global" (Algorithm 5) or None (identity).
        rng: generator for the global search.
        sigma: noise sigma along the normals [m] (estimated when None).
        outlier: as for :func:`algorithms.registration.local.localize`.
        tol: detection tolerance (relative eigenvalue).
        index: prebuilt MeshIndex of ``mesh``.
        discrete: look for discrete model symmetries.
        method: the pose update of the Algorithm 1 stage (default Hong-Tan).

    Raises:
        AlgorithmError: bad input, an unknown ``symmetric`` (the valid choices are listed),
            a 2D feature type (planar problems go through :func:`algorithm2`), or measured
            faces that are not the requested feature.
    """
    t0 = time.perf_counter()
    if isinstance(symmetric, str) and symmetric not in SYMMETRIC_CHOICES:
        if symmetric not in FEATURE_TABLE:
            raise AlgorithmError(
                f"symmetric must be one of {', '.join(SYMMETRIC_CHOICES)} or a feature type "
                f"({', '.join(FEATURE_TABLE)}); got {symmetric!r}"
            )
        check_feature_type(symmetric)
        if FEATURE_TABLE[symmetric].planar:
            raise AlgorithmError(
                f"{symmetric} is a 2D feature (planar problem in SE(2)); localize 2D points "
                "with algorithms.registration.symmetric.algorithm2 and Feature.{symmetric}(...)"
            )
    if not (np.isfinite(tol) and 0 < tol < 1):
        raise AlgorithmError(f"tol must be in (0, 1), got {tol}")
    index = index if index is not None else (mesh if isinstance(mesh, MeshIndex) else MeshIndex(mesh))
    res1 = localize(points, index=index, method=method, init=init, rng=rng, sigma=sigma, outlier=outlier)
    T1 = res1.T_world_workpiece
    P = np.asarray(points, dtype=np.float64)
    finite = np.all(np.isfinite(P), axis=1)
    det_foot, det_normal, det_face = _surface_points(index, P[res1.inliers], T1, res1.sigma_m)
    T_ref = np.eye(4) if (init is None or isinstance(init, str)) else as_pose(init, name="init")

    if isinstance(symmetric, str) and symmetric == "none":
        obs = observability(det_foot, det_normal, tol)
        weak = _unit_rows(obs.weak_directions)
        rel = obs.relative_eigenvalues
        return SymmetricResult(
            T_world_workpiece=T1, solutions=T1[None].copy(), solution_rmse_m=np.array([res1.rmse_m]),
            feature="none", group=other_group(weak, obs.centroid, obs.characteristic_length_m),
            free_dofs=len(weak), free_directions=weak,
            fixed_directions=np.zeros((0, 6)), covariance_fixed=None,
            converged=res1.converged, iterations=res1.iterations, status=res1.status,
            rmse_m=res1.rmse_m, history=res1.history, sigma_m=res1.sigma_m,
            general_system_rank=int(np.sum(rel >= tol)),
            general_system_condition=float(1 / rel[0]) if rel[0] >= tol else float("inf"),
            relative_eigenvalues=rel, detection_tol=tol, algorithm="1",
            n_points_used=res1.n_points_used, n_outliers=res1.n_outliers, inliers=res1.inliers,
            time_s=time.perf_counter() - t0,
        )
    if isinstance(symmetric, SymmetryGroup):
        group = symmetric
    elif isinstance(symmetric, Feature):
        group = symmetric.group
    elif symmetric == "auto":
        group = detect_symmetry(det_foot, det_normal, tol).group
    else:
        feat = Feature.from_mesh(index.mesh, np.unique(det_face), kind=symmetric)
        group = feat.group
    res2 = algorithm2(P, index, group, init=T1, sigma=sigma, outlier=outlier)
    T2 = res2.T_world_workpiece
    sols = [T2]
    if discrete:
        syms = model_symmetries(index.mesh, index=index)
        reps = [np.eye(4)]
        for S in syms[1:]:
            # T S equals T S' modulo G_0 when S' S^-1 is in G_0
            if any(group.contains(S @ inv_pose(R), SAME_SOLUTION_TOL, SAME_SOLUTION_TOL * index.extent)
                   for R in reps):
                continue
            reps.append(S)
        sols = [T2 @ S for S in reps]
    sols = sorted(sols, key=lambda T: _pose_gap(T, T_ref, index.extent))
    rms = []
    Yi = P[res2.inliers]
    for T in sols:
        d = index.query(transform_points(inv_pose(T), Yi)).distance
        rms.append(float(np.sqrt(np.mean(d**2))))
    inliers = res2.inliers
    status = res2.status
    # the information at the result, on the surface points (as for the detection)
    f2, n2, _ = _surface_points(index, P[inliers], T2, res2.sigma_m)
    rel = _scaled_information(f2, n2[:, None, :], False) if len(f2) >= 6 else res2.relative_eigenvalues
    rank6 = int(np.sum(rel >= tol))
    cond = float(1.0 / rel[0]) if rank6 == 6 else float("inf")
    if len(sols) > 1:
        status += f"; {len(sols)} equally good poses (discrete symmetry of the model)"
    return SymmetricResult(
        T_world_workpiece=sols[0], solutions=np.asarray(sols), solution_rmse_m=np.asarray(rms),
        feature=res2.feature, group=_move_group(group, T2, sols[0]), free_dofs=res2.free_dofs,
        free_directions=_move_twists(res2.free_directions, T2, sols[0]),
        fixed_directions=_move_twists(res2.fixed_directions, T2, sols[0]),
        covariance_fixed=res2.covariance_fixed, converged=res2.converged,
        iterations=res1.iterations + res2.iterations, status=status, rmse_m=res2.rmse_m,
        history=res1.history + res2.history[1:], sigma_m=res2.sigma_m,
        general_system_rank=rank6, general_system_condition=cond,
        relative_eigenvalues=rel, detection_tol=tol, algorithm="2",
        n_points_used=res2.n_points_used, n_outliers=int(finite.sum() - res2.n_points_used),
        inliers=inliers, time_s=time.perf_counter() - t0,
    )


def _surface_points(index, Y, T, sigma):
    """Feet, smooth normals and faces of the points that measure a surface, not an edge.

    Points on, beyond or within the noise of a sharp edge (their foot on the edge, the offset
    not along the normal, or the foot closer to a sharp edge than EDGE_BAND_SIGMA noise
    sigmas) measure the edge: they would fake information along a free direction (a plane
    whose points hang over its border). The information analyses leave them out; Algorithm
    2 still uses every inlier. Falls back to all points when fewer than 6 remain.
    """
    Ym = transform_points(inv_pose(T), Y)
    cp = index.query(Ym)
    smooth = index.smooth_normals(cp.face, cp.foot)
    along = np.abs(np.einsum("ij,ij->i", Ym - cp.foot, cp.normal))
    table = pseudo_normals(index)
    pn = table.at(cp.face, cp.foot)
    band = max(EDGE_BAND_SIGMA * sigma, 1e-9 * index.extent)
    keep = ((along >= EDGE_COS * cp.distance) | (cp.distance <= 1e-12 * index.extent)) & (
        np.einsum("ij,ij->i", pn, cp.normal) >= EDGE_COS) & (
        table.sharp_edge_distance(cp.face, cp.foot) > band)
    if keep.sum() < 6:
        keep[:] = True
    return cp.foot[keep], smooth[keep], cp.face[keep]


def _unit_rows(W):
    W = np.asarray(W, dtype=np.float64).reshape(-1, 6)
    out = W.copy()
    for i, x in enumerate(W):
        nw = np.linalg.norm(x[:3])
        out[i] = x / (nw if nw > 1e-9 * max(np.linalg.norm(x[3:]), 1e-300) else np.linalg.norm(x[3:]))
    return out


def _pose_gap(T, T_ref, size):
    return rotation_error_rad(T, T_ref) * size + float(np.linalg.norm(T[:3, 3] - T_ref[:3, 3]))


def _move_twists(X, T_from, T_to):
    """Twists about the workpiece origin at T_from, expressed for the pose T_to (same world
    motions): T_to = T_from S, so the workpiece frames differ by S."""
    S = inv_pose(T_from) @ T_to
    if np.allclose(S, np.eye(4), atol=1e-12):
        return X.copy()
    Si = inv_pose(S)
    R, p = Si[:3, :3], Si[:3, 3]
    w = X[:, :3] @ R.T
    v = X[:, 3:] @ R.T + np.cross(p, w)
    return np.hstack([w, v])


def _move_group(group, T_from, T_to):
    S = inv_pose(T_from) @ T_to
    if np.allclose(S, np.eye(4), atol=1e-12) or group.kind == "other":
        return group
    Si = inv_pose(S)
    origin = transform_points(Si, group.origin[None])[0]
    axis = Si[:3, :3] @ group.axis
    if group.kind == "freeform":
        return symmetry_group("freeform", origin)
    return symmetry_group(group.kind, origin, axis)

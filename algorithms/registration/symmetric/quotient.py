"""Localization on the quotient ``SE(3)/G_0``: document 000's Algorithm 2.

A feature with symmetry subgroup ``G_0`` (see :mod:`.groups`) fixes the pose only on
``SE(3)/G_0``. Its points make the linear systems of the Tangent and Hong-Tan updates
singular (the ``G_0`` directions carry no information). Algorithm 2 (document 000, section
4.2) never forms them: with a basis ``eta_1..eta_q`` of the complement ``m_0``
(``q = dim SE(3)/G_0``) it

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
``determined_directions`` (the ``m_0`` basis, with the covariance along it), both in the
workpiece frame. Outliers are rejected by the rules of :mod:`algorithms.registration.robust`
(the cut tightened once at convergence; the iteration goes on if that changes the inliers).

The verdict (``status``): NOT_CONVERGED if the stopping rule was not met; else UNOBSERVABLE if
``G_0`` leaves directions free; else POOR_FIT if the noise cannot explain the RMS; else OK.
:mod:`.pipeline` finds ``G_0`` from the data and lists every equally good pose.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from algorithms.arraytypes import ArrayLike, BoolArray, FloatArray, IntArray, Pose
from algorithms.errors import AlgorithmError
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import as_pose, exp_se3, inv_pose, transform_points
from algorithms.registration.fit_check import poor_fit_reason, white_noise_sigma_m
from algorithms.registration.inputs import check_sigma
from algorithms.registration.result import RegistrationResult, fit_status
from algorithms.registration.robust import (
    OUTLIER_FLOOR_REL,
    Mask,
    OutlierConfig,
    OutlierStages,
    count,
    outlier_config,
    same_mask,
)
from algorithms.registration.symmetric.detect import DETECTION_TOL
from algorithms.registration.symmetric.features import Feature, TriangleMesh
from algorithms.registration.symmetric.groups import SymmetryGroup

__all__ = [
    "MAX_ITERATIONS",
    "TOLERANCE",
    "SymmetricResult",
    "algorithm2",
    "scaled_information",
]

#: Stopping rule and iteration cap of Algorithm 2.
TOLERANCE = 1e-10
MAX_ITERATIONS = 100
#: Most halvings of one step before the iteration counts as stalled.
MAX_HALVINGS = 12
#: A stalled step that raises the residual by no more than this fraction counts as converged.
STALL_REL = 1e-6
#: RMS below this fraction of the data's size is an exact fit.
FLOOR_REL = 1e-12
MIN_POINTS = 3


@dataclass(frozen=True, kw_only=True, eq=False)
class SymmetricResult(RegistrationResult):
    """Result of :func:`algorithm2` and :func:`localize_symmetric`: a
    :class:`algorithms.registration.result.RegistrationResult` plus

    Attributes:
        feature: the table feature whose ``G_0`` was used ("freeform": none), "other", or
            "none" (``symmetric="none"``: Algorithm 1 only).
        group: the :class:`SymmetryGroup` used (at ``T_world_workpiece``).
        solution_rmse_m: (K,) RMS point-to-model distance at each of ``solutions`` [m].
        general_system_rank: rank of the 6x6 (3x3 planar) matrix of Tangent/Hong-Tan at the
            result (scaled, relative tolerance ``detection_tol``): below 6 (3) the general
            updates are singular here.
        general_system_condition: its condition number (inf when singular).
        detection_tol: the tolerance that decided which directions are free.
        algorithm: "2" (Algorithm 2) or "1" (``symmetric="none"``: Algorithm 1 only).

    Here ``free_directions`` spans ``G_0`` (the pose along it stays at the initial pose),
    ``determined_directions`` spans ``m_0`` (the directions solved) and ``covariance`` is
    that of the pose coordinates along them (``T_true = T_est exp(sum m_j eta_j)``), from the
    point-to-plane information with ``sigma_m``; None with too few points. For the planar
    (2D) features both lie in se(2): ``q + k = 3``. ``method`` is ``"algorithm2"`` or, for
    ``symmetric="none"``, the local method.
    """

    feature: str
    group: SymmetryGroup
    solution_rmse_m: FloatArray
    general_system_rank: int
    general_system_condition: float
    detection_tol: float
    algorithm: str


# ----------------------------------------------------------------------------- models
@dataclass(frozen=True)
class _Feet:
    """Where the points land on the model at a pose (workpiece frame, metres).

    Attributes:
        points: (n, 3) the points moved into the workpiece frame.
        foot: (n, 3) their closest points on the model.
        normals: (n, m, 3) unit normals at the feet (m > 1 where a feature has several).
        distance: (n,) point-to-model distances >= 0 [m].
        smooth_normals: (n, m, 3) normals of the ideal surface at the feet (a mesh's
            interpolated ones; a feature's own).
    """

    points: FloatArray
    foot: FloatArray
    normals: FloatArray
    distance: FloatArray
    smooth_normals: FloatArray


class _Model:
    """Closest points on a Feature or a mesh (workpiece frame)."""

    def __init__(self, model: object) -> None:
        self.feature: Feature | None = None
        self.index: MeshIndex | None = None
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

    def feet(self, T_world_workpiece: Pose, points_world: FloatArray) -> _Feet:
        """The feet of world points ``(n, 3)`` with the model at ``T_world_workpiece``."""
        Ym = transform_points(inv_pose(T_world_workpiece), points_world)
        if self.feature is not None and self.feature.index is None:
            p = self.feature.closest(Ym)
            return _Feet(Ym, p.foot, p.normals, np.abs(p.distance), p.normals)
        assert self.index is not None
        cp = self.index.query(Ym)
        smooth = self.index.smooth_normals(cp.face, cp.foot)
        return _Feet(Ym, cp.foot, cp.normal[:, None, :], cp.distance, smooth[:, None, :])


def _rows(Ym: FloatArray, foot: FloatArray, normals: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Point-to-plane rows J (N*m, 6) about the origin and residuals s (N*m,)."""
    m = normals.shape[1]
    Y = np.repeat(Ym, m, axis=0)
    F = np.repeat(foot, m, axis=0)
    n = normals.reshape(-1, 3)
    J = np.hstack([np.cross(Y, n), n])
    s = np.einsum("ij,ij->i", Y - F, n)
    return J, s


def _lstsq_scaled(A: FloatArray, b: FloatArray) -> tuple[FloatArray, int, float]:
    """Least squares with column scaling; returns (x, rank, smallest relative sv)."""
    d = np.linalg.norm(A, axis=0)
    d[d == 0] = 1.0
    x, _, rank, sv = np.linalg.lstsq(A / d, b, rcond=1e-12)
    rel = float(sv[-1] / sv[0]) if len(sv) and sv[0] > 0 else 0.0
    return x / d, int(rank), rel


def scaled_information(feet: FloatArray, normals: FloatArray, planar: bool) -> FloatArray:
    """Eigenvalues of the point-to-plane information, ascending, relative to the largest.

    Rotations are scaled by the RMS distance of the feet from their centroid and taken about
    it (as in :func:`algorithms.registration.uncertainty.observability`), so the eigenvalues
    compare rotations and translations in one unit.

    Args:
        feet: (n, 3) [m] points on the model, workpiece frame.
        normals: (n, m, 3) unit normals there (m per point).
        planar: keep the se(2) part only (rotation about z, translation in x and y).

    Returns:
        (6,) or, planar, (3,) relative eigenvalues in [0, 1].
    """
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


def _check_points(points: ArrayLike, planar: bool) -> tuple[FloatArray, BoolArray]:
    P = np.asarray(points, dtype=np.float64)
    if planar and P.ndim == 2 and P.shape[1] == 2:
        P = np.hstack([P, np.zeros((len(P), 1))])
    if P.ndim != 2 or P.shape[1] != 3:
        raise AlgorithmError(f"points must be (N, 3){' or (N, 2)' if planar else ''}, got {P.shape}")
    finite = np.all(np.isfinite(P), axis=1)
    return P, finite


def _check_planar_pose(T: Pose) -> None:
    R = T[:3, :3]
    if abs(R[2, 2] - 1.0) > 1e-9 or abs(T[2, 3]) > 1e-12:
        raise AlgorithmError("a 2D feature needs a planar init (rotation about z, no z translation)")


def _mse(distance: FloatArray, mask: Mask) -> float:
    """Mean squared distance of the inliers [m^2]: Algorithm 2's ``e_k``."""
    return float(np.mean(distance[mask] ** 2))


# ----------------------------------------------------------------------- Algorithm 2
@dataclass(frozen=True)
class _Problem:
    """Algorithm 2's checked input.

    Attributes:
        model: closest points on the model (workpiece frame).
        group: ``G_0``; its ``m0`` (q, 6) is the basis ``B`` the updates move along.
        points: (N, 3) [m] every input row, world frame (NaN rows included).
        finite: (N,) the rows with finite coordinates.
        rows: (n,) their indices.
        Y: (n, 3) [m] the finite points, world frame.
        T_init: the initial ``T_world_workpiece`` (``g^0``).
        sigma: the given noise sigma [m], or None (estimated).
        outlier: the checked outlier rule.
        size_m: the points' bounding-box diagonal [m] (1 when they coincide).
        max_iterations: cap on pose updates.
        tolerance: ``delta`` of the stopping rule.
    """

    model: _Model
    group: SymmetryGroup
    points: FloatArray
    finite: BoolArray
    rows: IntArray
    Y: FloatArray
    T_init: Pose
    sigma: float | None
    outlier: OutlierConfig
    size_m: float
    max_iterations: int
    tolerance: float

    @property
    def floor2(self) -> float:
        """``e_k`` at or below this is an exact fit [m^2]."""
        return (FLOOR_REL * self.size_m) ** 2


@dataclass
class _State:
    """Algorithm 2's iterate ``g^k`` with its feet, inliers and ``e_k``, and the verdict."""

    T: Pose
    feet: _Feet
    stages: OutlierStages
    mask: Mask
    e: float
    history: list[float]
    poses: list[Pose]
    iterations: int = 0
    converged: bool = False
    message: str = ""


@dataclass(frozen=True)
class _Trial:
    """A candidate update ``g^(k-1) exp(xi)`` with its feet and ``e`` on the current inliers."""

    T: Pose
    feet: _Feet
    e: float


@dataclass(frozen=True)
class _Stop:
    """Why the iteration stopped."""

    converged: bool
    message: str


def _check_group(group: SymmetryGroup | None, model: _Model) -> SymmetryGroup:
    if group is None:
        if model.feature is None:
            raise AlgorithmError("give the symmetry group G_0 (a SymmetryGroup) for a mesh model")
        group = model.feature.group
    if not isinstance(group, SymmetryGroup):
        raise AlgorithmError(f"group must be a SymmetryGroup, got {type(group).__name__}")
    if model.feature is not None and model.feature.planar != group.planar:
        raise AlgorithmError("a 2D (planar) feature needs a planar group and vice versa")
    return group


def _problem(points: ArrayLike, model: object, group: SymmetryGroup | None, init: ArrayLike | None,
             sigma: float | None, max_iterations: int, tolerance: float, outlier: str | float | None) -> _Problem:
    """Check Algorithm 2's input (the order of the checks decides which error is raised)."""
    mdl = _Model(model)
    group = _check_group(group, mdl)
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
    sigma = check_sigma(sigma)
    mode = outlier_config(outlier)
    T = np.eye(4) if init is None else as_pose(init, name="init")
    if group.planar:
        _check_planar_pose(T)
    rows = np.nonzero(finite)[0]
    Y = P[rows]
    size = float(np.linalg.norm(np.ptp(Y, axis=0))) or 1.0
    return _Problem(model=mdl, group=group, points=P, finite=finite, rows=rows, Y=Y, T_init=T, sigma=sigma,
                    outlier=mode, size_m=size, max_iterations=max_iterations, tolerance=tolerance)


def _start(pb: _Problem) -> _State:
    """Steps 1-2: the feet at ``g^0`` (k = 0), the inliers and ``e_0``."""
    stages = OutlierStages(pb.outlier, OUTLIER_FLOOR_REL * pb.size_m, OUTLIER_FLOOR_REL * pb.size_m, MIN_POINTS)
    feet = pb.model.feet(pb.T_init, pb.Y)
    mask = stages.mask(feet.distance)
    e0 = _mse(feet.distance, mask)
    return _State(T=pb.T_init, feet=feet, stages=stages, mask=mask, e=e0, history=[float(np.sqrt(e0))],
                  poses=[pb.T_init])


def _m0_step(pb: _Problem, st: _State) -> FloatArray:
    """Step 3: the point-to-plane least squares in ``m_0`` only; the twist ``B^T m`` (6,)."""
    f, mask = st.feet, st.mask
    J, s = _rows(f.points[mask], f.foot[mask], f.normals[mask])
    B = pb.group.m0
    mu, _, _ = _lstsq_scaled(J @ B.T, s)
    return B.T @ mu


def _trial(pb: _Problem, st: _State, xi: FloatArray) -> _Trial:
    T = st.T @ exp_se3(xi)
    feet = pb.model.feet(T, pb.Y)
    return _Trial(T=T, feet=feet, e=_mse(feet.distance, st.mask))


def _halved_step(pb: _Problem, st: _State) -> _Trial:
    """Steps 3-4: the update along ``m_0``, halved while it would raise the residual."""
    xi = _m0_step(pb, st)
    trial = _trial(pb, st, xi)
    halvings = 0
    while trial.e > st.e and halvings < MAX_HALVINGS:
        # overshoot far from the minimum: halve the motion
        xi = 0.5 * xi
        trial = _trial(pb, st, xi)
        halvings += 1
    return trial


def _stop_before_step(pb: _Problem, st: _State) -> _Stop | None:
    if st.e <= pb.floor2:
        return _Stop(True, f"converged: residual at the numerical floor (RMS {np.sqrt(st.e):.3g} m)")
    if st.iterations >= pb.max_iterations:
        return _Stop(False, f"not converged: reached max_iterations = {pb.max_iterations}")
    return None


def _stalled(st: _State, trial: _Trial) -> _Stop:
    """No halving of the step lowers the residual: converged when it stays within rounding."""
    converged = trial.e <= st.e * (1.0 + STALL_REL)
    return _Stop(converged, "converged: no further decrease" if converged else
                 "not converged: stalled, no step along m_0 lowers the residual")


def _accept(pb: _Problem, st: _State, trial: _Trial) -> _Stop | None:
    """Steps 4-5: ``g^k``, new feet and inliers, ``e_k``; stop when ``1 - e_k / e_(k-1) < delta``
    with the inliers unchanged."""
    st.iterations += 1
    st.T = trial.T
    st.feet = trial.feet
    st.history.append(float(np.sqrt(trial.e)))
    st.poses.append(st.T)
    rel = 1.0 - trial.e / st.e if st.e > 0 else 0.0
    new_mask = st.stages.mask(trial.feet.distance)
    changed = not same_mask(new_mask, st.mask)
    st.mask = new_mask
    st.e = _mse(trial.feet.distance, new_mask)
    if not changed and rel < pb.tolerance:
        return _Stop(True, f"converged: relative decrease 1 - e_k/e_(k-1) = {rel:.3g} < delta = {pb.tolerance:g}")
    return None


def _descend(pb: _Problem, st: _State) -> None:
    """Steps 3-5 repeated until a stopping rule holds; sets ``converged`` and ``message``."""
    while True:
        stop = _stop_before_step(pb, st)
        if stop is None:
            trial = _halved_step(pb, st)
            stop = _stalled(st, trial) if trial.e > st.e else _accept(pb, st, trial)
        if stop is not None:
            st.converged, st.message = stop.converged, stop.message
            return


def _tighten_outliers(st: _State) -> bool:
    """Move the outlier cut to its final stage; True when that changed the inliers."""
    if not st.stages.tighten():
        return False
    new_mask = st.stages.mask(st.feet.distance)
    if same_mask(new_mask, st.mask):
        return False
    st.mask = new_mask
    st.e = _mse(st.feet.distance, new_mask)
    st.converged = False
    return True


@dataclass(frozen=True)
class _Information:
    """The point-to-plane information at Algorithm 2's result.

    Attributes:
        rows: (n*m, q) rows ``J B^T`` of the inliers along ``m_0``.
        residuals: (n*m,) their point-to-plane residuals [m].
        sigma_m: the given sigma, or the one the residuals give [m].
        covariance: (q, q) of the pose along ``m_0``, None when singular.
        relative_eigenvalues: the scaled 6x6 (3x3 planar) information's, ascending.
        rank: of that matrix at ``DETECTION_TOL``.
        condition: its condition number (inf when rank deficient).
    """

    rows: FloatArray
    residuals: FloatArray
    sigma_m: float
    covariance: np.ndarray | None
    relative_eigenvalues: FloatArray
    rank: int
    condition: float


def _information(pb: _Problem, st: _State) -> _Information:
    f, mask, q = st.feet, st.mask, pb.group.quotient_dim
    J, s = _rows(f.points[mask], f.foot[mask], f.normals[mask])
    A = J @ pb.group.m0.T
    dof = max(len(s) - q, 1)
    sigma_used = float(pb.sigma) if pb.sigma is not None else float(np.sqrt(np.sum(s * s) / dof))
    cov = None
    N = A.T @ A
    if q and np.linalg.matrix_rank(N / np.max(np.abs(N)) if np.max(np.abs(N)) > 0 else N) == q:
        cov = np.linalg.inv(N) * sigma_used**2
        cov = 0.5 * (cov + cov.T)
    rel_eig = scaled_information(f.foot[mask], f.smooth_normals[mask], pb.group.planar)
    rank6 = int(np.sum(rel_eig >= DETECTION_TOL))
    cond = float(1.0 / rel_eig[0]) if rel_eig[0] > 0 and rank6 == len(rel_eig) else float("inf")
    return _Information(rows=A, residuals=s, sigma_m=sigma_used, covariance=cov, relative_eigenvalues=rel_eig,
                        rank=rank6, condition=cond)


def _result(pb: _Problem, st: _State, info: _Information, t0: float) -> SymmetricResult:
    """The SymmetricResult of Algorithm 2 and its verdict."""
    group, mask, dist = pb.group, st.mask, st.feet.distance
    n_used = count(mask, len(pb.Y))
    message = st.message
    deficient = max(0, (len(info.relative_eigenvalues) - info.rank) - group.dim)
    if deficient:
        message += (f"; WARNING: the points leave {deficient} direction(s) of m_0 unfixed as well "
                    "(more symmetric than the group given): minimum-norm steps were taken")
    inliers = np.zeros(len(pb.points), dtype=bool)
    inliers[pb.rows[mask]] = True
    rmse = float(np.sqrt(np.mean(dist[mask] ** 2)))
    extent = float(np.linalg.norm(np.ptp(pb.points[pb.finite], axis=0)))
    white = (white_noise_sigma_m(st.feet.points[mask], info.residuals.reshape(n_used, -1))
             if pb.sigma is None else math.nan)
    poor = poor_fit_reason(rmse, n_used, int(pb.finite.sum()), extent, pb.sigma, white)
    return SymmetricResult(
        T_world_workpiece=st.T,
        method="algorithm2",
        converged=st.converged,
        status=fit_status(st.converged, group.dim + deficient, poor),
        message=message + (f"; poor fit: {poor}" if poor else ""),
        rmse_m=rmse,
        iterations=st.iterations,
        history=tuple(st.history),
        pose_history=tuple(st.poses),
        inliers=inliers,
        n_points_used=n_used,
        n_outliers=int(len(pb.Y) - n_used),
        n_dropped_nonfinite=int(len(pb.points) - len(pb.Y)),
        sigma_m=info.sigma_m,
        determined_directions=group.m0.copy(),
        covariance=info.covariance,
        free_directions=group.g0.copy(),
        solutions=(st.T,),
        relative_eigenvalues=info.relative_eigenvalues,
        time_s=time.perf_counter() - t0,
        poor_fit_reason=poor,
        feature=group.kind,
        group=group,
        solution_rmse_m=np.array([rmse]),
        general_system_rank=info.rank,
        general_system_condition=info.condition,
        detection_tol=DETECTION_TOL,
        algorithm="2",
    )


def algorithm2(
    points: ArrayLike,
    model: Feature | TriangleMesh | MeshIndex,
    group: SymmetryGroup | None = None,
    init: ArrayLike | None = None,
    sigma: float | None = None,
    max_iterations: int = MAX_ITERATIONS,
    tolerance: float = TOLERANCE,
    outlier: str | float | None = "mad",
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
        sigma: noise sigma along the normals [m] for the covariance and the poor-fit verdict
            (estimated when None).
        max_iterations: cap on pose updates.
        tolerance: ``delta`` of ``1 - e_k/e_(k-1) < delta``.
        outlier: ``"mad"`` (the staged robust cut of :mod:`algorithms.registration.robust`),
            a distance [m], or None.

    Returns:
        SymmetricResult (``solutions`` holds the one pose; ``algorithm = "2"``).

    Raises:
        AlgorithmError: bad points, model, group, init or options.
    """
    t0 = time.perf_counter()
    pb = _problem(points, model, group, init, sigma, max_iterations, tolerance, outlier)
    st = _start(pb)
    _descend(pb, st)
    # converged: tighten the outlier cut once; go on if that changes the inliers
    while st.converged and _tighten_outliers(st):
        _descend(pb, st)
    return _result(pb, st, _information(pb, st), t0)

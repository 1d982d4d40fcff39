"""Localization on the quotient ``SE(3)/G_0``: document 000's Algorithm 2, and the pipeline
that finds ``G_0`` from the data and lists every equally good pose (:func:`localize_symmetric`).

Algorithm 2 (document 000, section 4.2). A feature with symmetry subgroup ``G_0`` (see
:mod:`.groups`) fixes the pose only on ``SE(3)/G_0``. Its points make the linear systems of the
Tangent and Hong-Tan updates singular (the ``G_0`` directions carry no information).
Algorithm 2 never forms them: with a basis ``eta_1..eta_q`` of the complement ``m_0``
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
workpiece frame. Outliers are rejected by the rules of :mod:`algorithms.registration.robust`.

The pipeline (:func:`localize_symmetric`): Algorithm 1 from the initial pose, the subgroup the
data leave free (:mod:`.detect`) or the one asked for, Algorithm 2, then every model symmetry
``S`` (:mod:`.discrete`) gives the equally good pose ``T S``: every distinct one goes to
``solutions`` (distinct modulo ``G_0``: two poses differing by a free motion are the same
solution), the one nearest the initial pose first.

The verdict (``status``): NOT_CONVERGED if Algorithm 2 did not meet its stopping rule; else
AMBIGUOUS if the model's symmetries give several equally good poses; else UNOBSERVABLE if
``G_0`` leaves directions free; else POOR_FIT if ``sigma`` is given and the RMS exceeds 3
sigma; else OK.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from algorithms.errors import AlgorithmError
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import as_pose, exp_se3, inv_pose, rotation_error_rad, transform_points
from algorithms.registration.fit_check import poor_fit_reason, white_noise_sigma_m
from algorithms.registration.inputs import check_sigma
from algorithms.registration.local import localize
from algorithms.registration.result import RegistrationResult, Status, fit_status
from algorithms.registration.robust import OUTLIER_FLOOR_REL, OutlierStages, count, outlier_config, same_mask
from algorithms.registration.symmetric.detect import DETECTION_TOL, detect_symmetry
from algorithms.registration.symmetric.discrete import model_symmetries, pseudo_normals
from algorithms.registration.symmetric.features import Feature
from algorithms.registration.symmetric.groups import (
    FEATURE_TABLE,
    SymmetryGroup,
    check_feature_type,
    other_group,
    symmetry_group,
)
from algorithms.registration.uncertainty import observability, sym_inverse, unit_twists

__all__ = [
    "MAX_ITERATIONS",
    "SAME_SOLUTION_TOL",
    "SYMMETRIC_CHOICES",
    "TOLERANCE",
    "SymmetricResult",
    "algorithm2",
    "localize_symmetric",
]

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
    solution_rmse_m: np.ndarray
    general_system_rank: int
    general_system_condition: float
    detection_tol: float
    algorithm: str


# ----------------------------------------------------------------------------- models
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
    sigma = check_sigma(sigma)
    mode = outlier_config(outlier)
    T = np.eye(4) if init is None else as_pose(init, name="init")
    if group.planar:
        _check_planar_pose(T)
    rows = np.nonzero(finite)[0]
    Y = P[rows]
    size = float(np.linalg.norm(np.ptp(Y, axis=0))) or 1.0
    floor2 = (FLOOR_REL * size) ** 2
    stages = OutlierStages(mode, OUTLIER_FLOOR_REL * size, OUTLIER_FLOOR_REL * size, MIN_POINTS)
    B = group.m0

    def evaluate(T_):
        Ym_ = transform_points(inv_pose(T_), Y)
        return (Ym_,) + tuple(mdl.closest(Ym_))

    Ym, foot, normals, dist, smooth, _ = evaluate(T)
    mask = stages.mask(dist)

    def mse(d, mk):
        return float(np.mean(d[mk] ** 2))

    e_prev = mse(dist, mask)
    history = [float(np.sqrt(e_prev))]
    poses = [T]
    converged, message = False, f"not converged: reached max_iterations = {max_iterations}"
    it = 0
    while True:
        while True:
            if e_prev <= floor2:
                converged = True
                message = f"converged: residual at the numerical floor (RMS {np.sqrt(e_prev):.3g} m)"
                break
            if it >= max_iterations:
                converged = False
                message = f"not converged: reached max_iterations = {max_iterations}"
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
                message = ("converged: no further decrease" if converged else
                           "not converged: stalled, no step along m_0 lowers the residual")
                break
            it += 1
            T = T @ exp_se3(xi)
            Ym, foot, normals, dist, smooth, _ = cand
            history.append(float(np.sqrt(e_new)))
            poses.append(T)
            rel = 1.0 - e_new / e_prev if e_prev > 0 else 0.0
            new_mask = stages.mask(dist)
            changed = not same_mask(new_mask, mask)
            mask = new_mask
            e_prev = mse(dist, mask)
            if not changed and rel < tolerance:
                converged = True
                message = f"converged: relative decrease 1 - e_k/e_(k-1) = {rel:.3g} < delta = {tolerance:g}"
                break
        # converged: tighten the outlier cut once; go on if that changes the inliers
        if converged and stages.tighten():
            new_mask = stages.mask(dist)
            if not same_mask(new_mask, mask):
                mask = new_mask
                e_prev = mse(dist, mask)
                converged = False
                continue
        break

    n_used = count(mask, len(Y))
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
        message += (f"; WARNING: the points leave {deficient} direction(s) of m_0 unfixed as well "
                    "(more symmetric than the group given): minimum-norm steps were taken")
    inliers = np.zeros(len(P), dtype=bool)
    inliers[rows[mask]] = True
    rmse = float(np.sqrt(np.mean(dist[mask] ** 2)))
    extent = float(np.linalg.norm(np.ptp(P[finite], axis=0)))
    poor = poor_fit_reason(rmse, n_used, int(finite.sum()), extent, sigma,
                           white_noise_sigma_m(Ym[mask], s.reshape(n_used, -1)) if sigma is None else math.nan)
    status = fit_status(converged, group.dim + deficient, poor)
    return SymmetricResult(
        T_world_workpiece=T,
        method="algorithm2",
        converged=converged,
        status=status,
        message=message + (f"; poor fit: {poor}" if poor else ""),
        rmse_m=rmse,
        iterations=it,
        history=tuple(history),
        pose_history=tuple(poses),
        inliers=inliers,
        n_points_used=n_used,
        n_outliers=int(len(Y) - n_used),
        n_dropped_nonfinite=int(len(P) - len(Y)),
        sigma_m=sigma_used,
        determined_directions=group.m0.copy(),
        covariance=cov,
        free_directions=group.g0.copy(),
        solutions=(T,),
        relative_eigenvalues=rel_eig,
        time_s=time.perf_counter() - t0,
        poor_fit_reason=poor,
        feature=group.kind,
        group=group,
        solution_rmse_m=np.array([rmse]),
        general_system_rank=rank6,
        general_system_condition=cond,
        detection_tol=DETECTION_TOL,
        algorithm="2",
    )


def _check_planar_pose(T):
    R = T[:3, :3]
    if abs(R[2, 2] - 1.0) > 1e-9 or abs(T[2, 3]) > 1e-12:
        raise AlgorithmError("a 2D feature needs a planar init (rotation about z, no z translation)")



# ---------------------------------------------------------------------- the pipeline
def localize_symmetric(
    points,
    mesh,
    symmetric="auto",
    init=None,
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
        init: initial pose (4x4) or None (identity). An unknown pose is found first by
            :func:`algorithms.registration.global_search.global_localize`.
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
                f"with algorithms.registration.symmetric.algorithm2 and Feature.{symmetric}(...)"
            )
    if not (np.isfinite(tol) and 0 < tol < 1):
        raise AlgorithmError(f"tol must be in (0, 1), got {tol}")
    index = index if index is not None else (mesh if isinstance(mesh, MeshIndex) else MeshIndex(mesh))
    res1 = localize(points, index=index, method=method, init=init, sigma=sigma, outlier=outlier)
    T1 = res1.T_world_workpiece
    P = np.asarray(points, dtype=np.float64)
    finite = np.all(np.isfinite(P), axis=1)
    det_foot, det_normal, det_face = _surface_points(index, P[res1.inliers], T1, res1.sigma_m)
    T_ref = np.eye(4) if init is None else as_pose(init, name="init")

    if isinstance(symmetric, str) and symmetric == "none":
        obs = observability(det_foot, det_normal, tol)
        weak = unit_twists(obs.weak_directions)
        rel = obs.relative_eigenvalues
        if len(weak):
            determined = unit_twists(obs.determined_directions)
            cov = _covariance(index, P[res1.inliers], T1, determined, res1.sigma_m)
        else:
            determined, cov = np.eye(6), res1.covariance
        return SymmetricResult(
            T_world_workpiece=T1, method=res1.method, converged=res1.converged,
            status=fit_status(res1.converged, len(weak), res1.poor_fit_reason),
            message=res1.message, rmse_m=res1.rmse_m, iterations=res1.iterations, history=res1.history,
            pose_history=res1.pose_history,
            inliers=res1.inliers, n_points_used=res1.n_points_used, n_outliers=res1.n_outliers,
            n_dropped_nonfinite=res1.n_dropped_nonfinite, sigma_m=res1.sigma_m,
            determined_directions=determined, covariance=cov, free_directions=weak, solutions=(T1,),
            relative_eigenvalues=rel, time_s=time.perf_counter() - t0, poor_fit_reason=res1.poor_fit_reason,
            feature="none", group=other_group(weak, obs.centroid, obs.characteristic_length_m),
            solution_rmse_m=np.array([res1.rmse_m]),
            general_system_rank=int(np.sum(rel >= tol)),
            general_system_condition=float(1 / rel[0]) if rel[0] >= tol else float("inf"),
            detection_tol=tol, algorithm="1",
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
    status, message = res2.status, res2.message
    # the information at the result, on the surface points (as for the detection)
    f2, n2, _ = _surface_points(index, P[inliers], T2, res2.sigma_m)
    rel = _scaled_information(f2, n2[:, None, :], False) if len(f2) >= 6 else res2.relative_eigenvalues
    rank6 = int(np.sum(rel >= tol))
    cond = float(1.0 / rel[0]) if rank6 == 6 else float("inf")
    if len(sols) > 1:
        message += f"; {len(sols)} equally good poses (discrete symmetry of the model)"
        if status not in (Status.NOT_CONVERGED, Status.POOR_FIT):
            status = Status.AMBIGUOUS
    return SymmetricResult(
        T_world_workpiece=sols[0], method=res2.method, converged=res2.converged, status=status,
        message=message, rmse_m=res2.rmse_m, iterations=res1.iterations + res2.iterations,
        history=res1.history + res2.history[1:], pose_history=res1.pose_history + res2.pose_history[1:],
        inliers=inliers, n_points_used=res2.n_points_used,
        n_outliers=int(finite.sum() - res2.n_points_used), n_dropped_nonfinite=int(len(P) - finite.sum()),
        sigma_m=res2.sigma_m,
        determined_directions=_move_twists(res2.determined_directions, T2, sols[0]),
        covariance=res2.covariance,
        free_directions=_move_twists(res2.free_directions, T2, sols[0]),
        solutions=tuple(sols), relative_eigenvalues=rel, time_s=time.perf_counter() - t0,
        poor_fit_reason=res2.poor_fit_reason,
        feature=res2.feature, group=_move_group(group, T2, sols[0]), solution_rmse_m=np.asarray(rms),
        general_system_rank=rank6, general_system_condition=cond, detection_tol=tol, algorithm="2",
    )


def _covariance(index, Y, T, B, sigma) -> np.ndarray | None:
    """sigma^2 (A^T A)^-1 with A the point-to-plane rows of the points Y at T along the
    directions B (q, 6): the covariance of the pose along them, or None if singular."""
    cp = index.query(transform_points(inv_pose(T), Y))
    A = np.hstack([np.cross(cp.foot, cp.normal), cp.normal]) @ B.T
    try:
        C = sym_inverse(A.T @ A) * sigma**2
    except np.linalg.LinAlgError:
        return None
    return C if np.all(np.isfinite(C)) else None


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

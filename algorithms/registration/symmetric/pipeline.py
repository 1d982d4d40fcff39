"""Symmetric localization as one call (:func:`localize_symmetric`): Algorithm 1, the
subgroup ``G_0`` the data leave free, Algorithm 2 on ``SE(3)/G_0``, the equally good poses.

Algorithm 1 from the initial pose, the subgroup the data leave free (:mod:`.detect`) or the one
asked for, Algorithm 2 (:mod:`.quotient`), then every model symmetry ``S`` (:mod:`.discrete`)
gives the equally good pose ``T S``: every distinct one goes to ``solutions`` (distinct modulo
``G_0``: two poses differing by a free motion are the same solution), the one nearest the
initial pose first.

The verdict (``status``): NOT_CONVERGED if Algorithm 2 did not meet its stopping rule; else
AMBIGUOUS if the model's symmetries give several equally good poses; else UNOBSERVABLE if
``G_0`` leaves directions free; else POOR_FIT if ``sigma`` is given and the RMS exceeds 3
sigma; else OK.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from algorithms.arraytypes import ArrayLike, BoolArray, FloatArray, IntArray, Pose
from algorithms.errors import AlgorithmError
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import as_pose, inv_pose, rotation_error_rad, transform_points
from algorithms.registration.local import localize
from algorithms.registration.result import RegistrationResult, Status, fit_status
from algorithms.registration.symmetric.detect import DETECTION_TOL, detect_symmetry
from algorithms.registration.symmetric.discrete import model_symmetries, pseudo_normals
from algorithms.registration.symmetric.features import Feature, TriangleMesh
from algorithms.registration.symmetric.groups import (
    FEATURE_TABLE,
    SymmetryGroup,
    check_feature_type,
    other_group,
    symmetry_group,
)
from algorithms.registration.symmetric.quotient import SymmetricResult, algorithm2, scaled_information
from algorithms.registration.uncertainty import observability, sym_inverse, unit_twists

__all__ = ["SAME_SOLUTION_TOL", "SYMMETRIC_CHOICES", "localize_symmetric"]

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


@dataclass(frozen=True)
class _Stage1:
    """Algorithm 1's result and the surface points it gives for the detection.

    Attributes:
        result: Algorithm 1's result.
        points: (N, 3) [m] the input points, world frame.
        finite: (N,) the rows with finite coordinates.
        feet: (k, 3) feet of the inliers that measure a surface, not an edge (workpiece frame).
        normals: (k, 3) smooth normals there.
        faces: (k,) their mesh faces.
        T_ref: the initial pose (identity when none): the solutions are sorted by their gap to it.
    """

    result: RegistrationResult
    points: FloatArray
    finite: BoolArray
    feet: FloatArray
    normals: FloatArray
    faces: IntArray
    T_ref: Pose


def _check_symmetric(symmetric: object, tol: float) -> None:
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


def _algorithm1(points: ArrayLike, index: MeshIndex, init: ArrayLike | None, sigma: float | None,
                outlier: str | float | None, method: str) -> _Stage1:
    """Step 1: Algorithm 1 from ``init``, and the surface points at its pose."""
    res1 = localize(points, index=index, method=method, init=init, sigma=sigma, outlier=outlier)
    P = np.asarray(points, dtype=np.float64)
    finite = np.all(np.isfinite(P), axis=1)
    feet, normals, faces = _surface_points(index, P[res1.inliers], res1.T_world_workpiece, res1.sigma_m)
    T_ref = np.eye(4) if init is None else as_pose(init, name="init")
    return _Stage1(result=res1, points=P, finite=finite, feet=feet, normals=normals, faces=faces, T_ref=T_ref)


def _algorithm1_result(s1: _Stage1, index: MeshIndex, tol: float, t0: float) -> SymmetricResult:
    """``symmetric="none"``: Algorithm 1's result as it is, its weak directions reported free."""
    res1, T1 = s1.result, s1.result.T_world_workpiece
    obs = observability(s1.feet, s1.normals, tol)
    weak = unit_twists(obs.weak_directions)
    rel = obs.relative_eigenvalues
    if len(weak):
        determined = unit_twists(obs.determined_directions)
        cov = _covariance(index, s1.points[res1.inliers], T1, determined, res1.sigma_m)
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


def _subgroup(symmetric: str | Feature | SymmetryGroup, s1: _Stage1, index: MeshIndex, tol: float) -> SymmetryGroup:
    """Step 2: ``G_0`` as given, detected on the surface points, or of the named feature
    fitted to the faces the points landed on."""
    if isinstance(symmetric, SymmetryGroup):
        return symmetric
    if isinstance(symmetric, Feature):
        return symmetric.group
    if symmetric == "auto":
        return detect_symmetry(s1.feet, s1.normals, tol).group
    return Feature.from_mesh(index.mesh, np.unique(s1.faces), kind=symmetric).group


def _equally_good_poses(T: Pose, group: SymmetryGroup, index: MeshIndex, discrete: bool,
                        T_ref: Pose) -> list[Pose]:
    """Step 4: ``T S`` for the model symmetries ``S`` distinct modulo ``G_0``, nearest ``T_ref`` first."""
    sols = [T]
    if discrete:
        syms = model_symmetries(index.mesh, index=index)
        reps = [np.eye(4)]
        for S in syms[1:]:
            # T S equals T S' modulo G_0 when S' S^-1 is in G_0
            if any(group.contains(S @ inv_pose(R), SAME_SOLUTION_TOL, SAME_SOLUTION_TOL * index.extent)
                   for R in reps):
                continue
            reps.append(S)
        sols = [T @ S for S in reps]
    return sorted(sols, key=lambda T_: _pose_gap(T_, T_ref, index.extent))


def _solution_rmse(index: MeshIndex, Y: FloatArray, solutions: list[Pose]) -> FloatArray:
    """(K,) RMS distance [m] of the world points Y to the model at each solution."""
    rms = []
    for T in solutions:
        d = index.query(transform_points(inv_pose(T), Y)).distance
        rms.append(float(np.sqrt(np.mean(d**2))))
    return np.asarray(rms)


def _general_system(index: MeshIndex, res2: SymmetricResult, P: FloatArray, tol: float
                    ) -> tuple[FloatArray, int, float]:
    """Relative eigenvalues, rank and condition of the general 6x6 system at Algorithm 2's
    result, on the surface points (as for the detection)."""
    f2, n2, _ = _surface_points(index, P[res2.inliers], res2.T_world_workpiece, res2.sigma_m)
    rel = scaled_information(f2, n2[:, None, :], False) if len(f2) >= 6 else res2.relative_eigenvalues
    rank6 = int(np.sum(rel >= tol))
    cond = float(1.0 / rel[0]) if rank6 == 6 else float("inf")
    return rel, rank6, cond


def _pipeline_result(s1: _Stage1, res2: SymmetricResult, group: SymmetryGroup, sols: list[Pose],
                     index: MeshIndex, tol: float, t0: float) -> SymmetricResult:
    """Algorithm 2's result with Algorithm 1's history before it, every solution, and the
    verdict AMBIGUOUS where several poses are equally good."""
    res1, P, finite, T2 = s1.result, s1.points, s1.finite, res2.T_world_workpiece
    rms = _solution_rmse(index, P[res2.inliers], sols)
    status, message = res2.status, res2.message
    rel, rank6, cond = _general_system(index, res2, P, tol)
    if len(sols) > 1:
        message += f"; {len(sols)} equally good poses (discrete symmetry of the model)"
        if status not in (Status.NOT_CONVERGED, Status.POOR_FIT):
            status = Status.AMBIGUOUS
    return SymmetricResult(
        T_world_workpiece=sols[0], method=res2.method, converged=res2.converged, status=status,
        message=message, rmse_m=res2.rmse_m, iterations=res1.iterations + res2.iterations,
        history=res1.history + res2.history[1:], pose_history=res1.pose_history + res2.pose_history[1:],
        inliers=res2.inliers, n_points_used=res2.n_points_used,
        n_outliers=int(finite.sum() - res2.n_points_used), n_dropped_nonfinite=int(len(P) - finite.sum()),
        sigma_m=res2.sigma_m,
        determined_directions=_move_twists(res2.determined_directions, T2, sols[0]),
        covariance=res2.covariance,
        free_directions=_move_twists(res2.free_directions, T2, sols[0]),
        solutions=tuple(sols), relative_eigenvalues=rel, time_s=time.perf_counter() - t0,
        poor_fit_reason=res2.poor_fit_reason,
        feature=res2.feature, group=_move_group(group, T2, sols[0]), solution_rmse_m=rms,
        general_system_rank=rank6, general_system_condition=cond, detection_tol=tol, algorithm="2",
    )


def localize_symmetric(
    points: ArrayLike,
    mesh: TriangleMesh | MeshIndex,
    symmetric: str | Feature | SymmetryGroup = "auto",
    init: ArrayLike | None = None,
    sigma: float | None = None,
    outlier: str | float | None = "mad",
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
        mesh: the CAD model (a trimesh or a MeshIndex; workpiece frame, metres).
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
    _check_symmetric(symmetric, tol)
    index = index if index is not None else (mesh if isinstance(mesh, MeshIndex) else MeshIndex(mesh))
    s1 = _algorithm1(points, index, init, sigma, outlier, method)
    if isinstance(symmetric, str) and symmetric == "none":
        return _algorithm1_result(s1, index, tol, t0)
    group = _subgroup(symmetric, s1, index, tol)
    res2 = algorithm2(s1.points, index, group, init=s1.result.T_world_workpiece, sigma=sigma, outlier=outlier)
    sols = _equally_good_poses(res2.T_world_workpiece, group, index, discrete, s1.T_ref)
    return _pipeline_result(s1, res2, group, sols, index, tol, t0)


def _covariance(index: MeshIndex, Y: FloatArray, T: Pose, B: FloatArray, sigma: float) -> FloatArray | None:
    """sigma^2 (A^T A)^-1 with A the point-to-plane rows of the points Y at T along the
    directions B (q, 6): the covariance of the pose along them, or None if singular."""
    cp = index.query(transform_points(inv_pose(T), Y))
    A = np.hstack([np.cross(cp.foot, cp.normal), cp.normal]) @ B.T
    try:
        C = sym_inverse(A.T @ A) * sigma**2
    except np.linalg.LinAlgError:
        return None
    return C if np.all(np.isfinite(C)) else None


def _surface_points(index: MeshIndex, Y: FloatArray, T: Pose, sigma: float
                    ) -> tuple[FloatArray, FloatArray, IntArray]:
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


def _pose_gap(T: Pose, T_ref: Pose, size: float) -> float:
    """Rotation [rad] times the model's size plus translation [m] between two poses."""
    return rotation_error_rad(T, T_ref) * size + float(np.linalg.norm(T[:3, 3] - T_ref[:3, 3]))


def _move_twists(X: FloatArray, T_from: Pose, T_to: Pose) -> FloatArray:
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


def _move_group(group: SymmetryGroup, T_from: Pose, T_to: Pose) -> SymmetryGroup:
    """G_0 at T_from, seen from the equally good pose T_to (same world motions)."""
    S = inv_pose(T_from) @ T_to
    if np.allclose(S, np.eye(4), atol=1e-12) or group.kind == "other":
        return group
    Si = inv_pose(S)
    origin = transform_points(Si, group.origin[None])[0]
    axis = Si[:3, :3] @ group.axis
    if group.kind == "freeform":
        return symmetry_group("freeform", origin)
    return symmetry_group(group.kind, origin, axis)

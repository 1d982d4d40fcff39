"""The localization a trial runs, by the name of ``localize.method``.

* a local update rule (``hong_tan``, ``tangent``, ``menq``, ``va``, ``icp``, ``fine_001``):
  :func:`algorithms.registration.localize` from the trial's initial pose;
* a global method (``multistart``, ``genetic``, ``pso``): :func:`algorithms.registration.global_localize`
  (no initial pose; polished with Hong-Tan);
* a stage alone: ``genetic_coarse`` is document 001's coarse stage, one GA run with the
  document's constants and no fine stage (the GA's own pose; its time is the GA's);
  ``genetic_001`` is document 001's pipeline as printed: that GA run, then the document's fine
  stage ending the fit (no verification's choice among candidates, no Hong-Tan polish). Both
  take the study's ``ga_mutation`` reading and ``ga_rotation_range_deg`` constraint (the GA's
  orientations within that range of the trial's initial pose; 0: every orientation);
  ``pso_alone`` is document 003's swarm from the trial's initial pose (the pre-registration)
  without the polish (:func:`algorithms.registration.global_search.pso_refine`);
* a peer, where installed: ``open3d_icp`` (Open3D point-to-plane ICP) and ``small_gicp``
  (small_gicp GICP), both against a dense sample of the CAD model (0.5 mm spacing, exact face
  normals), 100 iterations, 1e-12 relative change, correspondences within 3x the initial
  translation error (at least 1 mm). Where the package is missing the trial's status is
  ``not_installed``.

A stage or a peer has no verdict of its own: its status is ``ok`` when it returned a pose.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from algorithms.geometry.se3 import inv_pose, transform_points
from algorithms.registration import global_localize, localize
from algorithms.registration.global_search import pso_refine
from algorithms.registration.global_search.search import GLOBAL_METHODS
from twin.realize import Workpiece

#: Spacing of the dense model sample the peers align to [m].
PEER_TARGET_SPACING_M = 0.0005


@dataclass(frozen=True)
class Outcome:
    """A localization's pose (workpiece to world), RMS residual [m], pose updates, verdict, time [s]."""

    T_world_workpiece: np.ndarray
    rmse_m: float
    iterations: int
    status: str
    time_s: float


def run_method(method: str, points: np.ndarray, workpiece: Workpiece, T_init: np.ndarray, sigma_m: float | None,
               rng: np.random.Generator, init_distance_m: float, variant: str = "ours",
               ga: dict | None = None, tolerance: float | None = None, feet=None) -> Outcome | str:
    """Localize ``points`` (world frame) on ``workpiece`` (its ``mesh`` and ``index``) by
    ``method`` (module docstring; a local method or the multistart as ``variant``: ours or as
    printed; document 001's stages with ``ga``: ``mutation`` and ``rotation_range_deg``; a
    local method with ``tolerance``, the ``delta`` of its stopping rule, None: its default, and
    ``feet``, the part's exact surfaces for document 000's Newton foot points, None: the mesh);
    a status string instead of an outcome when it cannot run."""
    index = workpiece.index
    t0 = time.perf_counter()
    if method in GLOBAL_METHODS:
        found = global_localize(points, index=index, method=method, rng=rng, noise_sigma_m=sigma_m, variant=variant)
        return Outcome(found.T_world_workpiece, found.rmse_m, found.iterations, found.status.value, found.time_s)
    if method in ("genetic_coarse", "genetic_001"):
        return _document_001(method, points, index, T_init, sigma_m, rng, ga or {})
    if method == "pso_alone":
        T, diag = pso_refine(points, T_init, index=index, rng=rng)
        return Outcome(T, _rms_m(points, T, index), len(diag.fitness_history) - 1, "ok", time.perf_counter() - t0)
    if method in ("open3d_icp", "small_gicp"):
        return _peer(method, points, workpiece, T_init, max(3.0 * init_distance_m, 1e-3))
    res = localize(points, index=index if feet is None else feet, method=method, init=T_init, sigma=sigma_m,
                   variant=variant, tolerance=tolerance)
    return Outcome(res.T_world_workpiece, res.rmse_m, res.iterations, res.status.value, res.time_s)


def _document_001(method: str, points: np.ndarray, index, T_init: np.ndarray, sigma_m: float | None,
                  rng: np.random.Generator, ga: dict) -> Outcome:
    """Document 001's coarse stage alone (``genetic_coarse``), or with its fine stage ending the
    fit (``genetic_001``): one GA run with the document's constants, as ``ga`` reads them."""
    range_deg = float(ga.get("rotation_range_deg", 0.0))
    found = global_localize(points, index=index, method="genetic", rng=rng, noise_sigma_m=sigma_m, polish=None,
                            ga_restarts=1, ga_mutation=ga.get("mutation", "per_bit"),
                            ga_rotation_range_rad=np.radians(range_deg) if range_deg > 0 else None,
                            init=T_init if range_deg > 0 else None)
    diag = found.diagnostics.genetic
    if diag is None:
        raise RuntimeError("internal error: the genetic search returned no GA diagnostics")
    if method == "genetic_001":
        return Outcome(found.T_world_workpiece, found.rmse_m, diag.generations + diag.fine_001_iterations, "ok",
                       found.time_s)
    return Outcome(diag.T_coarse, _rms_m(points, diag.T_coarse, index), diag.generations, "ok",
                   float(found.diagnostics.timings_s.get("ga_s", found.time_s)))


def _rms_m(points: np.ndarray, T_world_workpiece: np.ndarray, index) -> float:
    x = transform_points(inv_pose(T_world_workpiece), points)
    d = index.query(x).distance
    return float(np.sqrt(np.mean(np.square(d))))


_TARGETS: dict[int, tuple] = {}


def _target(workpiece, method: str):
    """The peer's prepared dense model sample of a workpiece, cached with the workpiece kept
    alive (so that an id is never reused for another part while it is in the cache)."""
    hit = _TARGETS.get(id(workpiece))
    if hit is None or hit[0] is not workpiece:
        if len(_TARGETS) >= 4:
            _TARGETS.clear()
        hit = _TARGETS[id(workpiece)] = (workpiece, {})
    prepared = hit[1]
    if method not in prepared:
        import trimesh

        mesh = workpiece.mesh
        n = int(min(400_000, mesh.area / PEER_TARGET_SPACING_M**2))
        pts, fi = trimesh.sample.sample_surface_even(mesh, n, seed=0)
        pts, normals = np.asarray(pts), np.asarray(mesh.face_normals)[fi]
        if method == "open3d_icp":
            import open3d as o3d

            target = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
            target.normals = o3d.utility.Vector3dVector(normals)
            prepared[method] = (target,)
        else:
            import small_gicp

            target = small_gicp.PointCloud(pts)
            tree = small_gicp.KdTree(target)
            small_gicp.estimate_normals_covariances(target, tree, num_neighbors=20)
            prepared[method] = (target, tree)
    return prepared[method]


def _peer(method: str, points: np.ndarray, workpiece, T_init: np.ndarray, max_corr_m: float) -> Outcome | str:
    try:
        if method == "open3d_icp":
            import open3d as o3d
        else:
            import small_gicp
    except ImportError:
        return "not_installed"
    prepared = _target(workpiece, method)
    if method == "open3d_icp":
        src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
        t0 = time.perf_counter()
        res = o3d.pipelines.registration.registration_icp(
            src, prepared[0], max_corr_m, inv_pose(T_init),
            o3d.pipelines.registration.TransformationEstimationPointToPlane(),
            o3d.pipelines.registration.ICPConvergenceCriteria(1e-12, 1e-12, 100))
        T, its = inv_pose(np.asarray(res.transformation)), -1
    else:
        t0 = time.perf_counter()
        src = small_gicp.PointCloud(points)
        small_gicp.estimate_covariances(src, num_neighbors=min(20, len(points) - 1))
        res = small_gicp.align(prepared[0], src, prepared[1], init_T_target_source=inv_pose(T_init),
                               registration_type="GICP", max_correspondence_distance=max_corr_m,
                               max_iterations=100, rotation_epsilon=1e-12, translation_epsilon=1e-12)
        T, its = inv_pose(np.asarray(res.T_target_source)), int(res.iterations)
    elapsed = time.perf_counter() - t0
    return Outcome(T, _rms_m(points, T, workpiece.index), its, "ok", elapsed)

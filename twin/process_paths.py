"""The process paths of the laser loop, as a stage any workflow can use: the scenario's path
settings, its process region on the part, document 004's path from the scan points and
document 003's CAD raster (step 5) moved by an estimate.

Scan path (document 004): scan-line cloud, outlier filter, then each line is cut into pieces
at sharp edges, steps, gaps and the border of the process region (judged on the CAD normals
at the estimate), pieces on consecutive lines are chained into patches, and per patch:
per-line B-spline fits resampled at ``path.point_spacing_m``, cross-line triangulation
normals (never across a step), tool frames (eq. 11). Robot base frame.

CAD path (document 003, step 5): a raster of contact points on the CAD mesh, cut the same
way, in the workpiece frame; :func:`determined_part` keeps the points an estimate with free
directions still fixes.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import trimesh

from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import inv_pose, transform_points
from algorithms.paths.normals import smooth_line_normals, triangulation_normals
from algorithms.paths.pointcloud import CloudParams, LineCloud, organize_scan_lines, remove_outliers, simplify_lines
from algorithms.paths.regions import ProcessRegion, chain_pieces, split_runs
from algorithms.paths.spline import fit_lines
from algorithms.paths.toolpath import ProcessPath, ToolSettings, build_path, cad_raster
from algorithms.registration.uncertainty import invariant_points
from twin.errors import TwinError
from twin.realize import Realized
from twin.scan import Scan
from twin.scenario import Scenario
from twin.segments import split_kept

MIN_PIECE_KNOT_SPANS = 2   # a scan-line piece shorter than this many B-spline knot spans is left out


@dataclass(frozen=True)
class ScanPath:
    """Document 004's pipeline from the scan points to a path (robot base frame).

    Attributes:
        lines: fitted lines resampled at the point spacing, patch by patch.
        normals: cross-line triangulation normals of ``lines``; ``tool_normals`` smoothed.
        patches: number of patches (smooth pieces chained across lines).
        cloud_lines, cloud_points: scan lines and points after the outlier filter.
        removed: samples dropped by reason (invalid, between lines, outliers, merged, ...).
        fit_rms_error_m, fit_max_error_m: B-spline fit residuals of the pieces.
        left_out: pieces that could not form a patch (fewer than two lines), in words.
    """

    lines: tuple
    normals: tuple
    tool_normals: tuple
    patches: int
    cloud_lines: int
    cloud_points: int
    removed: dict
    fit_rms_error_m: float
    fit_max_error_m: float
    left_out: tuple
    time_s: float


def cloud_params(scenario: Scenario) -> CloudParams:
    p = scenario.path
    return CloudParams(outlier_window_m=p.outlier_window_m, outlier_k=p.outlier_k, max_gap_m=p.max_gap_m,
                       simplify_spacing_m=p.simplify_spacing_m, empty=p.empty_lines)


def tool_settings(scenario: Scenario) -> ToolSettings:
    p = scenario.path
    return ToolSettings(p.heading, tuple(p.heading_direction), p.axis, tuple(p.axis_direction),
                        float(np.radians(p.lead_deg)), float(np.radians(p.tilt_deg)), p.tip_radius_m,
                        p.retract_m)


def process_region(scenario: Scenario, mesh: trimesh.Trimesh) -> ProcessRegion:
    """The scenario's process region (workpiece frame) on its part ``mesh``.

    Raises:
        TwinError: ``path.region_features`` names a feature the part does not have.
    """
    p = scenario.path
    lo, hi = (None, None) if p.region_box_m is None else (tuple(p.region_box_m[0]), tuple(p.region_box_m[1]))
    faces = None
    if p.region_features:
        known = mesh.metadata.get("features", {})
        unknown = [f for f in p.region_features if f not in known]
        if unknown:
            allowed = ", ".join(known) if known else "none: a loaded mesh names no features"
            raise TwinError(f"path.region_features: the part has no feature {unknown[0]!r}; its features: {allowed}")
        faces = np.unique(np.concatenate([known[f] for f in p.region_features]))
    return ProcessRegion(tuple(p.region_axis), float(np.radians(p.region_cone_deg)), lo, hi, faces)

def _beam_toward_sensor(scan: Scan, line_ids) -> np.ndarray:
    """Mean direction from the points of the given scan lines back to the sensor, base frame."""
    on = np.isin(scan.plan.line, np.asarray(line_ids))
    z = scan.plan.T_world_sensor[on, :3, 2].mean(axis=0)
    return -(inv_pose(scan.scenario.T_world_base)[:3, :3] @ z)


def _line_groups(scan: Scan) -> list[np.ndarray]:
    """Scan-line labels grouped by pass (lines of one pass run the same way)."""
    labels = np.unique(scan.line[scan.line >= 0])
    lp = np.asarray(scan.plan.line_pass)
    if len(labels) == 0 or len(lp) <= labels.max():
        return [labels]
    return [labels[lp[labels] == k] for k in np.unique(lp[labels])]


def _pieces(cloud: LineCloud, T_base_workpiece: np.ndarray, index: MeshIndex, region: ProcessRegion,
            max_gap_m: float, min_length_m: float) -> list[list[np.ndarray]]:
    """Each line of the cloud cut at edges, steps, gaps and the region's border; pieces
    shorter than ``min_length_m`` are left out."""
    T_wb = inv_pose(T_base_workpiece)
    out = []
    for line in cloud.lines:
        p_wp = transform_points(T_wb, line)
        cp = index.query(p_wp)
        n_wp = index.smooth_normals(cp.face, cp.foot)
        runs = split_runs(p_wp, n_wp, region.select(cp.foot, n_wp, cp.face), max_gap_m=max_gap_m)
        out.append([line[r] for r in runs if np.linalg.norm(line[r[-1]] - line[r[0]]) >= min_length_m])
    return out


def scan_path(scan: Scan, T_base_workpiece_estimate: np.ndarray, index: MeshIndex, region: ProcessRegion) -> ScanPath:
    """Document 004's pipeline from the scan points to process lines (robot base frame), per
    pass and per patch, on the process ``region`` (module docstring, step 3)."""
    sc = scan.scenario
    if scan.beams != 1:
        raise TwinError("the scan-derived path needs one beam per sample (sensor.kind = 'point')")
    t0 = time.perf_counter()
    params = cloud_params(sc)
    link_m = 3.0 * _max_line_spacing_m(sc)
    lines: list[np.ndarray] = []
    normals: list[np.ndarray] = []
    tool_normals: list[np.ndarray] = []
    left_out: list[str] = []
    removed: dict = {}
    n_lines = n_points = patches = 0
    sq = n_fit = 0.0
    max_fit = 0.0
    points = scan.points_base[:, 0]
    for group in _line_groups(scan):
        label = np.where(np.isin(scan.line, group), scan.line, -1)
        cloud = organize_scan_lines(points, label, empty=params.empty)
        cloud = remove_outliers(cloud, params.outlier_window_m, params.outlier_k, params.outlier_min_residual_m)
        n_lines += len(cloud.lines)
        n_points += cloud.n_points
        for k, v in cloud.removed.items():
            removed[k] = removed.get(k, 0) + int(v)
        pieces = _pieces(cloud, T_base_workpiece_estimate, index, region, params.max_gap_m,
                         MIN_PIECE_KNOT_SPANS * sc.path.knot_spacing_m)
        orient = _beam_toward_sensor(scan, group)
        for patch in chain_pieces(pieces, cloud.direction, link_m):
            if len(patch) < 2:
                (i, j), = patch
                left_out.append(f"a piece of {len(pieces[i][j])} points on scan line {int(cloud.line_ids[i])} "
                                "has no neighbour line in its patch")
                continue
            part = LineCloud(tuple(pieces[i][j] for i, j in patch), cloud.line_ids[[i for i, _ in patch]],
                             tuple(np.full(len(pieces[i][j]), -1) for i, j in patch), cloud.direction, cloud.across)
            part = simplify_lines(part, params.simplify_spacing_m)
            fits = fit_lines(part.lines, sc.path.point_spacing_m, sc.path.knot_spacing_m)
            n = triangulation_normals(fits.lines, orient=orient)
            lines.extend(fits.lines)
            normals.extend(n)
            tool_normals.extend(smooth_line_normals(fits.lines, n, 2 * sc.path.knot_spacing_m))
            patches += 1
            for f in fits.fits:
                sq += f.rms_error_m**2 * f.n_points
                n_fit += f.n_points
                max_fit = max(max_fit, f.max_error_m)
    if not lines:
        raise TwinError("no patch of the scan lies in the process region (path.region_*): nothing to process")
    return ScanPath(tuple(lines), tuple(normals), tuple(tool_normals), patches, n_lines, n_points, removed,
                    float(np.sqrt(sq / max(n_fit, 1))), float(max_fit), tuple(left_out), time.perf_counter() - t0)


def _max_line_spacing_m(scenario: Scenario) -> float:
    """The widest scan-line spacing of the scan's passes [m]."""
    return max([scenario.scan.line_spacing_m] + [p.line_spacing_m for p in scenario.scan.passes or ()])


def cad_path_lines(realized: Realized) -> tuple[list, list]:
    """The CAD raster's contact lines and normals in the WORKPIECE frame, cut at edges, steps
    and the border of the process region."""
    p = realized.scenario.path
    wp = realized.workpiece
    return cad_raster(wp.mesh, p.line_spacing_m, p.point_spacing_m, p.margin_m, p.line_axis,
                      normals=wp.index.smooth_normals, process_region=process_region(realized.scenario, wp.mesh))


def cad_path(realized: Realized) -> ProcessPath:
    """A raster of contact points on the CAD model, as a process path in the WORKPIECE frame."""
    lines, normals = cad_path_lines(realized)
    return build_path(lines, normals, tool_settings(realized.scenario))


def determined_part(lines_wp, normals_wp, localization, index: MeshIndex) -> tuple[list, list]:
    """The CAD path's points whose position the estimate fixes: with free directions (a bore
    whose rotation about its axis the scan leaves free), only the points that stay on the
    part when moved along them (:func:`algorithms.registration.uncertainty.invariant_points`)."""
    F = np.asarray(localization.free_directions, dtype=np.float64).reshape(-1, 6)
    if len(F) == 0:
        return list(lines_wp), list(normals_wp)
    keep = [invariant_points(index, ln, F) for ln in lines_wp]
    lines, normals = split_kept(lines_wp, normals_wp, keep)
    return lines, normals


def check_process_region(realized: Realized) -> None:
    """Bad input, before anything runs: a process region that selects no face of the part."""
    mesh = realized.workpiece.mesh
    centres = np.asarray(mesh.triangles_center)
    region = process_region(realized.scenario, mesh)
    if not region.select(centres, np.asarray(mesh.face_normals), np.arange(len(mesh.faces))).any():
        p = realized.scenario.path
        features = f", region_features {list(p.region_features)}" if p.region_features else ""
        raise TwinError(f"the process region (path.region_axis {np.round(p.region_axis, 3).tolist()}, "
                        f"region_cone_deg {p.region_cone_deg:g}, region_box_m {p.region_box_m}{features}) "
                        "selects no face of the part")


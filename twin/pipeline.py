"""The loop of the twin as one function: scan, localize, plan the process paths, solve the
joints, replay in the true cell. Returns a frozen :class:`RunResult`; writes no files.

1. scan the part (1 ms, true cell; one or several passes) and rebuild the points
   (document 004, eq. 2);
2. localize the part against its CAD mesh (documents 000/001) from the nominal pose, with the
   sensor's combined standard uncertainty as sigma, detecting the symmetry of what was
   scanned (document 000, Algorithm 2): the determined and free directions, the Cramer-Rao
   covariance and the fit check come with the estimate;
3. scan path (document 004): scan-line cloud, outlier filter, then each line is cut into
   pieces at sharp edges, steps, gaps and the border of the process region (judged on the
   CAD normals at the estimate), pieces on consecutive lines are chained into patches, and
   per patch: per-line B-spline fits resampled at ``path.point_spacing_m``, cross-line
   triangulation normals (never across a step), tool frames (eq. 11);
4. CAD path (document 003, step 5): a raster of contact points on the CAD mesh, cut the same
   way, moved by the localization estimate;
5. each path: five-axis mink IK on the nominal cell (the ball centre and the tool axis held,
   the spin about the axis free), the tool's shank and holder checked against the part at
   the estimate, the arm against the table; a stretch that is unreachable, singular,
   discontinuous or colliding is dropped and listed (the line is split there, with a
   retract, a transit and a re-approach), or with ``strict`` the run fails there
   (:mod:`twin.segments`); then the time law at the feed and the replay in
   the true cell with the tool at 1 ms: deviation, contacts and joint limits.

A stage that fails (an unreachable scan, a path with nothing left, ``strict``) does not
raise: the result keeps what the finished stages made and says which stage failed and why
(``failure``), so the caller can write the evidence.

Cells: the nominal cell is compiled once (scan planning and path IK share it); the true cell
in two configurations, each compiled once from the same truth: with the sensor (the scan)
and with the process tool (the replays).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
import trimesh

from algorithms.errors import AlgorithmError
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import inv_pose, transform_points
from algorithms.paths.normals import smooth_line_normals, triangulation_normals
from algorithms.paths.pointcloud import CloudParams, LineCloud, organize_scan_lines, remove_outliers, simplify_lines
from algorithms.paths.regions import ProcessRegion, chain_pieces, split_runs
from algorithms.paths.spline import fit_lines
from algorithms.paths.timing import Trajectory
from algorithms.paths.toolpath import ProcessPath, ToolSettings, build_path, cad_raster, transform_path
from algorithms.registration.symmetric import localize_symmetric
from algorithms.registration.uncertainty import invariant_points, nearest_along_free, systematic_covariance
from twin.cell import Cell, build_cell
from twin.errors import TwinError
from twin.realize import Realized
from twin.replay import ReplayLog, build_replay_cell, replay
from twin.scan import Scan, run_scan
from twin.scenario import Scenario
from twin.segments import StageFailed, solve_with_drops, split_kept
from twin.trajectory import PathIK, time_law_for

RECORDING_GAP_S = 1.0      # sim_time between the scan and each replay in the recording
MIN_PIECE_KNOT_SPANS = 2   # a scan-line piece shorter than this many B-spline knot spans is left out


@dataclass(frozen=True)
class PathRun:
    """One process path solved and replayed.

    Attributes:
        name: "scan_path" or "cad_path".
        path: the process path, robot base frame (after any drops).
        ik, trajectory, log: the joint solution, its timing and the replay.
        t_offset_s: where the replay starts on the recording's timeline [s].
        normals_points, normals: (M, 3) contact points and the normals the path used, base frame.
        dropped: the stretches left out (unreachable, singular, discontinuous, colliding).
    """

    name: str
    path: ProcessPath
    ik: PathIK
    trajectory: Trajectory
    log: ReplayLog
    t_offset_s: float
    normals_points: np.ndarray = field(repr=False)
    normals: np.ndarray = field(repr=False)
    dropped: tuple = ()


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


@dataclass(frozen=True)
class RunResult:
    """Everything the loop produced (robot base frame, SI units).

    Attributes:
        realized: the realized scenario.
        scan: the simulated scan (None when the scan stage failed).
        localization: the registration result (None when it did not run).
        scan_path: document 004's path from the scan, or None (``scan_path_skipped`` says why).
        cad_path_workpiece: the CAD raster path in the workpiece frame (None if not made).
        runs: the replayed paths (scan path first when there is one, then the CAD path).
        replay_cell: the true cell with the tool (for recordings).
        timings_s: wall time per stage [s].
        failure: None for a complete run, else (stage, reason).
    """

    realized: Realized
    scan: Scan | None
    localization: object
    scan_path: ScanPath | None
    scan_path_skipped: str | None
    cad_path_workpiece: ProcessPath | None
    runs: tuple[PathRun, ...]
    replay_cell: Cell = field(repr=False)
    timings_s: dict = field(default_factory=dict)
    failure: tuple[str, str] | None = None
    pose_covariance: np.ndarray | None = field(default=None, repr=False)

    @property
    def complete(self) -> bool:
        return self.failure is None

    @property
    def T_base_workpiece_estimate(self) -> np.ndarray:
        return self.localization.T_world_workpiece

    def run(self, name: str) -> PathRun | None:
        return next((r for r in self.runs if r.name == name), None)


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


def sensor_sigma_m(scenario: Scenario) -> float:
    """Combined standard uncertainty of one distance (GUM): repeatability, linearity band
    (uniform, amplitude / sqrt 3) and quantisation (step / sqrt 12), for the switched-on sources."""
    s, n = scenario.sensor, scenario.noise
    var = (s.sigma_m**2 if n.gaussian else 0.0) + ((s.linearity_m / np.sqrt(3)) ** 2 if n.linearity else 0.0) \
        + ((s.resolution_m / np.sqrt(12)) ** 2 if n.quantization else 0.0)
    return float(np.sqrt(var))


def pose_covariance(scan: Scan, localization, index: MeshIndex) -> np.ndarray:
    """The estimate's covariance along its determined directions: the Cramer-Rao term of the
    random errors (repeatability and quantisation) plus the sensor's linearity curve as a
    systematic error: Legendre polynomials of degree 0-3 in the measured distance across the
    window, each coefficient with the standard deviation ``linearity_m`` (the curve is known
    only by its +/- band, and one smooth shape can carry the whole band: the IL-065's
    sin-shaped curve has degree-1 and degree-3 coefficients of 0.95 and 1.16 times the band);
    :func:`algorithms.registration.uncertainty.systematic_covariance`."""
    sc = scan.scenario
    D = np.asarray(localization.determined_directions, dtype=np.float64).reshape(-1, 6)
    C = np.asarray(localization.covariance, dtype=np.float64)
    if len(D) == 0:
        return C
    s, n = sc.sensor, sc.noise
    sigma_all = sensor_sigma_m(sc)
    lin = s.linearity_m if n.linearity else 0.0
    # the random part of sigma_all: without the linearity band's share (linearity / sqrt 3)
    C = C * max(sigma_all**2 - lin**2 / 3.0, 0.0) / sigma_all**2
    if lin == 0.0:
        return C
    mask = scan.valid & (scan.line >= 0)[:, None]
    d = scan.d[mask][localization.inliers]
    pts = scan.points_base[mask][localization.inliers]
    near, far = s.window_m
    u = np.clip(2.0 * (d - s.reference_m) / (far - near), -1.0, 1.0)
    basis = np.polynomial.legendre.legvander(u, 3)
    cp = index.query(transform_points(inv_pose(localization.T_world_workpiece), pts))
    normals = index.smooth_normals(cp.face, cp.foot)
    return C + systematic_covariance(cp.foot, normals, D, basis, np.full(4, lin))


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
    lines, normals, tool_normals, left_out = [], [], [], []
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


def _timed(name: str, path: ProcessPath, ik: PathIK, dropped, realized: Realized,
           say: Callable[[str], None]) -> Trajectory:
    p = realized.scenario.path
    traj = time_law_for(path, ik, p.feed_m_s, p.transit_speed_m_s, p.acceleration_m_s2,
                        p.touchdown_acceleration_m_s2)
    note = f", {len(dropped)} stretch(es) dropped" if dropped else ""
    say(f"{name}: {len(path.T_tool)} poses, IK {ik.time_per_pose_ms:.3f} ms/pose, "
        f"{traj.duration_s:.1f} s of motion{note}")
    return traj


def _replayed(name: str, path: ProcessPath, ik: PathIK, traj: Trajectory, dropped, replay_cell: Cell,
              realized: Realized, t_offset_s: float, timings: dict, say: Callable[[str], None]) -> PathRun:
    t0 = time.perf_counter()
    log = replay(replay_cell, traj, path, realized.workpiece.index)
    timings[f"{name}_replay_s"] = time.perf_counter() - t0
    say(f"{name}: replayed, {len(log.unintended_contacts)} unintended contact(s)")
    mask = path.process_mask()
    return PathRun(name, path, ik, traj, log, t_offset_s, path.contact[mask], path.normal[mask], tuple(dropped))


# ------------------------------------------------------------------ the loop
def _ignore(event: str, value) -> None:
    pass


def run(realized: Realized, say: Callable[[str], None] = lambda msg: None, strict: bool = False,
        watch: Callable[[str, object], None] = _ignore) -> RunResult:
    """The whole loop (module docstring). ``say`` receives one progress line per stage;
    ``watch(event, value)`` each stage's result as it is made, in order: ``"cells"``
    (replay cell, realized scenario), ``"scan"``, ``"localization"``, then ``"run"`` per
    replayed path (a live recording follows the run with them).

    A failing stage ends the run with ``failure`` set; bad input found before the loop
    starts (cells that do not compile) raises :class:`TwinError`.
    """
    check_process_region(realized)
    timings: dict = {}
    t0 = time.perf_counter()
    nominal = build_cell(realized, "nominal")
    true_cell = build_cell(realized, "true")
    replay_cell = build_replay_cell(realized)
    timings["build_cells_s"] = time.perf_counter() - t0
    watch("cells", (replay_cell, realized))
    state = {"scan": None, "localization": None, "covariance": None, "scan_path": None, "skipped": None,
             "cad": None, "runs": [], "pending": None, "watch": watch}
    failure = None
    with ThreadPoolExecutor(max_workers=1) as pool:
        try:
            try:
                _run(realized, nominal, true_cell, replay_cell, say, strict, timings, state, pool)
            finally:
                # a replay still running in the background belongs to the evidence
                _collect(state["pending"], state)
        except StageFailed as exc:
            failure = (exc.stage, exc.reason)
        except (TwinError, AlgorithmError) as exc:
            failure = (_current_stage(state), str(exc))
    return RunResult(realized, state["scan"], state["localization"], state["scan_path"], state["skipped"],
                     state["cad"], tuple(state["runs"]), replay_cell, timings, failure, state["covariance"])


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


def _current_stage(state: dict) -> str:
    if state["scan"] is None:
        return "scan"
    if state["localization"] is None:
        return "localize"
    if state["cad"] is None and not state["runs"]:
        return "scan_path" if state["scan"].beams == 1 and state["skipped"] is None else "cad_path"
    return "cad_path"


def _run(realized: Realized, nominal: Cell, true_cell: Cell, replay_cell: Cell, say, strict: bool,
         timings: dict, state: dict, pool: ThreadPoolExecutor) -> None:
    scenario = realized.scenario
    index = realized.workpiece.index
    t0 = time.perf_counter()
    scan = run_scan(realized, nominal, true_cell)
    timings["scan_s"] = time.perf_counter() - t0
    state["scan"] = scan
    state["watch"]("scan", scan)
    say(f"scanned {len(scan.t)} samples ({scan.t[-1]:.1f} s simulated)")

    t0 = time.perf_counter()
    loc = localize_symmetric(scan.line_points_base, realized.workpiece.mesh, symmetric="auto",
                             init=realized.T_base_workpiece_nominal, sigma=sensor_sigma_m(scenario), index=index)
    timings["localize_s"] = time.perf_counter() - t0
    if len(loc.free_directions):
        # along its free directions the estimate keeps the nominal pose (the points cannot move it)
        loc = dataclasses.replace(loc, T_world_workpiece=nearest_along_free(
            loc.T_world_workpiece, loc.free_directions, realized.T_base_workpiece_nominal))
    state["localization"] = loc
    state["watch"]("localization", loc)
    state["covariance"] = pose_covariance(scan, loc, index)
    T_est = loc.T_world_workpiece
    free = len(loc.free_directions)
    say(f"localized: {loc.status.value}, rms {loc.rmse_m * 1e6:.2f} um, {6 - free} determined, "
        f"{free} free direction(s)")

    t_offset = float(scan.t[-1]) + RECORDING_GAP_S
    settings = tool_settings(scenario)
    if scan.beams == 1:
        t0 = time.perf_counter()
        try:
            sp = scan_path(scan, T_est, index, process_region(scenario, realized.workpiece.mesh))
        except (TwinError, AlgorithmError) as exc:
            raise StageFailed("scan_path", str(exc)) from None
        state["scan_path"] = sp
        timings["scan_path_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        path, ik, dropped = solve_with_drops("scan_path", sp.lines, sp.tool_normals, settings, T_est, nominal,
                                             T_est, index, strict)
        timings["scan_path_ik_s"] = time.perf_counter() - t0
        traj = _timed("scan_path", path, ik, dropped, realized, say)
        # The scan path's replay (MuJoCo's rollout, outside the GIL) runs on the second core
        # while the CAD path is planned; it is collected before the CAD path is replayed.
        state["pending"] = pool.submit(_replayed, "scan_path", path, ik, traj, dropped, replay_cell, realized, t_offset,
                              timings, say)
        t_offset += traj.duration_s + RECORDING_GAP_S
    else:
        state["skipped"] = "the scan-derived path needs one beam per sample (sensor.kind = 'point')"

    t0 = time.perf_counter()
    try:
        lines_wp, normals_wp = determined_part(*cad_path_lines(realized), loc, index)
        if not lines_wp:
            raise StageFailed("cad_path", "no CAD path point is determined by the scan: the free directions "
                                          "move every point of the process region off the part")
        state["cad"] = build_path(lines_wp, normals_wp, settings)
    except AlgorithmError as exc:
        raise StageFailed("cad_path", str(exc)) from None
    timings["cad_path_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    path, ik, dropped = solve_with_drops("cad_path", lines_wp, normals_wp, settings, None, nominal, T_est, index,
                                         strict, T_base_frame=T_est)
    state["cad"] = transform_path(inv_pose(T_est), path)   # after any drops, workpiece frame
    timings["cad_path_ik_s"] = time.perf_counter() - t0
    traj = _timed("cad_path", path, ik, dropped, realized, say)
    _collect(state["pending"], state)
    state["runs"].append(_replayed("cad_path", path, ik, traj, dropped, replay_cell, realized, t_offset, timings,
                                   say))
    state["watch"]("run", state["runs"][-1])


def _collect(pending, state: dict) -> None:
    """The scan path's run from its background replay (once)."""
    if pending is not None and not state.get("collected"):
        state["collected"] = True
        state["runs"].append(pending.result())
        state["watch"]("run", state["runs"][-1])

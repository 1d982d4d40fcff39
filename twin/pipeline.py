"""The loop of the twin as one function: scan, localize, plan the process paths, solve the
joints, replay in the true cell. Returns a frozen :class:`RunResult`; writes no files.

1. scan the part (1 ms, true cell) and rebuild the points (document 004, eq. 2);
2. localize the part against its CAD mesh (documents 000/001) from the nominal pose, with the
   sensor's combined standard uncertainty as sigma (so a poor fit is reported);
3. scan path (document 004): scan-line cloud, filters, per-line B-spline fits resampled at
   ``path.point_spacing_m``, cross-line triangulation normals, tool frames (eq. 11) and
   flange poses (eq. 13);
4. CAD path (document 003, step 5): a raster of contact points on the CAD mesh moved by the
   localization estimate;
5. each path: mink IK on the nominal cell, time law at the feed, replay in the true cell
   with the tool at 1 ms, deviation, contacts and joint limits.

Cells: the nominal cell is compiled once (scan planning and path IK share it); the true cell
in two configurations, each compiled once from the same truth: with the sensor (the scan)
and with the process tool (the replays).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from algorithms.errors import AlgorithmError
from algorithms.geometry.se3 import inv_pose
from algorithms.paths.normals import smooth_line_normals, triangulation_normals
from algorithms.paths.pointcloud import CloudParams, LineCloud, prepare_scan_lines
from algorithms.paths.spline import FittedLines, fit_lines
from algorithms.paths.timing import Trajectory
from algorithms.paths.toolpath import ProcessPath, ToolSettings, build_path, cad_raster, transform_path
from algorithms.registration.local import localize
from twin.cell import Cell, build_cell
from twin.errors import TwinError
from twin.realize import Realized
from twin.replay import ReplayLog, build_replay_cell, replay
from twin.scan import Scan, run_scan
from twin.scenario import Scenario
from twin.trajectory import PathIK, plan_joint_trajectory

RECORDING_GAP_S = 1.0  # sim_time between the scan and each replay in the recording


@dataclass(frozen=True)
class PathRun:
    """One process path solved and replayed.

    Attributes:
        name: "scan_path" or "cad_path".
        path: the process path, robot base frame.
        ik, trajectory, log: the joint solution, its timing and the replay.
        t_offset_s: where the replay starts on the recording's timeline [s].
        normals_points, normals: (M, 3) contact points and the normals the path used, base frame.
    """

    name: str
    path: ProcessPath
    ik: PathIK
    trajectory: Trajectory
    log: ReplayLog
    t_offset_s: float
    normals_points: np.ndarray = field(repr=False)
    normals: np.ndarray = field(repr=False)


@dataclass(frozen=True)
class ScanPath:
    """Document 004's pipeline from the scan points to a path (robot base frame)."""

    cloud: LineCloud
    fits: FittedLines
    normals: tuple
    tool_normals: tuple
    path: ProcessPath
    time_s: float


@dataclass(frozen=True)
class RunResult:
    """Everything the loop produced (robot base frame, SI units).

    Attributes:
        realized: the realized scenario.
        scan: the simulated scan.
        localization: the registration result (its pose is ``T_base_workpiece_estimate``).
        scan_path: document 004's path from the scan, or None (``scan_path_skipped`` says why).
        cad_path_workpiece: the CAD raster path in the workpiece frame.
        runs: the replayed paths (scan path first when there is one, then the CAD path).
        replay_cell: the true cell with the tool (for recordings).
        timings_s: wall time per stage [s].
    """

    realized: Realized
    scan: Scan
    localization: object
    scan_path: ScanPath | None
    scan_path_skipped: str | None
    cad_path_workpiece: ProcessPath
    runs: tuple[PathRun, ...]
    replay_cell: Cell = field(repr=False)
    timings_s: dict = field(default_factory=dict)

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


def sensor_sigma_m(scenario: Scenario) -> float:
    """Combined standard uncertainty of one distance (GUM): repeatability, linearity band
    (uniform, amplitude / sqrt 3) and quantisation (step / sqrt 12), for the switched-on sources."""
    s, n = scenario.sensor, scenario.noise
    var = (s.sigma_m**2 if n.gaussian else 0.0) + ((s.linearity_m / np.sqrt(3)) ** 2 if n.linearity else 0.0) \
        + ((s.resolution_m / np.sqrt(12)) ** 2 if n.quantization else 0.0)
    return float(np.sqrt(var))


def _beam_toward_sensor(scan: Scan) -> np.ndarray:
    """Mean direction from the scanned points back to the sensor, robot base frame."""
    on = scan.plan.line >= 0
    z = scan.plan.T_world_sensor[on, :3, 2].mean(axis=0)
    return -(inv_pose(scan.scenario.T_world_base)[:3, :3] @ z)


def scan_path(scan: Scan, T_base_workpiece_estimate: np.ndarray) -> ScanPath:
    """Document 004's pipeline from the scan points to a process path (robot base frame)."""
    sc = scan.scenario
    if scan.beams != 1:
        raise TwinError("the scan-derived path needs one beam per sample (sensor.kind = 'point')")
    t0 = time.perf_counter()
    cloud = prepare_scan_lines(scan.points_base[:, 0], scan.line, cloud_params(sc))
    fits = fit_lines(cloud.lines, sc.path.point_spacing_m, sc.path.knot_spacing_m)
    normals = triangulation_normals(fits.lines, orient=_beam_toward_sensor(scan))
    # The tool follows the normals smoothed along each line (see smooth_line_normals).
    tool_normals = smooth_line_normals(fits.lines, normals, 2 * sc.path.knot_spacing_m)
    path = build_path(fits.lines, tool_normals, tool_settings(sc), T_frame_ref=T_base_workpiece_estimate)
    return ScanPath(cloud, fits, normals, tool_normals, path, time.perf_counter() - t0)


def cad_path(realized: Realized) -> ProcessPath:
    """A raster of contact points on the CAD model, as a process path in the WORKPIECE frame."""
    p = realized.scenario.path
    wp = realized.workpiece
    lines, normals = cad_raster(wp.mesh, p.line_spacing_m, p.point_spacing_m, p.margin_m, p.line_axis,
                                normals=wp.index.smooth_normals)
    return build_path(lines, normals, tool_settings(realized.scenario))


def _solve_and_replay(name: str, path: ProcessPath, nominal: Cell, replay_cell: Cell, realized: Realized,
                      t_offset_s: float, normals_points: np.ndarray, normals: np.ndarray,
                      say: Callable[[str], None]) -> PathRun:
    p = realized.scenario.path
    ik, traj = plan_joint_trajectory(nominal, path, p.T_flange_tool, p.feed_m_s, p.transit_speed_m_s,
                                     p.acceleration_m_s2, touchdown_acceleration_m_s2=p.touchdown_acceleration_m_s2)
    say(f"{name}: {len(path.T_tool)} poses, IK {ik.time_per_pose_ms:.3f} ms/pose, {traj.duration_s:.1f} s of motion")
    log = replay(replay_cell, traj, path, realized.workpiece.index)
    say(f"{name}: replayed, {len(log.unintended_contacts)} unintended contact(s)")
    return PathRun(name, path, ik, traj, log, t_offset_s, normals_points, normals)


def run(realized: Realized, say: Callable[[str], None] = lambda msg: None) -> RunResult:
    """The whole loop (module docstring). ``say`` receives one progress line per stage.

    Raises:
        TwinError: bad input found on the way (an unreachable scan line or path, ...).
    """
    try:
        return _run(realized, say)
    except AlgorithmError as exc:
        raise TwinError(str(exc)) from None


def _run(realized: Realized, say: Callable[[str], None]) -> RunResult:
    scenario = realized.scenario
    timings = {}
    t0 = time.perf_counter()
    nominal = build_cell(realized, "nominal")
    true_cell = build_cell(realized, "true")
    replay_cell = build_replay_cell(realized)
    timings["build_cells_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    scan = run_scan(realized, nominal, true_cell)
    timings["scan_s"] = time.perf_counter() - t0
    say(f"scanned {len(scan.t)} samples ({scan.t[-1]:.1f} s simulated)")

    t0 = time.perf_counter()
    loc = localize(scan.line_points_base, index=realized.workpiece.index, init=realized.T_base_workpiece_nominal,
                   sigma=sensor_sigma_m(scenario))
    timings["localize_s"] = time.perf_counter() - t0
    T_est = loc.T_world_workpiece
    say(f"localized in {loc.iterations} iterations, rms {loc.rmse_m * 1e6:.2f} um")

    runs = []
    t_offset = float(scan.t[-1]) + RECORDING_GAP_S
    sp, skipped = None, None
    if scan.beams == 1:
        t0 = time.perf_counter()
        sp = scan_path(scan, T_est)
        timings["scan_path_s"] = time.perf_counter() - t0
        pts = np.concatenate(sp.fits.lines)
        t0 = time.perf_counter()
        r = _solve_and_replay("scan_path", sp.path, nominal, replay_cell, realized, t_offset, pts,
                              np.concatenate(sp.normals), say)
        timings["scan_path_ik_s"] = r.ik.time_s
        timings["scan_path_replay_s"] = time.perf_counter() - t0 - r.ik.time_s
        runs.append(r)
        t_offset += r.trajectory.duration_s + RECORDING_GAP_S
    else:
        skipped = "the scan-derived path needs one beam per sample (sensor.kind = 'point')"

    t0 = time.perf_counter()
    cp_wp = cad_path(realized)
    cp = transform_path(T_est, cp_wp)
    timings["cad_path_s"] = time.perf_counter() - t0
    mask = cp.process_mask()
    t0 = time.perf_counter()
    r = _solve_and_replay("cad_path", cp, nominal, replay_cell, realized, t_offset, cp.contact[mask],
                          cp.normal[mask], say)
    timings["cad_path_ik_s"] = r.ik.time_s
    timings["cad_path_replay_s"] = time.perf_counter() - t0 - r.ik.time_s
    runs.append(r)
    return RunResult(realized, scan, loc, sp, skipped, cp_wp, tuple(runs), replay_cell, timings)

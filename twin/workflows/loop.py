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
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from algorithms.geometry.se3 import inv_pose
from algorithms.paths.timing import Trajectory
from algorithms.paths.toolpath import ProcessPath, build_path, transform_path
from algorithms.registration.result import RegistrationResult
from algorithms.registration.symmetric import localize_symmetric
from algorithms.registration.uncertainty import nearest_along_free
from twin.cell import Cell, build_cell
from twin.errors import TwinError
from twin.process_paths import (
    ScanPath,
    cad_path_lines,
    check_process_region,
    determined_part,
    process_region,
    scan_path,
    tool_settings,
)
from twin.realize import Realized
from twin.replay import ReplayLog, build_replay_cell, replay
from twin.scan import Scan, run_scan
from twin.scan_uncertainty import pose_covariance, scan_reading_sigma_m
from twin.segments import solve_with_drops
from twin.stages import StageFailed, StageRunner
from twin.trajectory import PathIK, time_law_for

RECORDING_GAP_S = 1.0      # sim_time between the scan and each replay in the recording


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
        planned_points: the contact points planned in the process region, before any was
            dropped or left undetermined by the scan (the coverage's denominator).
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
    planned_points: int = 0



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
    localization: RegistrationResult | None
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
        if self.localization is None:
            raise TwinError("the run has no estimate: its localization stage did not finish")
        return self.localization.T_world_workpiece

    def run(self, name: str) -> PathRun | None:
        return next((r for r in self.runs if r.name == name), None)



def _timed(name: str, path: ProcessPath, ik: PathIK, dropped, realized: Realized,
           say: Callable[[str], None]) -> Trajectory:
    p = realized.scenario.path
    traj = time_law_for(path, ik, p.feed_m_s, p.transit_speed_m_s, p.acceleration_m_s2,
                        p.touchdown_acceleration_m_s2)
    note = f", {len(dropped)} stretch(es) dropped" if dropped else ""
    say(f"{name}: {len(path.T_tool)} poses, IK {ik.time_per_pose_ms:.3f} ms/pose, "
        f"{traj.duration_s:.1f} s of motion{note}")
    return traj


def _replayed(name: str, path: ProcessPath, ik: PathIK, traj: Trajectory, dropped, planned_points: int,
              replay_cell: Cell, realized: Realized, t_offset_s: float, timings: dict,
              say: Callable[[str], None]) -> PathRun:
    t0 = time.perf_counter()
    log = replay(replay_cell, traj, path, realized.workpiece.index)
    timings[f"{name}_replay_s"] = time.perf_counter() - t0
    say(f"{name}: replayed, {len(log.unintended_contacts)} unintended contact(s)")
    mask = path.process_mask()
    return PathRun(name, path, ik, traj, log, t_offset_s, path.contact[mask], path.normal[mask], tuple(dropped),
                   planned_points)


# ------------------------------------------------------------------ the loop
Say = Callable[[str], None]
Watch = Callable[[str, object], None]


def _ignore(event: str, value: object) -> None:
    pass


@dataclass
class _Loop:
    """The loop's cells and its stages' records as they are made (one slot per record)."""

    realized: Realized
    nominal: Cell
    true_cell: Cell
    replay_cell: Cell
    say: Say
    watch: Watch
    strict: bool
    runner: StageRunner = field(default_factory=StageRunner)
    scan: Scan | None = None
    localization: RegistrationResult | None = None
    covariance: np.ndarray | None = None
    scan_path: ScanPath | None = None
    scan_path_skipped: str | None = None
    cad_path_workpiece: ProcessPath | None = None
    runs: list[PathRun] = field(default_factory=list)
    pending: Future | None = None


def run(realized: Realized, say: Say = lambda msg: None, strict: bool = False, watch: Watch = _ignore) -> RunResult:
    """The whole loop (module docstring). ``say`` receives one progress line per stage;
    ``watch(event, value)`` each stage's result as it is made, in order: ``"cells"``
    (replay cell, realized scenario), ``"scan"``, ``"localization"``, then ``"run"`` per
    replayed path (a live recording follows the run with them).

    A failing stage ends the run with ``failure`` naming it; bad input found before the loop
    starts (a process region that selects nothing, cells that do not compile) raises
    :class:`TwinError`.
    """
    check_process_region(realized)
    runner = StageRunner()
    t0 = time.perf_counter()
    loop = _Loop(realized, build_cell(realized, "nominal"), build_cell(realized, "true"), build_replay_cell(realized),
                 say, watch, strict, runner)
    runner.timings_s["build_cells_s"] = time.perf_counter() - t0
    watch("cells", (loop.replay_cell, realized))
    with ThreadPoolExecutor(max_workers=1) as pool:
        runner.run(lambda: _stages(loop, pool))
    return RunResult(realized, loop.scan, loop.localization, loop.scan_path, loop.scan_path_skipped,
                     loop.cad_path_workpiece, tuple(loop.runs), loop.replay_cell, runner.timings_s, runner.failure,
                     loop.covariance)


def _stages(loop: _Loop, pool: ThreadPoolExecutor) -> None:
    try:
        scan = _scan(loop)
        loc = _localize(loop, scan)
        t_offset = float(scan.t[-1]) + RECORDING_GAP_S
        if scan.beams == 1:
            t_offset = _scan_path(loop, pool, scan, loc.T_world_workpiece, t_offset)
        else:
            loop.scan_path_skipped = "the scan-derived path needs one beam per sample (sensor.kind = 'point')"
        _cad_path(loop, loc, t_offset)
    finally:
        # a replay still running in the background belongs to the evidence
        _collect(loop)


def _scan(loop: _Loop) -> Scan:
    with loop.runner.stage("scan"):
        scan = loop.scan = run_scan(loop.realized, loop.nominal, loop.true_cell)
    loop.watch("scan", scan)
    loop.say(f"scanned {len(scan.t)} samples ({scan.t[-1]:.1f} s simulated)")
    return scan


def localize_scan(realized: Realized, scan: Scan) -> RegistrationResult:
    """Symmetric-aware localization from the nominal pose, with the points' standard uncertainty
    (the sensor's, and the encoders' noise: :mod:`twin.scan_uncertainty`) as sigma;
    along free directions the estimate keeps the nominal pose (the points cannot move it)."""
    index = realized.workpiece.index
    loc = localize_symmetric(scan.line_points_base, realized.workpiece.mesh, symmetric="auto",
                             init=realized.T_base_workpiece_nominal, sigma=scan_reading_sigma_m(scan, index),
                             index=index)
    if len(loc.free_directions):
        loc = dataclasses.replace(loc, T_world_workpiece=nearest_along_free(
            loc.T_world_workpiece, loc.free_directions, realized.T_base_workpiece_nominal))
    return loc


def _localize(loop: _Loop, scan: Scan) -> RegistrationResult:
    """:func:`localize_scan`, then the pose covariance of the scan's points."""
    realized, index = loop.realized, loop.realized.workpiece.index
    with loop.runner.stage("localize"):
        loc = localize_scan(realized, scan)
    loop.localization = loc
    loop.watch("localization", loc)
    with loop.runner.within("localize"):
        loop.covariance = pose_covariance(scan, loc, index, scan_reading_sigma_m(scan, index))
    free = len(loc.free_directions)
    loop.say(f"localized: {loc.status.value}, rms {loc.rmse_m * 1e6:.2f} um, {6 - free} determined, "
             f"{free} free direction(s)")
    return loc


def _scan_path(loop: _Loop, pool: ThreadPoolExecutor, scan: Scan, T_est: np.ndarray, t_offset: float) -> float:
    """Document 004's path from the scan, solved; its replay (MuJoCo's rollout, outside the
    GIL) runs on the second core while the CAD path is planned. Returns the next path's
    start on the recording's timeline [s]."""
    realized, index = loop.realized, loop.realized.workpiece.index
    with loop.runner.stage("scan_path"):
        sp = scan_path(scan, T_est, index, process_region(realized.scenario, realized.workpiece.mesh))
    loop.scan_path = sp
    with loop.runner.stage("scan_path", timing="scan_path_ik_s"):
        path, ik, dropped = solve_with_drops("scan_path", sp.lines, sp.tool_normals, tool_settings(realized.scenario),
                                             T_est, loop.nominal, T_est, index, loop.strict)
        traj = _timed("scan_path", path, ik, dropped, realized, loop.say)
    planned = sum(len(line) for line in sp.lines)
    loop.pending = pool.submit(_replayed, "scan_path", path, ik, traj, dropped, planned, loop.replay_cell, realized,
                               t_offset, loop.runner.timings_s, loop.say)
    return t_offset + traj.duration_s + RECORDING_GAP_S


def _cad_path(loop: _Loop, loc: RegistrationResult, t_offset: float) -> None:
    """The CAD raster at the estimate (its determined part), solved, then replayed after the
    scan path's replay is collected."""
    realized, index = loop.realized, loop.realized.workpiece.index
    T_est = loc.T_world_workpiece
    settings = tool_settings(realized.scenario)
    with loop.runner.stage("cad_path"):
        region_lines = cad_path_lines(realized)
        planned = sum(len(line) for line in region_lines[0])
        lines_wp, normals_wp = determined_cad_lines(region_lines, loc, index)
        loop.cad_path_workpiece = build_path(lines_wp, normals_wp, settings)
    with loop.runner.stage("cad_path", timing="cad_path_ik_s"):
        path, ik, dropped = solve_with_drops("cad_path", lines_wp, normals_wp, settings, None, loop.nominal, T_est,
                                             index, loop.strict, T_base_frame=T_est)
        loop.cad_path_workpiece = transform_path(inv_pose(T_est), path)   # after any drops, workpiece frame
        traj = _timed("cad_path", path, ik, dropped, realized, loop.say)
    _collect(loop)
    with loop.runner.within("cad_path"):
        loop.runs.append(_replayed("cad_path", path, ik, traj, dropped, planned, loop.replay_cell, realized,
                                   t_offset, loop.runner.timings_s, loop.say))
    loop.watch("run", loop.runs[-1])


def determined_cad_lines(region_lines: tuple[list, list], loc: RegistrationResult, index) -> tuple[list, list]:
    """The CAD raster's lines and normals (workpiece frame) that the estimate determines.

    Raises:
        StageFailed: the free directions leave no point of the process region on the part.
    """
    lines_wp, normals_wp = determined_part(*region_lines, loc, index)
    if not lines_wp:
        raise StageFailed("cad_path", "no CAD path point is determined by the scan: the free directions "
                                      "move every point of the process region off the part")
    return lines_wp, normals_wp


def _collect(loop: _Loop) -> None:
    """The scan path's run from its background replay (once)."""
    if loop.pending is not None:
        pending, loop.pending = loop.pending, None
        with loop.runner.within("scan_path"):
            loop.runs.append(pending.result())
        loop.watch("run", loop.runs[-1])

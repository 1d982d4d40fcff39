"""Recordings (``.rrd``) of a scan and of a run: every one carries the layout of
:mod:`twin.viz.blueprint`, the estimated pose when there is one, and a text panel."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import rerun as rr

from algorithms.geometry.se3 import transform_points
from twin import evaluate
from twin.cell import Cell
from twin.viz.blueprint import PATH_COLOURS, REPORT_ENTITY, send_blueprint
from twin.viz.cell import log_cell, log_pose_with_outline, mesh_outline
from twin.viz.paths import log_normals, log_path_lines, log_replay, log_tool_frames
from twin.viz.scan import DEVIATION_SCALE_M, STATUS_LEGEND, log_scan

if TYPE_CHECKING:
    from algorithms.geometry.mesh_index import MeshIndex
    from algorithms.paths.toolpath import ProcessPath
    from algorithms.registration.result import RegistrationResult
    from twin.realize import Realized
    from twin.replay import ReplayLog
    from twin.scan import Scan

PATH_TITLES = {"scan_path": "scan path", "cad_path": "CAD path"}
#: The localization's iterations are shown on ``sim_time`` over this span after the scan [s]
#: (less than the gap before the first replay).
ITERATION_SPAN_S = 0.8


class PathRunView(Protocol):
    """A replayed process path as the recordings read it (:class:`twin.pipeline.PathRun`: viz sits
    beside the pipeline in the layers and does not import it)."""

    @property
    def name(self) -> str: ...

    @property
    def path(self) -> ProcessPath: ...

    @property
    def log(self) -> ReplayLog: ...

    @property
    def t_offset_s(self) -> float: ...

    @property
    def normals_points(self) -> np.ndarray: ...

    @property
    def normals(self) -> np.ndarray: ...

    @property
    def dropped(self) -> tuple[Any, ...]: ...


class RunView(Protocol):
    """A run as the recordings read it (:class:`twin.pipeline.RunResult`)."""

    @property
    def realized(self) -> Realized: ...

    @property
    def scan(self) -> Scan | None: ...

    @property
    def runs(self) -> Sequence[PathRunView]: ...

    @property
    def replay_cell(self) -> Cell: ...

    @property
    def localization(self) -> Any: ...  # a RegistrationResult, or None (RunResult types it as object)

    @property
    def failure(self) -> tuple[str, str] | None: ...

    @property
    def pose_covariance(self) -> np.ndarray | None: ...


def save_scan_recording(path: str | Path, cell: Cell, scan: Scan, app_id: str = "scan_twin") -> Path:
    """Write a ``.rrd`` file with the cell that scanned, the moving arm, the beam, points and distances."""
    return _save(path, cell, scan, None, app_id)


def save_run_recording(path: str | Path, result: RunView, app_id: str = "scan_twin_run") -> Path:
    """Write a ``.rrd`` of ``twin run``: the scan, the estimate, then each process path planned
    and replayed (:class:`twin.pipeline.RunResult`; the cell shown is the replay cell, the true
    cell with the tool)."""
    return _save(path, result.replay_cell, result.scan, result, app_id)


def _save(path: str | Path, cell: Cell, scan: Scan | None, result: RunView | None, app_id: str) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream(app_id)
    runs: Sequence[PathRunView] = result.runs if result is not None else ()
    with rec:
        rec.save(str(path))
        begin(cell, [r.name for r in runs], getattr(result, "localization", None) is not None)
        index = result.realized.workpiece.index if result is not None else None
        if scan is not None:
            log_scan(cell, scan, cell.T_world_base, index)
        loc = result.localization if result is not None else None
        if loc is not None:
            log_estimate(cell, loc, _scan_end_s(scan))
        for run in runs:
            log_path_run(cell, run)
        log_summary(scan, result, runs)
        rec.flush()
    return path


class LiveRecording:
    """A run streamed to a Rerun viewer while it goes: each stage is logged as it finishes
    (:func:`twin.pipeline.run`'s ``watch`` events), with the same entities and layout as the
    file :func:`save_run_recording` writes.

    Args:
        sink: ``"spawn"`` (start a viewer on this machine) or the gRPC address of a running
            viewer or server (``rerun+http://HOST:PORT/proxy``).
    """

    def __init__(self, sink: str, app_id: str = "scan_twin_run",
                 say: Callable[[str], None] = lambda msg: None) -> None:
        self.rec = rr.RecordingStream(app_id)
        if sink == "spawn":
            self.rec.spawn()
        else:
            self.rec.connect_grpc(sink)
        self.say = say
        self.lost = False
        self.cell: Cell | None = None
        self.index: MeshIndex | None = None
        self.t_scan_end_s = 0.0

    def __call__(self, event: str, value: Any) -> None:
        """One stage's result: ``cells`` (replay cell, realized scenario), ``scan``,
        ``localization`` or ``run`` (a :class:`twin.pipeline.PathRun`)."""
        if self.lost:
            return
        with self.rec:
            if event == "cells":
                self.cell, realized = value
                self.index = realized.workpiece.index
                names = (["scan_path"] if realized.scenario.sensor.kind == "point" else []) + ["cad_path"]
                begin(self.cell, names, True)
            elif event == "scan":
                cell = self._cell(event)
                log_scan(cell, value, cell.T_world_base, self.index)
                self.t_scan_end_s = float(value.t[-1])
            elif event == "localization":
                log_estimate(self._cell(event), value, self.t_scan_end_s)
            elif event == "run":
                log_path_run(self._cell(event), value)
            self._flush()

    def _cell(self, event: str) -> Cell:
        """The replay cell the ``cells`` event gave (it comes first)."""
        if self.cell is None:
            raise RuntimeError(f"live recording: the {event!r} event came before 'cells'")
        return self.cell

    def finish(self, result: RunView) -> None:
        """The report's text panel, then the stream is closed."""
        if not self.lost:
            with self.rec:
                log_summary(result.scan, result, result.runs)
                self._flush()
        self.rec.disconnect()

    def _flush(self) -> None:
        """Send what was logged; a viewer that went away ends the stream, not the run."""
        try:
            self.rec.flush()
        except RuntimeError as exc:
            self.lost = True
            self.say(f"the live viewer cannot be reached ({exc}); the run goes on without it")


def begin(cell: Cell, path_names: list[str], localized: bool) -> None:
    """The layout and the static cell, first in every recording."""
    plots = [("plots/scan", "distance d [mm]")] + [(f"plots/{n}", f"{PATH_TITLES.get(n, n)} deviation [um]")
                                                    for n in path_names]
    if localized:
        plots.append(("plots/localization", "localization residual rms [um] per iteration"))
    send_blueprint(_focus(cell), float(np.ptp(cell.mesh.vertices, axis=0).max()), plots)
    rr.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    log_cell(cell)


def log_estimate(cell: Cell, loc: RegistrationResult, t_scan_end_s: float) -> None:
    """The estimated pose (static, full precision), the residual falling over the iterations,
    and the estimate moving (``world/workpiece/iterations``): on the ``localization_iteration``
    timeline, and on ``sim_time`` from the nominal pose during the scan to the estimate, the
    iterations spread over the :data:`ITERATION_SPAN_S` after the scan's end."""
    log_pose_with_outline("world/workpiece/estimate", cell.T_world_base @ loc.T_world_workpiece, cell.mesh,
                          [40, 200, 255])
    hist = np.asarray(loc.history, dtype=np.float64)
    if not len(hist):
        return
    steps = rr.TimeColumn("localization_iteration", sequence=np.arange(len(hist)))
    rr.send_columns("plots/localization/rms_um", indexes=[steps], columns=rr.Scalars.columns(scalars=hist * 1e6))
    if len(loc.pose_history) != len(hist):
        return
    T = cell.T_world_base @ np.asarray(loc.pose_history)
    for index in (steps, rr.TimeColumn("sim_time", duration=np.r_[0.0, t_scan_end_s + ITERATION_SPAN_S *
                                                                 np.arange(1, len(hist)) / max(len(hist) - 1, 1)])):
        rr.send_columns("world/workpiece/iterations", indexes=[index],
                        columns=rr.Transform3D.columns(translation=T[:, :3, 3], mat3x3=T[:, :3, :3]))
    rr.log("world/workpiece/iterations/mesh", rr.LineStrips3D(mesh_outline(cell.mesh), colors=[[255, 220, 0]],
                                                              radii=0.0002), static=True)


def log_path_run(cell: Cell, run: PathRunView) -> None:
    """One process path: planned lines, tool frames, normals, the replay, contacts and drops."""
    ent = f"world/path/{run.name}"
    planned, actual = PATH_COLOURS.get(run.name, ([90, 90, 90], [255, 200, 0]))
    p = run.path
    lines = [p.T_tool[a:b + 1, :3, 3] for a, b, kind, _ in p.segments if kind == "process"]
    log_path_lines(f"{ent}/planned", lines, cell.T_world_base, planned)
    log_tool_frames(f"{ent}/tool_frames", p.T_tool[p.process_mask()], cell.T_world_base)
    log_normals(f"{ent}/normals", run.normals_points, run.normals, cell.T_world_base, planned)
    log_replay(cell, run.log, run.t_offset_s, ent, actual)
    bad = [c for c in run.log.contacts if not c.intended]
    if bad:
        where = transform_points(cell.T_world_base, np.array([c.position_m for c in bad]))
        rr.log(f"{ent}/contacts", rr.Points3D(where, radii=0.002, colors=[255, 0, 255],
                                              labels=[f"{c.geom} x {c.other}" for c in bad]), static=True)
    if run.dropped:
        # The stretches left out (unreachable, singular, colliding), as markers.
        pts = transform_points(cell.T_world_base, np.array([d.position_m for d in run.dropped]))
        rr.log(f"{ent}/dropped", rr.Points3D(pts, radii=0.0015, colors=[255, 140, 0],
                                             labels=[d.reason.split(":")[0] for d in run.dropped]), static=True)


def log_summary(scan: Scan | None, result: RunView | None, runs: Sequence[PathRunView]) -> None:
    rr.log(REPORT_ENTITY, rr.TextDocument(_summary(scan, result, runs), media_type=rr.MediaType.MARKDOWN), static=True)


def _scan_end_s(scan: Scan | None) -> float:
    """The scan's last sample time [s]: where the localization's iterations start on ``sim_time``."""
    if scan is None:
        raise RuntimeError("a run with a localization has a scan")
    return float(scan.t[-1])


def _focus(cell: Cell) -> np.ndarray:
    """The part's centre in the world (its true pose: where the points are)."""
    return transform_points(cell.T_world_workpiece, cell.mesh.bounds.mean(axis=0)[None])[0]


def _summary(scan: Scan | None, result: RunView | None, runs: Sequence[PathRunView]) -> str:
    """The headline figures, in Markdown (times are recording times, ``sim_time``)."""
    out = ["# " + ("twin run" if result is not None else "twin scan"), ""]
    if scan is not None:
        out.append(f"- scan: {len(scan.t)} samples, t = 0 - {scan.t[-1]:.2f} s")
        out.append(f"- points coloured by signed distance to the true surface: blue -{DEVIATION_SCALE_M * 1e6:.0f} um, "
                   f"white 0, red +{DEVIATION_SCALE_M * 1e6:.0f} um, grey off the part "
                   "(`world/scan/points_by_line`: by scan line; `world/scan/points_by_status`: every beam "
                   f"that met the part, by sensor status: {STATUS_LEGEND})")
    if result is not None and result.failure is not None:
        out.append(f"- **stopped at {result.failure[0]}**: {result.failure[1]}")
    loc = result.localization if result is not None else None
    if result is not None and loc is not None:
        t_end = _scan_end_s(scan)
        e = evaluate.pose_errors(loc.T_world_workpiece, result.realized)
        free = len(loc.free_directions)
        err = (f"{np.degrees(e.rotation_rad):.4f} deg, {e.translation_m * 1e6:.1f} um from the truth" if not free
               else f"{free} free direction(s)")
        out.append(f"- estimate (`world/workpiece/estimate`, cyan): {loc.status.value}, {err}; its "
                   f"{len(loc.history) - 1} iteration(s) (`world/workpiece/iterations`, yellow) on the "
                   f"`localization_iteration` timeline and from t = {t_end:.2f} s to "
                   f"{t_end + ITERATION_SPAN_S:.2f} s")
        d = evaluate.determined_errors(loc, result.realized, result.pose_covariance)
        if d["std"]:
            out.append(f"- errors along the determined directions: max {d['max_sigmas']} standard deviations "
                       f"(1 sigma: {', '.join(f'{v:.2e}' for v in d['std'])}, rad or m)")
    for run in runs:
        v = run.log.summary()
        dev = "" if v["max_deviation_mm"] is None else f", max deviation {v['max_deviation_mm'] * 1e3:.0f} um"
        out.append(f"- {PATH_TITLES.get(run.name, run.name)}: replay from t = {run.t_offset_s:.2f} s{dev}, "
                   f"{v['unintended_contacts']} unintended contact(s)")
    return "\n".join(out)

"""Recordings (``.rrd``) of a scan and of a run: every one carries the layout of
:mod:`twin.viz.blueprint`, the estimated pose when there is one, and a text panel."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import rerun as rr

from algorithms.geometry.se3 import transform_points
from twin import evaluate
from twin.cell import Cell
from twin.deviation import cad_deviation_m, deviation_colours, deviation_scale
from twin.pose_table import markdown as pose_markdown
from twin.realize import Realized
from twin.robot import HOME_Q
from twin.sensors.laser import sensor_sigma_m
from twin.viz.blueprint import (
    BEAM_COLOUR,
    CAD_DEVIATION_ENTITY,
    CONTACT_COLOUR,
    DROPPED_COLOUR,
    ESTIMATE_COLOUR,
    ITERATION_COLOUR,
    NOMINAL_COLOUR,
    PATH_COLOURS,
    REPORT_ENTITY,
    Plot,
    send_blueprint,
    stage_span,
)
from twin.viz.cell import body_poses, log_cell, log_pose_with_outline, mesh_outline
from twin.viz.columns import quiet_timelines
from twin.viz.legend import LEGEND_ENTITY, bar_label, legend_image
from twin.viz.paths import TRANSIT_COLOUR, log_normals, log_path_lines, log_replay, log_tool_frames
from twin.viz.scan import STATUS_LEGEND, log_scan, truth_scale

PATH_TITLES = {"scan_path": "scan path", "cad_path": "CAD path"}
#: The localization's iterations are shown on ``sim_time`` over this span after the scan [s]
#: (less than the gap before the first replay).
ITERATION_SPAN_S = 0.8


def save_scan_recording(path: str | Path, cell: Cell, scan, realized: Realized, app_id: str = "scan_twin") -> Path:
    """Write a ``.rrd`` file with the cell that scanned, the moving arm, the beam, points and distances."""
    return _save(path, cell, scan, None, evaluate.Evaluation(realized), app_id)


def save_run_recording(path: str | Path, result, app_id: str = "scan_twin_run", report: dict | None = None) -> Path:
    """Write a ``.rrd`` of ``twin run``: the scan, the estimate, then each process path planned
    and replayed (:class:`twin.workflows.loop.RunResult`; the cell shown is the replay cell, the true
    cell with the tool); ``report`` (``report.json``'s content) gives the text panel its verdict
    and pose table."""
    return _save(path, result.replay_cell, result.scan, result, evaluate.Evaluation(result.realized), app_id,
                 report)


def _save(path: str | Path, cell: Cell, scan, result, truth: evaluate.Evaluation, app_id: str,
          report: dict | None = None) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream(app_id)
    quiet_timelines(rec)
    runs = result.runs if result is not None else ()
    loc = getattr(result, "localization", None)
    with rec:
        rec.save(str(path))
        begin(cell, [r.name for r in runs], loc is not None, scan, _spans(scan, loc, runs))
        if scan is not None:
            log_scan(cell, scan, cell.T_world_base, truth)
        if loc is not None:
            log_estimate(cell, loc, scan)
        for run in runs:
            log_path_run(cell, run, _t_planned(scan))
        log_summary(scan, result, runs, report)
        rec.flush()
    return path


def _t_planned(scan) -> float:
    """When the process paths exist on ``sim_time`` [s]: after the localization's iterations."""
    return (float(scan.t[-1]) if scan is not None else 0.0) + ITERATION_SPAN_S


def _spans(scan, loc, runs) -> dict[str, tuple[float, float]]:
    """Each time series' stage on ``sim_time`` [s]: the scan, the localization, each replay."""
    out: dict[str, tuple[float, float]] = {}
    if scan is not None:
        t_end = float(scan.t[-1])
        out["plots/scan"] = stage_span(0.0, t_end)
        if loc is not None:
            out["plots/localization"] = stage_span(t_end, t_end + ITERATION_SPAN_S)
    for run in runs:
        out[f"plots/{run.name}"] = stage_span(run.t_offset_s, run.t_offset_s + float(run.log.t[-1]))
    return out


class LiveRecording:
    """A run streamed to a Rerun viewer while it goes: each stage is logged as it finishes
    (:func:`twin.workflows.loop.run`'s ``watch`` events), with the same entities and layout as the
    file :func:`save_run_recording` writes (the plots' time spans and the report come with
    :meth:`finish`).

    Args:
        sink: ``"spawn"`` (start a viewer on this machine) or the gRPC address of a running
            viewer or server (``rerun+http://HOST:PORT/proxy``).
        app_id: the recording's application id.
        say: where a lost viewer is reported.
    """

    def __init__(self, sink: str, app_id: str = "scan_twin_run", say: Callable[[str], None] = lambda msg: None):
        self.rec = rr.RecordingStream(app_id)
        quiet_timelines(self.rec)
        if sink == "spawn":
            self.rec.spawn()
        else:
            self.rec.connect_grpc(sink)
        self.say = say
        self.lost = False
        self.cell: Cell | None = None
        self.evaluation: evaluate.Evaluation | None = None
        self.scan = None

    def __call__(self, event: str, value) -> None:
        """One stage's result: ``cells`` (replay cell, realized scenario), ``scan``,
        ``localization`` or ``run`` (a :class:`twin.workflows.loop.PathRun`)."""
        if self.lost:
            return
        with self.rec:
            if event == "cells":
                self.cell, realized = value
                self.evaluation = evaluate.Evaluation(realized)
                names = (["scan_path"] if realized.scenario.sensor.kind == "point" else []) + ["cad_path"]
                begin(self.cell, names, True, None, {})
            elif self.cell is None or self.evaluation is None:
                raise ValueError(f"recording event {event!r} before the cells")
            elif event == "scan":
                log_scan(self.cell, value, self.cell.T_world_base, self.evaluation)
                self.scan = value
            elif event == "localization":
                log_estimate(self.cell, value, self.scan)
            elif event == "run":
                log_path_run(self.cell, value, _t_planned(self.scan))
            self._flush()

    def finish(self, result, report: dict | None = None) -> None:
        """The layout again with each plot's time span, the report's text panel, then the
        stream is closed."""
        if not self.lost and self.cell is not None:
            with self.rec:
                send_layout(self.cell, [r.name for r in result.runs], result.localization is not None, result.scan,
                            _spans(result.scan, result.localization, result.runs))
                log_summary(result.scan, result, result.runs, report)
                self._flush()
        self.rec.disconnect()

    def _flush(self) -> None:
        """Send what was logged; a viewer that went away ends the stream, not the run."""
        try:
            self.rec.flush()
        except RuntimeError as exc:
            self.lost = True
            self.say(f"the live viewer cannot be reached ({exc}); the run goes on without it")


def send_layout(cell: Cell, path_names: list[str], localized: bool, scan, spans: dict) -> None:
    """The blueprint: the cell view framed on the arm's reach during the scan and the part, the
    plots each over its stage's span."""
    plots = [Plot("plots/scan", "distance d [mm]", spans.get("plots/scan"))]
    plots += [Plot(f"plots/{n}", f"{PATH_TITLES.get(n, n)} deviation [um]", spans.get(f"plots/{n}"))
              for n in path_names]
    if localized:
        plots.append(Plot("plots/localization", "localization residual rms [um] per iteration",
                          spans.get("plots/localization")))
    send_blueprint(_focus(cell), float(np.ptp(cell.mesh.vertices, axis=0).max()), frame_points(cell, scan), plots,
                   hidden=tuple(f"world/path/{n}/transit" for n in path_names))


def frame_points(cell: Cell, scan=None) -> np.ndarray:
    """World points the cell view must show: the part's box, the arm's bodies at its home pose
    and over the scan."""
    corners = np.array(np.meshgrid(*cell.mesh.bounds.T)).T.reshape(-1, 3)
    pts = [transform_points(cell.T_world_workpiece, corners), cell.T_world_base[None, :3, 3]]
    q = [HOME_Q[None]]
    if scan is not None and len(scan.t):
        q.append(scan.q_true[np.linspace(0, len(scan.t) - 1, 12).astype(int)])
    for qs in q:
        pts += [T[:, :3, 3] for T in body_poses(cell, qs).values()]
    return np.concatenate(pts)


def begin(cell: Cell, path_names: list[str], localized: bool, scan=None, spans: dict | None = None) -> None:
    """The layout, the legend and the static cell, first in every recording."""
    send_layout(cell, path_names, localized, scan, spans or {})
    rr.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    log_cell(cell)
    u = sensor_sigma_m(cell.scenario)
    if localized:
        scale = deviation_scale(cell.scenario.tolerances.max_surface_deviation_m, u)
        label = bar_label(scale, "the CAD model at the estimated pose (part view)")
    else:
        scale = truth_scale(u)
        label = bar_label(scale, "the TRUE surface (the twin's check)")
    rr.log(LEGEND_ENTITY, rr.EncodedImage(contents=legend_image(scale, _swatches(path_names, localized), label),
                                         media_type="image/png"), static=True)


def _swatches(path_names: list[str], localized: bool) -> list[tuple[str, tuple[int, ...]]]:
    out: list[tuple[str, tuple[int, ...]]] = [("laser beam", BEAM_COLOUR), ("nominal pose (outline)", NOMINAL_COLOUR)]
    if localized:
        out += [("estimated pose (outline)", ESTIMATE_COLOUR), ("iterations (outline)", ITERATION_COLOUR)]
    for n in path_names:
        planned, actual = PATH_COLOURS.get(n, ((90, 90, 90), (255, 200, 0)))
        out += [(f"{PATH_TITLES.get(n, n)}: planned", tuple(planned)), (f"{PATH_TITLES.get(n, n)}: replayed tip",
                                                                        tuple(actual))]
    if path_names:
        out += [("transit moves (hidden: switch on)", TRANSIT_COLOUR), ("dropped stretch", DROPPED_COLOUR),
                ("unintended contact", CONTACT_COLOUR)]
    return out


def log_estimate(cell: Cell, loc, scan) -> None:
    """The estimated pose (static, full precision), the residual falling over the iterations,
    the estimate moving (``world/workpiece/iterations``) and the scan points against the CAD
    model at the estimate (``world/deviation/points``, with ``deviation_um`` per point for
    hovering). On the ``localization_iteration`` timeline, and on ``sim_time`` from the nominal
    pose during the scan to the estimate, the iterations spread over the :data:`ITERATION_SPAN_S`
    after the scan's end."""
    t_scan_end_s = float(scan.t[-1]) if scan is not None else 0.0
    log_pose_with_outline("world/workpiece/estimate", cell.T_world_base @ loc.T_world_workpiece, cell.mesh,
                          ESTIMATE_COLOUR)
    if scan is not None:
        log_cad_deviation(cell, scan, loc.T_world_workpiece, t_scan_end_s + ITERATION_SPAN_S)
    hist = np.asarray(loc.history, dtype=np.float64)
    if not len(hist):
        return
    steps = rr.TimeColumn("localization_iteration", sequence=np.arange(len(hist)))
    on_sim = rr.TimeColumn("sim_time", duration=t_scan_end_s + ITERATION_SPAN_S * np.arange(len(hist))
                           / max(len(hist) - 1, 1))
    rr.send_columns("plots/localization/rms_um", indexes=[steps, on_sim],
                    columns=rr.Scalars.columns(scalars=hist * 1e6))
    if len(loc.pose_history) != len(hist):
        return
    T = cell.T_world_base @ np.asarray(loc.pose_history)
    for index in (steps, rr.TimeColumn("sim_time", duration=np.r_[0.0, t_scan_end_s + ITERATION_SPAN_S *
                                                                 np.arange(1, len(hist)) / max(len(hist) - 1, 1)])):
        rr.send_columns("world/workpiece/iterations", indexes=[index],
                        columns=rr.Transform3D.columns(translation=T[:, :3, 3], mat3x3=T[:, :3, :3]))
    rr.log("world/workpiece/iterations/mesh", rr.LineStrips3D(mesh_outline(cell.mesh), colors=[ITERATION_COLOUR],
                                                              radii=0.0002), static=True)


def log_cad_deviation(cell: Cell, scan, T_base_workpiece_estimate: np.ndarray, t_s: float) -> None:
    """Every valid scan point coloured by its deviation from the CAD at the estimate, at ``t_s``."""
    pts = scan.valid_points_base
    if not len(pts):
        return
    dev = cad_deviation_m(pts, T_base_workpiece_estimate, cell.index)
    scale = deviation_scale(cell.scenario.tolerances.max_surface_deviation_m, sensor_sigma_m(cell.scenario))
    rr.set_time("sim_time", duration=t_s)
    rr.log(CAD_DEVIATION_ENTITY, rr.Points3D(transform_points(cell.T_world_base, pts), radii=0.0003,
                                             colors=deviation_colours(dev, scale)),
           rr.AnyValues(deviation_um=(dev * 1e6).astype(np.float32)))


def log_path_run(cell: Cell, run, t_planned_s: float) -> None:
    """One process path: planned lines, tool frames and normals from ``t_planned_s`` on, the
    replay, contacts and drops."""
    ent = f"world/path/{run.name}"
    planned, actual = PATH_COLOURS.get(run.name, ([90, 90, 90], [255, 200, 0]))
    p = run.path
    lines = [p.T_tool[a:b + 1, :3, 3] for a, b, kind, _ in p.segments if kind == "process"]
    log_path_lines(f"{ent}/planned", lines, cell.T_world_base, planned, t_s=t_planned_s)
    log_tool_frames(f"{ent}/tool_frames", p.T_tool[p.process_mask()], cell.T_world_base, t_s=t_planned_s)
    log_normals(f"{ent}/normals", run.normals_points, run.normals, cell.T_world_base, planned, t_s=t_planned_s)
    log_replay(cell, run.log, run.t_offset_s, ent, actual)
    bad = [c for c in run.log.contacts if not c.intended]
    if bad:
        where = transform_points(cell.T_world_base, np.array([c.position_m for c in bad]))
        rr.log(f"{ent}/contacts", rr.Points3D(where, radii=0.003, colors=[CONTACT_COLOUR],
                                              labels=[f"{c.geom} x {c.other}" for c in bad]), static=True)
    if run.dropped:
        # The stretches left out (unreachable, singular, colliding), as markers.
        pts = transform_points(cell.T_world_base, np.array([d.position_m for d in run.dropped]))
        rr.log(f"{ent}/dropped", rr.Points3D(pts, radii=0.0015, colors=[DROPPED_COLOUR],
                                             labels=[d.reason.split(":")[0] for d in run.dropped]), static=True)


def log_summary(scan, result, runs, report: dict | None = None) -> None:
    rr.log(REPORT_ENTITY, rr.TextDocument(_summary(scan, result, runs, report), media_type=rr.MediaType.MARKDOWN),
           static=True)


def _focus(cell: Cell) -> np.ndarray:
    """The part's centre in the world (its true pose: where the points are)."""
    return transform_points(cell.T_world_workpiece, cell.mesh.bounds.mean(axis=0)[None])[0]


def verdict_markdown(report: dict | None) -> list[str]:
    """The verdict and its checks (deciding ones first) as Markdown lines."""
    if report is None or "checks" not in report:
        return []
    checks = sorted(report["checks"], key=lambda c: not c["decides"])
    out = [f"## Verdict: {'PASS' if report.get('passed') else 'FAIL'}", "", "| check | result | detail |",
           "|---|---|---|"]
    out += [f"| {c['name']}{'' if c['decides'] else ' (shown only)'} | {'pass' if c['passed'] else '**FAIL**'} | "
            f"{c['detail'].replace('|', '/')} |" for c in checks]
    return out + [""]


def _summary(scan, result, runs, report: dict | None = None) -> str:
    """The verdict, the pose table and the headline figures, in Markdown (times are recording
    times, ``sim_time``)."""
    out = ["# " + ("twin run" if result is not None else "twin scan"), ""] + verdict_markdown(report)
    loc_block = (report or {}).get("localization", {})
    if "pose_table" in loc_block:
        out += ["## Pose", "", pose_markdown(loc_block["pose_table"]), ""]
    out += ["## Figures", ""]
    if scan is not None:
        out.append(f"- scan: {len(scan.t)} samples, t = 0 - {scan.t[-1]:.2f} s")
        out.append("- part view: the points coloured by their signed deviation from the CAD model at the estimated "
                   "pose (`world/deviation/points`; hover a point for `deviation_um`; scale in the legend); in the "
                   "cell view the points grow as measured, coloured against the TRUE surface (the twin's check, "
                   "green within the expanded uncertainty of a point); `world/scan/points_by_line` and "
                   f"`world/scan/points_by_status` (by sensor status: {STATUS_LEGEND}) are there to switch on")
    dev = (report or {}).get("deviation_vs_cad")
    if dev and dev.get("within_tolerance_share") is not None:
        out.append(f"- against the CAD at the estimate: {dev['within_tolerance_share']:.1%} of "
                   f"{dev['points_on_part']} points within +-{dev['tolerance_um']:.3g} um, rms {dev['rms_um']:.2f} um")
    if result is not None and result.failure is not None:
        out.append(f"- **stopped at {result.failure[0]}**: {result.failure[1]}")
    loc = getattr(result, "localization", None)
    if loc is not None:
        out.append(f"- estimate (`world/workpiece/estimate`, cyan): {loc.status.value}; its "
                   f"{len(loc.history) - 1} iteration(s) (`world/workpiece/iterations`, yellow) on the "
                   f"`localization_iteration` timeline and from t = {scan.t[-1]:.2f} s to "
                   f"{scan.t[-1] + ITERATION_SPAN_S:.2f} s")
    for run in runs:
        v = run.log.summary()
        dev_txt = "" if v["max_deviation_mm"] is None else f", max deviation {v['max_deviation_mm'] * 1e3:.0f} um"
        out.append(f"- {PATH_TITLES.get(run.name, run.name)}: planned at t = {_t_planned(scan):.2f} s, replayed from "
                   f"t = {run.t_offset_s:.2f} s{dev_txt}, {len(run.dropped)} stretch(es) dropped, "
                   f"{v['unintended_contacts']} unintended contact(s)")
    return "\n".join(out)

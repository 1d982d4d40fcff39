"""The recording of ``twin locate``: the coarse laser pass, the probe's qualification and
probing moves, the planned and measured points, and the coarse, final and true poses."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import rerun as rr

from algorithms.geometry.se3 import transform_points
from twin.cell import Cell
from twin.viz.blueprint import REPORT_ENTITY, send_blueprint
from twin.viz.cell import body_poses, log_cell, log_pose_with_outline
from twin.viz.scan import POSE_EVERY, log_scan

if TYPE_CHECKING:
    from twin.probing import ProbingLog
    from twin.realize import Realized
    from twin.scan import Scan

COARSE_COLOUR = [255, 150, 40]
FINAL_COLOUR = [40, 200, 255]


class FinePlanView(Protocol):
    """The planned fine points as the recording reads them (:class:`twin.locate.FinePlan`)."""

    @property
    def targets(self) -> tuple[Any, ...]: ...  # twin.probing.ProbeTarget, in probing order


class LocateView(Protocol):
    """A locate run as the recording reads it (:class:`twin.locate.LocateResult`, a layer above viz)."""

    @property
    def realized(self) -> Realized: ...

    @property
    def scan(self) -> Scan | None: ...

    @property
    def T_coarse(self) -> np.ndarray | None: ...

    @property
    def T_final(self) -> np.ndarray | None: ...

    @property
    def plan(self) -> FinePlanView | None: ...

    @property
    def probing(self) -> ProbingLog | None: ...


def save_locate_recording(path: str | Path, result: LocateView, cell: Cell, report: dict | None = None,
                          app_id: str = "scan_twin_locate") -> Path:
    """Write the ``.rrd`` of a locate run (:class:`twin.locate.LocateResult`); ``cell`` is the
    probe cell (the true cell with the probe, the laser and the reference sphere)."""
    path = Path(path)
    rec = rr.RecordingStream(app_id)
    T_wb = cell.T_world_base
    with rec:
        rec.save(str(path))
        focus = transform_points(cell.T_world_workpiece, cell.mesh.bounds.mean(axis=0)[None])[0]
        send_blueprint(focus, float(np.ptp(cell.mesh.vertices, axis=0).max()),
                       [("plots/scan", "coarse pass: distance d [mm]")])
        rr.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        log_cell(cell)
        if result.scan is not None:
            log_scan(cell, result.scan, T_wb, result.realized.workpiece.index)
        for name, T, colour in (("coarse", result.T_coarse, COARSE_COLOUR), ("estimate", result.T_final, FINAL_COLOUR)):
            if T is not None:
                log_pose_with_outline(f"world/workpiece/{name}", T_wb @ T, cell.mesh, colour)
        if result.plan is not None:
            pts = transform_points(T_wb, np.array([t.point for t in result.plan.targets]))
            rr.log("world/probe/planned", rr.Points3D(pts, radii=0.0012, colors=[[60, 120, 255]],
                                                      labels=[t.label for t in result.plan.targets]), static=True)
        if result.probing is not None:
            _log_probing(cell, result.probing, T_wb)
        if report is not None:
            rr.log(REPORT_ENTITY, rr.TextDocument(_summary(report), media_type=rr.MediaType.MARKDOWN), static=True)
        rec.flush()
    return path


def _log_probing(cell: Cell, log: ProbingLog, T_wb: np.ndarray) -> None:
    idx = np.arange(0, len(log.t), POSE_EVERY)
    times = rr.TimeColumn("sim_time", duration=log.t[idx])
    for name, T in body_poses(cell, log.q[idx]).items():
        rr.send_columns(f"world/robot/{name}", indexes=[times], columns=rr.Transform3D.columns(
            translation=T[:, :3, 3], mat3x3=T[:, :3, :3]))
    ball_w = transform_points(T_wb, log.ball)
    # the ball centre every 10 ms: a trail of the probing moves in the blueprint's cumulative views
    rr.send_columns("world/probe/ball_centre", indexes=[rr.TimeColumn("sim_time", duration=log.t[idx])],
                    columns=rr.Points3D.columns(positions=ball_w[idx]))
    rr.log("world/probe/ball_centre", rr.Points3D.from_fields(radii=0.0003, colors=[[230, 30, 40]]), static=True)
    hit = [h for h in log.hits if h.hit]
    # one entity growing with each trigger (every hit so far, labelled)
    for k, h in enumerate(hit):
        rr.set_time("sim_time", duration=float(h.trigger_t_s))
        centres = transform_points(T_wb, np.array([g.centre for g in hit[:k + 1]]))
        rr.log("world/probe/hits", rr.Points3D(centres, radii=0.001, colors=[[40, 220, 90]],
                                               labels=[g.target.label for g in hit[:k + 1]]))
    miss = [h for h in log.hits if not h.hit]
    if miss:
        rr.log("world/probe/misses", rr.Points3D(transform_points(T_wb, np.array([h.target.point for h in miss])),
                                                 radii=0.0015, colors=[[255, 0, 0]],
                                                 labels=[f"{h.target.label}: miss" for h in miss]), static=True)
    if log.contacts:
        where = transform_points(T_wb, np.array([c.position_m for c in log.contacts]))
        rr.log("world/probe/contacts", rr.Points3D(where, radii=0.002, colors=[[255, 0, 255]],
                                                   labels=[f"{c.geom} x {c.other}" for c in log.contacts]),
               static=True)


def _summary(report: dict) -> str:
    lines = ["# twin locate", "", "coarse pose: orange outline; final estimate: cyan; truth: the solid part", ""]
    if "failure" in report:
        lines.append(f"**stopped at {report['failed_stage']}**: {report['failure']}")
    for key in ("coarse", "fine"):
        if key in report:
            b = report[key]
            lines.append(f"- {key}: {b['rotation_error_deg']:.4f} deg, {b['translation_error_mm'] * 1e3:.2f} um from "
                         "the truth" + (f", max {b['max_error_sigmas']} sigma" if "max_error_sigmas" in b else ""))
    if "qualification" in report:
        lines.append(f"- effective ball radius {report['qualification']['effective_radius_mm']:.6f} mm")
    if "probing" in report:
        p = report["probing"]
        lines.append(f"- probing: {p['hits']} of {p['points']} hit, {p['unintended_contacts']} unintended contacts")
    return "\n".join(lines)

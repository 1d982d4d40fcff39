"""The recording of ``twin locate``: the coarse laser pass, the probe's qualification and
probing moves, the planned and measured points, and the coarse, final and true poses."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr

from algorithms.geometry.se3 import transform_points
from twin import evaluate
from twin.deviation import deviation_scale
from twin.pose_table import markdown as pose_markdown
from twin.sensors.laser import sensor_sigma_m
from twin.viz.blueprint import (
    BEAM_COLOUR,
    COARSE_COLOUR,
    CONTACT_COLOUR,
    ESTIMATE_COLOUR,
    NOMINAL_COLOUR,
    REPORT_ENTITY,
    Plot,
    send_blueprint,
    stage_span,
)
from twin.viz.cell import body_poses, log_cell, log_pose_with_outline, send_arm
from twin.viz.columns import POSE_PERIOD_S, every, quiet_timelines
from twin.viz.legend import LEGEND_ENTITY, bar_label, legend_image
from twin.viz.recording import frame_points, log_cad_deviation, verdict_markdown
from twin.viz.scan import log_scan

PLANNED_COLOUR = (60, 120, 255)
HIT_COLOUR = (40, 220, 90)
BALL_COLOUR = (230, 30, 40)


def save_locate_recording(path: str | Path, result, cell, report: dict | None = None,
                          app_id: str = "scan_twin_locate") -> Path:
    """Write the ``.rrd`` of a locate run (:class:`twin.workflows.locate.LocateResult`); ``cell`` is the
    probe cell (the true cell with the probe, the laser and the reference sphere)."""
    path = Path(path)
    rec = rr.RecordingStream(app_id)
    quiet_timelines(rec)
    T_wb = cell.T_world_base
    with rec:
        rec.save(str(path))
        _begin(cell, result)
        if result.scan is not None:
            log_scan(cell, result.scan, T_wb, evaluate.Evaluation(result.realized))
        for name, T, colour in (("coarse", result.T_coarse, COARSE_COLOUR), ("estimate", result.T_final,
                                                                              ESTIMATE_COLOUR)):
            if T is not None:
                log_pose_with_outline(f"world/workpiece/{name}", T_wb @ T, cell.mesh, colour)
        T_map = result.T_final if result.T_final is not None else result.T_coarse
        if result.scan is not None and T_map is not None:
            log_cad_deviation(cell, result.scan, T_map, float(result.scan.t[-1]))
        if result.plan is not None:
            pts = transform_points(T_wb, np.array([t.point for t in result.plan.targets]))
            rr.log("world/probe/planned", rr.Points3D(pts, radii=0.0012, colors=[PLANNED_COLOUR],
                                                      labels=[t.label for t in result.plan.targets]), static=True)
        if result.probing is not None:
            _log_probing(cell, result.probing, T_wb)
        if report is not None:
            rr.log(REPORT_ENTITY, rr.TextDocument(_summary(report), media_type=rr.MediaType.MARKDOWN), static=True)
        rec.flush()
    return path


def _begin(cell, result) -> None:
    """The layout framed on the arm, the part and the reference sphere; the legend; the cell."""
    focus = transform_points(cell.T_world_workpiece, cell.mesh.bounds.mean(axis=0)[None])[0]
    frame = [frame_points(cell, result.scan), np.asarray(cell.scenario.probe.sphere_xyz_m, dtype=np.float64)[None]]
    if result.probing is not None and len(result.probing.t):
        q = result.probing.q[np.linspace(0, len(result.probing.t) - 1, 24).astype(int)]
        frame += [T[:, :3, 3] for T in body_poses(cell, q).values()]
    span_scan = None if result.scan is None else stage_span(0.0, float(result.scan.t[-1]))
    send_blueprint(focus, float(np.ptp(cell.mesh.vertices, axis=0).max()), np.concatenate(frame),
                   [Plot("plots/scan", "coarse pass: distance d [mm]", span_scan)])
    rr.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    log_cell(cell)
    scale = deviation_scale(cell.scenario.tolerances.max_surface_deviation_m, sensor_sigma_m(cell.scenario))
    swatches = [("laser beam", BEAM_COLOUR), ("nominal pose (outline)", NOMINAL_COLOUR),
                ("coarse pose (outline)", COARSE_COLOUR), ("final pose (outline)", ESTIMATE_COLOUR),
                ("planned probe point", PLANNED_COLOUR), ("probe hit (ball centre)", HIT_COLOUR),
                ("ball centre path", BALL_COLOUR), ("miss / unintended contact", CONTACT_COLOUR)]
    rr.log(LEGEND_ENTITY, rr.EncodedImage(contents=legend_image(scale, swatches, bar_label(
        scale, "the CAD model at the final pose (coarse pass points, part view)")), media_type="image/png"),
           static=True)


def _log_probing(cell, log, T_wb) -> None:
    idx = every(log.t, POSE_PERIOD_S)
    send_arm(cell, log.t[idx], log.q[idx])
    ball_w = transform_points(T_wb, log.ball)
    # the ball centre every 50 ms: a thin trail of the probing moves in the cumulative cell view
    rr.send_columns("world/probe/ball_centre", indexes=[rr.TimeColumn("sim_time", duration=log.t[idx])],
                    columns=rr.Points3D.columns(positions=ball_w[idx]))
    rr.log("world/probe/ball_centre", rr.Points3D.from_fields(radii=0.0002, colors=[BALL_COLOUR]), static=True)
    hit = [h for h in log.hits if h.hit]
    # each trigger's ball centre appears when it happens (labelled)
    if hit:
        centres = transform_points(T_wb, np.array([g.centre for g in hit]))
        rr.send_columns("world/probe/hits", indexes=[rr.TimeColumn("sim_time", duration=[h.trigger_t_s for h in hit])],
                        columns=rr.Points3D.columns(positions=centres, labels=[g.target.label for g in hit]))
        rr.log("world/probe/hits", rr.Points3D.from_fields(radii=0.001, colors=[HIT_COLOUR]), static=True)
    miss = [h for h in log.hits if not h.hit]
    if miss:
        rr.log("world/probe/misses", rr.Points3D(transform_points(T_wb, np.array([h.target.point for h in miss])),
                                                 radii=0.003, colors=[CONTACT_COLOUR],
                                                 labels=[f"{h.target.label}: miss" for h in miss]), static=True)
    if log.contacts:
        where = transform_points(T_wb, np.array([c.position_m for c in log.contacts]))
        rr.log("world/probe/contacts", rr.Points3D(where, radii=0.003, colors=[CONTACT_COLOUR],
                                                   labels=[f"{c.geom} x {c.other}" for c in log.contacts]),
               static=True)


def _summary(report: dict) -> str:
    lines = ["# twin locate", ""] + verdict_markdown(report)
    fine = report.get("fine", {})
    if "pose_table" in fine:
        lines += ["## Final pose", "", pose_markdown(fine["pose_table"]), ""]
    lines += ["## Figures", "", "coarse pose: orange outline; final estimate: cyan; truth: the solid part; part view: "
              "the coarse pass's points against the CAD at the final pose (legend)", ""]
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

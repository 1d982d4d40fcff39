"""Recordings (``.rrd``) of a scan and of a run: every one carries the layout of
:mod:`twin.viz.blueprint`, the estimated pose when there is one, and a text panel."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr

from algorithms.geometry.se3 import transform_points
from twin import evaluate
from twin.cell import Cell
from twin.viz.blueprint import PATH_COLOURS, REPORT_ENTITY, send_blueprint
from twin.viz.cell import log_cell, log_pose_with_outline
from twin.viz.paths import log_normals, log_path_lines, log_replay, log_tool_frames
from twin.viz.scan import DEVIATION_SCALE_M, log_scan

PATH_TITLES = {"scan_path": "scan path", "cad_path": "CAD path"}


def save_scan_recording(path: str | Path, cell: Cell, scan, app_id: str = "scan_twin") -> Path:
    """Write a ``.rrd`` file with the cell that scanned, the moving arm, the beam, points and distances."""
    return _save(path, cell, scan, None, app_id)


def save_run_recording(path: str | Path, result, app_id: str = "scan_twin_run") -> Path:
    """Write a ``.rrd`` of ``twin run``: the scan, the estimate, then each process path planned
    and replayed (:class:`twin.pipeline.RunResult`; the cell shown is the replay cell, the true
    cell with the tool)."""
    return _save(path, result.replay_cell, result.scan, result, app_id)


def _save(path: str | Path, cell: Cell, scan, result, app_id: str) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream(app_id)
    runs = result.runs if result is not None else ()
    with rec:
        rec.save(str(path))
        plots = [("plots/scan", "distance d [mm]")] + [(f"plots/{r.name}", f"{PATH_TITLES.get(r.name, r.name)} "
                                                                             "deviation [um]") for r in runs]
        if getattr(result, "localization", None) is not None:
            plots.append(("plots/localization", "localization residual rms [um] per iteration"))
        send_blueprint(_focus(cell), float(np.ptp(cell.mesh.vertices, axis=0).max()), plots)
        rr.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        log_cell(cell)
        index = result.realized.workpiece.index if result is not None else None
        if scan is not None:
            log_scan(cell, scan, cell.T_world_base, index)
        loc = getattr(result, "localization", None)
        if loc is not None:
            log_pose_with_outline("world/workpiece/estimate", cell.T_world_base @ loc.T_world_workpiece, cell.mesh,
                                  [40, 200, 255])
            # the residual falling over the iterations, on a timeline of its own
            hist = np.asarray(loc.history, dtype=np.float64)
            if len(hist):
                rr.send_columns("plots/localization/rms_um",
                                indexes=[rr.TimeColumn("localization_iteration", sequence=np.arange(len(hist)))],
                                columns=rr.Scalars.columns(scalars=hist * 1e6))
        for run in runs:
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
                rr.log(f"{ent}/contacts", rr.Points3D(transform_points(cell.T_world_base,
                                                                       np.array([c.position_m for c in bad])),
                                                      radii=0.002, colors=[255, 0, 255],
                                                      labels=[f"{c.geom} x {c.other}" for c in bad]), static=True)
            if run.dropped:
                # The stretches left out (unreachable, singular, colliding), as markers.
                pts = np.array([d.position_m for d in run.dropped])
                rr.log(f"{ent}/dropped", rr.Points3D(transform_points(cell.T_world_base, pts), radii=0.0015,
                                                     colors=[255, 140, 0],
                                                     labels=[d.reason.split(":")[0] for d in run.dropped]),
                       static=True)
        rr.log(REPORT_ENTITY, rr.TextDocument(_summary(scan, result, runs), media_type=rr.MediaType.MARKDOWN),
               static=True)
        rec.flush()
    return path


def _focus(cell: Cell) -> np.ndarray:
    """The part's centre in the world (its true pose: where the points are)."""
    return transform_points(cell.T_world_workpiece, cell.mesh.bounds.mean(axis=0)[None])[0]


def _summary(scan, result, runs) -> str:
    """The headline figures, in Markdown (times are recording times, ``sim_time``)."""
    out = ["# " + ("twin run" if result is not None else "twin scan"), ""]
    if scan is not None:
        out.append(f"- scan: {len(scan.t)} samples, t = 0 - {scan.t[-1]:.2f} s")
        out.append(f"- points coloured by signed distance to the true surface: blue -{DEVIATION_SCALE_M * 1e6:.0f} um, "
                   f"white 0, red +{DEVIATION_SCALE_M * 1e6:.0f} um, grey off the part "
                   "(`world/scan/points_by_line`: by scan line)")
    if result is not None and result.failure is not None:
        out.append(f"- **stopped at {result.failure[0]}**: {result.failure[1]}")
    loc = getattr(result, "localization", None)
    if loc is not None:
        e = evaluate.pose_errors(loc.T_world_workpiece, result.realized)
        free = len(loc.free_directions)
        err = (f"{np.degrees(e.rotation_rad):.4f} deg, {e.translation_m * 1e6:.1f} um from the truth" if not free
               else f"{free} free direction(s)")
        out.append(f"- estimate (`world/workpiece/estimate`, cyan): {loc.status.value}, {err}")
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

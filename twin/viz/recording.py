"""Recordings (``.rrd``) of a scan and of a run."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr

from algorithms.geometry.se3 import transform_points
from twin.cell import Cell
from twin.viz.cell import log_cell
from twin.viz.paths import log_normals, log_path_lines, log_replay, log_tool_frames
from twin.viz.scan import log_scan


def save_scan_recording(path: str | Path, cell: Cell, scan, app_id: str = "scan_twin") -> Path:
    """Write a ``.rrd`` file with the cell that scanned, the moving arm, the beam, points and distances."""
    return _save(path, cell, scan, runs=(), app_id=app_id)


def save_run_recording(path: str | Path, result, app_id: str = "scan_twin_run") -> Path:
    """Write a ``.rrd`` of ``twin run``: the scan, then each process path planned and replayed
    (:class:`twin.pipeline.RunResult`; the cell shown is the replay cell, the true cell with the tool)."""
    return _save(path, result.replay_cell, result.scan, result.runs, app_id, result.failure)


def _save(path: str | Path, cell: Cell, scan, runs, app_id: str, failure=None) -> Path:
    """The recording: ``cell``'s geometry, the scan from sim_time 0, then each run (PathRun)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream(app_id)
    with rec:
        rec.save(str(path))
        rr.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        log_cell(cell)
        if scan is not None:
            log_scan(cell, scan, cell.T_world_base)
        for run in runs:
            ent = f"world/path/{run.name}"
            p = run.path
            lines = [p.T_tool[a:b + 1, :3, 3] for a, b, kind, _ in p.segments if kind == "process"]
            log_path_lines(f"{ent}/planned", lines, cell.T_world_base, [60, 160, 255])
            log_tool_frames(f"{ent}/tool_frames", p.T_tool[p.process_mask()], cell.T_world_base)
            log_normals(f"{ent}/normals", run.normals_points, run.normals, cell.T_world_base, [200, 60, 200])
            log_replay(cell, run.log, run.t_offset_s, ent)
            if run.dropped:
                # The stretches left out (unreachable, singular, colliding), as markers.
                pts = np.array([d.position_m for d in run.dropped])
                rr.log(f"{ent}/dropped", rr.Points3D(transform_points(cell.T_world_base, pts), radii=0.0015,
                                                     colors=[255, 140, 0],
                                                     labels=[d.reason.split(":")[0] for d in run.dropped]),
                       static=True)
        if failure is not None:
            rr.log("report/failure", rr.TextDocument(f"run stopped at {failure[0]}: {failure[1]}"), static=True)
        rec.flush()
    return path

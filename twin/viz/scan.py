"""The scan on the ``sim_time`` timeline: the moving arm, the beam, the points, the distance."""

from __future__ import annotations

import numpy as np
import rerun as rr

from twin.cell import Cell
from twin.viz.cell import body_poses, sensor_poses

POSE_EVERY = 10      # arm and beam logged every 10 ms (points and distances every 1 ms)
POINT_CHUNK = 100    # points grouped 100 ms per entity, so they stay visible once measured


def log_scan(cell: Cell, scan, T_world_base: np.ndarray) -> None:
    """The arm moving, the beam, the points appearing and the distance, on ``sim_time``."""
    idx = np.arange(0, len(scan.t), POSE_EVERY)
    times = rr.TimeColumn("sim_time", duration=scan.t[idx])
    poses = body_poses(cell, scan.q_true[idx])
    for name, T in poses.items():
        rr.send_columns(f"world/robot/{name}", indexes=[times], columns=rr.Transform3D.columns(
            translation=T[:, :3, 3], mat3x3=T[:, :3, :3]))
    # Beam: from the emitter along +z to the hit (or the far end of the window).
    sensor_T = sensor_poses(cell, scan.q_true[idx])
    d = np.nanmean(scan.d, axis=1) if scan.beams > 1 else scan.d[:, 0]
    length = np.where(np.isfinite(d[idx]), d[idx], cell.scenario.sensor.window_m[1])
    start = sensor_T[:, :3, 3]
    end = start + sensor_T[:, :3, 2] * length[:, None]
    strips = np.stack([start, end], axis=1)
    rr.send_columns("world/scan/beam", indexes=[times], columns=[
        *rr.LineStrips3D.columns(strips=strips).partition(np.ones(len(idx), dtype=int)),
    ])
    rr.log("world/scan/beam", rr.LineStrips3D.from_fields(colors=[[255, 40, 40]], radii=0.0004), static=True)
    # Points in the world frame, appearing as measured (chunks of POINT_CHUNK ms).
    pts = scan.points_base.reshape(len(scan.t), -1, 3)
    ok = scan.valid.reshape(len(scan.t), -1)
    R, p = T_world_base[:3, :3], T_world_base[:3, 3]
    for i0 in range(0, len(scan.t), POINT_CHUNK):
        sel = ok[i0:i0 + POINT_CHUNK]
        if not sel.any():
            continue
        chunk = pts[i0:i0 + POINT_CHUNK][sel] @ R.T + p
        rr.set_time("sim_time", duration=float(scan.t[i0]))
        rr.log(f"world/scan/points/{i0:08d}", rr.Points3D(chunk, radii=0.0003, colors=[[30, 200, 90]]))
    rr.send_columns("plots/d_mm", indexes=[rr.TimeColumn("sim_time", duration=scan.t)],
                    columns=rr.Scalars.columns(scalars=np.nan_to_num(d * 1e3, nan=np.nan)))

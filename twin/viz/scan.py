"""The scan on the ``sim_time`` timeline: the moving arm, the beam, the points, the distance.

The points are one entity (``world/scan/points``) logged chunk by chunk as they are measured
and coloured by their signed distance to the TRUE surface on a fixed scale
(:data:`DEVIATION_SCALE_M`, blue - white - red; grey off the part); ``world/scan/points_by_line``
holds the same points coloured by scan line, and ``world/scan/points_by_status`` every sample
whose beam met the part, at the ideal hit, coloured by the sensor's status
(:data:`STATUS_COLOURS`: the points the sensor refused, and why). The beam is a unit segment in its own frame,
scaled to the measured distance, and hidden when the scan ends.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import rerun as rr

from twin import evaluate
from twin.cell import Cell
from twin.robot import UR5E_DH
from twin.sensors.base import INCIDENCE, OCCLUDED, OUT_OF_WINDOW, STATUS_NAMES, VALID
from twin.viz.blueprint import deviation_colours
from twin.viz.cell import body_poses, sensor_poses

if TYPE_CHECKING:
    from algorithms.geometry.mesh_index import MeshIndex
    from twin.scan import Scan

POSE_EVERY = 10      # arm and beam logged every 10 ms (points and distances every 1 ms)
POINT_CHUNK = 100    # points logged 100 ms at a time
DEVIATION_SCALE_M = 10e-6
OFF_PART_M = 1e-3    # a point farther than this from the true surface is off the part (the table)
LINE_PALETTE = np.array([[31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40], [148, 103, 189],
                         [140, 86, 75], [227, 119, 194], [127, 127, 127], [188, 189, 34], [23, 190, 207]],
                        dtype=np.uint8)
#: Colour of each sensor status in ``world/scan/points_by_status`` (no hit: no point to show).
STATUS_COLOURS = {VALID: (40, 180, 70), OUT_OF_WINDOW: (150, 60, 200), INCIDENCE: (240, 150, 20),
                  OCCLUDED: (220, 40, 40)}
STATUS_LEGEND = ", ".join(f"{STATUS_NAMES[k]} rgb{v}" for k, v in STATUS_COLOURS.items())


def log_scan(cell: Cell, scan: Scan, T_world_base: np.ndarray, index: MeshIndex | None = None) -> None:
    """The arm moving, the beam, the points appearing and the distance, on ``sim_time``.
    ``index``: the part's MeshIndex for the deviation colours (built from the cell's mesh if None)."""
    idx = np.arange(0, len(scan.t), POSE_EVERY)
    times = rr.TimeColumn("sim_time", duration=scan.t[idx])
    poses = body_poses(cell, scan.q_true[idx])
    for name, T in poses.items():
        rr.send_columns(f"world/robot/{name}", indexes=[times], columns=rr.Transform3D.columns(
            translation=T[:, :3, 3], mat3x3=T[:, :3, :3]))
    # Beam: a unit segment along the sensor's z, scaled to the distance (the far end of the window
    # when invalid); scaled to nothing once the scan is over.
    sensor_T = sensor_poses(cell, scan.q_true[idx])
    d = np.nanmean(scan.d, axis=1) if scan.beams > 1 else scan.d[:, 0]
    length = np.where(np.isfinite(d[idx]), d[idx], cell.scenario.sensor.window_m[1])
    mats = sensor_T[:, :3, :3] * np.r_[1.0, 1.0, 0.0][None, None, :] + \
        sensor_T[:, :3, 2:3] * (length[:, None, None] * np.array([0.0, 0.0, 1.0])[None, None, :])
    end_t = float(scan.t[-1]) + float(scan.t[1] - scan.t[0]) if len(scan.t) > 1 else float(scan.t[-1])
    mats = np.concatenate([mats, np.zeros((1, 3, 3))])
    trans = np.concatenate([sensor_T[:, :3, 3], sensor_T[-1:, :3, 3]])
    rr.send_columns("world/scan/beam", indexes=[rr.TimeColumn("sim_time", duration=np.r_[scan.t[idx], end_t])],
                    columns=rr.Transform3D.columns(translation=trans, mat3x3=mats))
    rr.log("world/scan/beam/ray", rr.LineStrips3D([[[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]]], colors=[[255, 40, 40]],
                                                  radii=0.0004), static=True)
    # Points in the world frame, one entity, appearing as measured.
    n = len(scan.t)
    pts = scan.points_base.reshape(n, -1, 3)
    ok = scan.valid.reshape(n, -1)
    line = np.repeat(scan.line[:, None], pts.shape[1], axis=1)
    dev = _deviation(cell, scan, pts[ok], index)
    dev_all = np.full(ok.shape, np.nan)
    dev_all[ok] = dev
    R, p = T_world_base[:3, :3], T_world_base[:3, 3]
    for i0 in range(0, n, POINT_CHUNK):
        sel = ok[i0:i0 + POINT_CHUNK]
        if not sel.any():
            continue
        chunk = pts[i0:i0 + POINT_CHUNK][sel] @ R.T + p
        rr.set_time("sim_time", duration=float(scan.t[i0]))
        rr.log("world/scan/points", rr.Points3D(chunk, radii=0.0003,
                                                colors=deviation_colours(dev_all[i0:i0 + POINT_CHUNK][sel],
                                                                         DEVIATION_SCALE_M)))
        lines = line[i0:i0 + POINT_CHUNK][sel]
        rr.log("world/scan/points_by_line", rr.Points3D(chunk, radii=0.0003,
                                                        colors=LINE_PALETTE[np.maximum(lines, 0) % len(LINE_PALETTE)]))
    _log_status(scan, T_world_base)
    rr.send_columns("plots/scan/d_mm", indexes=[rr.TimeColumn("sim_time", duration=scan.t)],
                    columns=rr.Scalars.columns(scalars=np.nan_to_num(d * 1e3, nan=np.nan)))


def _log_status(scan, T_world_base: np.ndarray) -> None:
    """Every sample whose beam met the part, at its ideal hit as the controller would place it
    (logged joints, believed hand-eye), coloured by status and appearing as measured."""
    n = len(scan.t)
    d_hit = np.where(scan.d_true > 0, scan.d_true, np.nan)
    hits = scan.sensor.reconstruct(scan.q, d_hit, UR5E_DH, scan.T_flange_sensor_nominal).reshape(n, -1, 3)
    status = scan.status.reshape(n, -1)
    met = np.isfinite(hits).all(axis=2)
    palette = np.zeros((int(status.max(initial=0)) + 1, 3), dtype=np.uint8)
    for code, colour in STATUS_COLOURS.items():
        if code < len(palette):
            palette[code] = colour
    R, p = T_world_base[:3, :3], T_world_base[:3, 3]
    for i0 in range(0, n, POINT_CHUNK):
        sel = met[i0:i0 + POINT_CHUNK]
        if not sel.any():
            continue
        rr.set_time("sim_time", duration=float(scan.t[i0]))
        rr.log("world/scan/points_by_status", rr.Points3D(hits[i0:i0 + POINT_CHUNK][sel] @ R.T + p, radii=0.0003,
                                                          colors=palette[status[i0:i0 + POINT_CHUNK][sel]]))


def _deviation(cell: Cell, scan, points_base: np.ndarray, index) -> np.ndarray:
    """Signed distance [m] of base-frame points to the TRUE surface; NaN off the part."""
    if len(points_base) == 0:
        return np.zeros(0)
    if index is None:
        from algorithms.geometry.mesh_index import MeshIndex

        index = MeshIndex(cell.mesh)
    dev = evaluate.surface_error_m(points_base, scan.T_base_workpiece_true, index)
    dev[np.abs(dev) > OFF_PART_M] = np.nan
    return dev

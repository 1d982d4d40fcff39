"""The scan on the ``sim_time`` timeline: the moving arm, the beam, the points, the distance.

The points are one entity (``world/scan/points``) logged chunk by chunk as they are measured
and coloured by their signed distance to the TRUE surface (the twin's own check of its
sensor) on :func:`truth_scale`: green within the expanded uncertainty of a point (k = 2),
the scale of :mod:`twin.deviation` beyond; ``world/scan/points_by_line`` holds the same points
coloured by scan line, and ``world/scan/points_by_status`` every sample whose beam met the
part, at the ideal hit, coloured by the sensor's status (:data:`STATUS_COLOURS`: the points the
sensor refused, and why). The beam is a unit segment in its own frame, scaled to the measured
distance, and shrunk to 1 um when the scan ends (a zero length would be a singular transform).
The map against the CAD model at the estimate is logged with the estimate
(:func:`twin.viz.recording.log_estimate`).
"""

from __future__ import annotations

import numpy as np
import rerun as rr

from twin import evaluate
from twin.cell import Cell
from twin.deviation import OFF_PART_M, DeviationScale, deviation_colours, deviation_scale
from twin.robot import UR5E_DH
from twin.sensors.base import INCIDENCE, OCCLUDED, OUT_OF_WINDOW, STATUS_NAMES, VALID
from twin.sensors.laser import sensor_sigma_m
from twin.viz.cell import send_arm, sensor_poses
from twin.viz.columns import POSE_PERIOD_S, every, send_series

POINT_CHUNK = 100    # points logged 100 ms at a time
#: Length [m] the beam is shrunk to when the scan ends.
BEAM_HIDDEN_M = 1e-6
LINE_PALETTE = np.array([[31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40], [148, 103, 189],
                         [140, 86, 75], [227, 119, 194], [127, 127, 127], [188, 189, 34], [23, 190, 207]],
                        dtype=np.uint8)
#: Colour of each sensor status in ``world/scan/points_by_status`` (no hit: no point to show).
STATUS_COLOURS = {VALID: (40, 180, 70), OUT_OF_WINDOW: (150, 60, 200), INCIDENCE: (240, 150, 20),
                  OCCLUDED: (220, 40, 40)}
STATUS_LEGEND = ", ".join(f"{STATUS_NAMES[k]} rgb{v}" for k, v in STATUS_COLOURS.items())


def truth_scale(u_point_m: float) -> DeviationScale:
    """The scale of the points against the TRUE surface: green within U = 2 u of a point."""
    return deviation_scale(2.0 * u_point_m, u_point_m)


def log_scan(cell: Cell, scan, T_world_base: np.ndarray, truth: evaluate.Evaluation) -> None:
    """The arm moving, the beam, the points appearing and the distance, on ``sim_time``;
    ``truth`` gives the points' deviation from the true surface (their colours) and the ideal hits."""
    idx = every(scan.t, POSE_PERIOD_S)
    send_arm(cell, scan.t[idx], scan.q_true[idx])
    # Beam: a unit segment along the sensor's z, scaled to the distance (the far end of the window
    # when invalid); shrunk to BEAM_HIDDEN_M once the scan is over.
    sensor_T = sensor_poses(cell, scan.q_true[idx])
    d = np.nanmean(scan.d, axis=1) if scan.beams > 1 else scan.d[:, 0]
    length = np.where(np.isfinite(d[idx]), d[idx], cell.scenario.sensor.window_m[1])
    mats = sensor_T[:, :3, :3] * np.r_[1.0, 1.0, 0.0][None, None, :] + \
        sensor_T[:, :3, 2:3] * (length[:, None, None] * np.array([0.0, 0.0, 1.0])[None, None, :])
    end_t = float(scan.t[-1]) + float(scan.t[1] - scan.t[0]) if len(scan.t) > 1 else float(scan.t[-1])
    shrunk = sensor_T[-1:, :3, :3] * np.r_[1.0, 1.0, BEAM_HIDDEN_M][None, None, :]
    mats = np.concatenate([mats, shrunk])
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
    dev = _deviation(truth, pts[ok])
    dev_all = np.full(ok.shape, np.nan)
    dev_all[ok] = dev
    scale = truth_scale(sensor_sigma_m(cell.scenario))
    R, p = T_world_base[:3, :3], T_world_base[:3, 3]
    for i0 in range(0, n, POINT_CHUNK):
        sel = ok[i0:i0 + POINT_CHUNK]
        if not sel.any():
            continue
        chunk = pts[i0:i0 + POINT_CHUNK][sel] @ R.T + p
        rr.set_time("sim_time", duration=float(scan.t[i0]))
        rr.log("world/scan/points", rr.Points3D(chunk, radii=0.0003,
                                                colors=deviation_colours(dev_all[i0:i0 + POINT_CHUNK][sel],
                                                                         scale)))
        lines = line[i0:i0 + POINT_CHUNK][sel]
        rr.log("world/scan/points_by_line", rr.Points3D(chunk, radii=0.0003,
                                                        colors=LINE_PALETTE[np.maximum(lines, 0) % len(LINE_PALETTE)]))
    _log_status(scan, T_world_base)
    send_series("plots/scan/d_mm", scan.t, d * 1e3)


def _log_status(scan, T_world_base: np.ndarray) -> None:
    """Every sample whose beam met the part, at its ideal hit as the controller would place it
    (logged joints, believed hand-eye), coloured by status and appearing as measured."""
    n = len(scan.t)
    d_ideal = evaluate.ideal_distances_m(scan)
    d_hit = np.where(d_ideal > 0, d_ideal, np.nan)
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


def _deviation(truth: evaluate.Evaluation, points_base: np.ndarray) -> np.ndarray:
    """Signed distance [m] of base-frame points to the TRUE surface; NaN off the part."""
    if len(points_base) == 0:
        return np.zeros(0)
    dev = truth.surface_error_m(points_base)
    dev[np.abs(dev) > OFF_PART_M] = np.nan
    return dev

"""Scan evaluation against the truth only the simulator knows."""

from __future__ import annotations

import numpy as np

from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.kinematics import dh_forward
from algorithms.geometry.se3 import inv_pose, transform_points
from twin.robot import UR5E_DH
from twin.sensor import STATUS_NAMES


def scan_report(scan, mesh, index: MeshIndex | None = None) -> dict:
    """Counts, point-to-true-surface residuals and servo tracking of a scan (SI units unless named)."""
    index = index or MeshIndex(mesh)
    pts = scan.valid_points_base.reshape(-1, 3)
    p_wp = transform_points(inv_pose(scan.T_base_workpiece_true), pts)
    to_part = index.query(p_wp).distance if len(pts) else np.empty(0)
    to_table = np.abs(transform_points(scan.scenario.T_world_base, pts)[:, 2])
    on_part = to_part <= to_table
    r = to_part[on_part]
    counts = np.bincount(scan.status.ravel(), minlength=len(STATUS_NAMES))
    T_ref = dh_forward(scan.q_ref, UR5E_DH) @ scan.T_flange_sensor_nominal
    T_act = dh_forward(scan.q_true, UR5E_DH) @ scan.T_flange_sensor_nominal
    dev = np.linalg.norm(T_ref[:, :3, 3] - T_act[:, :3, 3], axis=1)
    sim_s = float(len(scan.t) * (scan.t[1] - scan.t[0])) if len(scan.t) > 1 else 0.0
    return {
        "samples": int(len(scan.t)),
        "duration_s": float(scan.t[-1]),
        "sample_period_s": float(scan.t[1] - scan.t[0]) if len(scan.t) > 1 else None,
        "status_counts": {STATUS_NAMES[k]: int(v) for k, v in enumerate(counts)},
        "points_on_part": int(on_part.sum()),
        "points_on_table": int((~on_part).sum()),
        "residual_rms_um": float(np.sqrt(np.mean(r**2)) * 1e6) if len(r) else None,
        "residual_max_um": float(r.max() * 1e6) if len(r) else None,
        "servo_tracking_max_mm": float(dev.max() * 1e3),
        "servo_tracking_rms_mm": float(np.sqrt(np.mean(dev**2)) * 1e3),
        "sim_speed_x_realtime": float(sim_s / scan.timings_s["simulate_s"]),
        "timings_s": {k: round(v, 4) for k, v in scan.timings_s.items()},
    }

"""Scan planning: a raster of scan lines over the workpiece, seen on the CAD model at the NOMINAL pose.

Lines run along the workpiece's x (or y) axis, ``line_spacing_m`` apart, alternating direction.
Each line is found by casting rays at the nominal CAD model (1 mm apart, along -z of the
workpiece, or along the fixed beam direction); the sensor sits at the stand-off along the
(smoothed) surface normal or the fixed direction, its +z on the beam and its +x along the line axis.
Between lines the sensor retracts, moves over and approaches. Each segment follows a
trapezoidal speed profile; poses come out every 1 ms.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import mujoco.batch
import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.spatial.transform import Rotation, Slerp

from algorithms.geometry.raycast import GRID_SHIFT_M
from algorithms.geometry.se3 import transform_points
from twin.cell import Cell
from twin.errors import TwinError
from twin.robot import WORKPIECE_GROUPS

PLAN_STEP_M = 0.001          # ray spacing along a line on the CAD model
NORMAL_SMOOTHING_M = 0.003   # Gaussian smoothing of the normals along a line (sigma)
ACCELERATION_M_S2 = 0.5      # trapezoidal profile acceleration of every segment
# Where the beam follows a curved normal the sensor also turns; the path slows down so that it
# turns at most this fast (the wrist joints of the UR5e reach pi rad/s; IK needs headroom).
ANGULAR_SPEED_RAD_S = 0.5


@dataclass(frozen=True)
class ScanPlan:
    """Sensor poses every ``dt`` seconds.

    Attributes:
        t: (K,) times [s], exactly ``dt`` apart from 0.
        T_world_sensor: (K, 4, 4) planned sensor poses (world).
        line: (K,) scan-line index, -1 during approach, retract and line changes.
        line_y_m: (L,) cross-line coordinate of each line in the workpiece frame [m].
        dt: step [s].
    """

    t: np.ndarray
    T_world_sensor: np.ndarray
    line: np.ndarray
    line_y_m: np.ndarray
    dt: float

    @property
    def duration_s(self) -> float:
        return float(self.t[-1]) if len(self.t) else 0.0


def _frames(z: np.ndarray, tangent: np.ndarray) -> np.ndarray:
    """Rotation matrices with +z along ``z`` and +x along ``tangent`` projected off z."""
    x = tangent - np.einsum("ij,ij->i", tangent, z)[:, None] * z
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=2)


def _trapezoid_s(length: float, v_max: float, a_max: float, dt: float) -> np.ndarray:
    """Arc length at every ``dt`` of a rest-to-rest trapezoidal profile, ending exactly at ``length``."""
    if length <= 0:
        return np.zeros(1)
    t_acc = v_max / a_max
    if a_max * t_acc**2 >= length:  # triangle profile
        t_acc = np.sqrt(length / a_max)
        v_max = a_max * t_acc
    t_flat = (length - a_max * t_acc**2) / v_max
    total = 2 * t_acc + t_flat
    n = int(np.ceil(total / dt - 1e-9))
    t = np.arange(n + 1) * dt
    t[-1] = min(t[-1], total)
    s = np.where(t < t_acc, 0.5 * a_max * t**2,
                 np.where(t < t_acc + t_flat, 0.5 * a_max * t_acc**2 + v_max * (t - t_acc),
                          length - 0.5 * a_max * np.maximum(total - t, 0.0) ** 2))
    return np.clip(s, 0.0, length)


def _interp_poses(T_path: np.ndarray, s_path: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Poses at arc lengths ``s`` on a polyline of poses (linear position, slerp rotation)."""
    out = np.empty((len(s), 4, 4))
    out[:] = np.eye(4)
    for k in range(3):
        out[:, k, 3] = np.interp(s, s_path, T_path[:, k, 3])
    if len(s_path) == 1:
        out[:, :3, :3] = T_path[0, :3, :3]
    else:
        out[:, :3, :3] = Slerp(s_path, Rotation.from_matrix(T_path[:, :3, :3]))(s).as_matrix()
    return out


def _segment(T_path: np.ndarray, s_path: np.ndarray, speed: float, dt: float) -> np.ndarray:
    s = _trapezoid_s(float(s_path[-1]), speed, ACCELERATION_M_S2, dt)
    return _interp_poses(T_path, s_path, s)


def _straight(T_a: np.ndarray, T_b: np.ndarray, speed: float, dt: float) -> np.ndarray:
    length = float(np.linalg.norm(T_b[:3, 3] - T_a[:3, 3]))
    # Rotation-only moves: give them a length so they take time (1 rad ~ 0.1 m).
    ang = float(np.linalg.norm(Rotation.from_matrix(T_a[:3, :3].T @ T_b[:3, :3]).as_rotvec()))
    length = max(length, 0.1 * ang, 1e-6)
    return _segment(np.stack([T_a, T_b]), np.array([0.0, length]), speed, dt)


def scan_region(cell: Cell) -> tuple[tuple[float, float], tuple[float, float]]:
    spec = cell.scenario.scan
    if spec.region_m is not None:
        return spec.region_m
    lo, hi = cell.mesh.bounds[0, :2], cell.mesh.bounds[1, :2]
    m = spec.margin_m
    if np.any(hi - lo <= 2 * m):
        raise TwinError(f"scan.margin_m = {m:g} m leaves no region on a {hi - lo} m part")
    return (float(lo[0] + m), float(lo[1] + m)), (float(hi[0] - m), float(hi[1] - m))


def _cast_line(cell: Cell, batch, u: np.ndarray, v: float, axis: str, direction_wp: np.ndarray):
    """Cast planning rays at the nominal CAD model; returns hit mask, points and normals (workpiece frame)."""
    top = cell.mesh.bounds[1, 2]
    if axis == "x":
        xy = np.column_stack([u, np.full_like(u, v)])
    else:
        xy = np.column_stack([np.full_like(u, v), u])
    start_wp = np.column_stack([xy, np.full(len(u), top)])
    # The region is a grid on the plane of the part's top (z = max z of the mesh): each ray
    # passes through its grid point and starts 50 mm higher, back along the beam.
    start_wp = start_wp - direction_wp * (0.05 / max(-direction_wp[2], 0.2))
    T = cell.T_world_workpiece
    start_w = transform_points(T, start_wp)
    dir_w = np.broadcast_to(T[:3, :3] @ direction_wp, start_w.shape).copy()
    dist, _, normal = batch.ray(start_w, dir_w, geomgroup=WORKPIECE_GROUPS, flg_static=True, normal=True)
    dist, normal = dist[0], normal[0]
    hit = dist >= 0
    p_w = start_w + dir_w * dist[:, None]
    R = T[:3, :3]
    return hit, (p_w - T[:3, 3]) @ R, normal @ R


def plan_scan(cell: Cell, dt: float = 0.001) -> ScanPlan:
    """Plan the raster scan on the nominal cell (poses in the world frame)."""
    if cell.which != "nominal":
        raise TwinError("scan planning uses the nominal cell (what the planner believes)")
    spec = cell.scenario.scan
    (x0, y0), (x1, y1) = scan_region(cell)
    axis = spec.line_axis
    (u0, u1), (v0, v1) = ((x0, x1), (y0, y1)) if axis == "x" else ((y0, y1), (x0, x1))
    v_lines = np.arange(v0, v1 - GRID_SHIFT_M, spec.line_spacing_m) + GRID_SHIFT_M
    if len(v_lines) > spec.max_lines:
        v_lines = v_lines[: spec.max_lines]
    u = np.arange(u0, u1 - GRID_SHIFT_M, PLAN_STEP_M) + GRID_SHIFT_M
    plan_dir_wp = np.array([0.0, 0.0, -1.0]) if spec.beam == "normal" else spec.direction
    batch = mujoco.batch.Batch(cell.model, 1, nthread=1)
    T_wp = cell.T_world_workpiece
    lines = []
    for i, v in enumerate(v_lines):
        hit, p, n = _cast_line(cell, batch, u, float(v), axis, plan_dir_wp)
        if hit.sum() < 2:
            continue
        # Longest run of consecutive hits: the line's span on the part.
        idx = np.flatnonzero(hit)
        runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
        run = max(runs, key=len)
        if len(run) < 2:
            continue
        p, n = p[run], n[run]
        if len(lines) % 2 == 1:
            p, n = p[::-1], n[::-1]
        if spec.beam == "normal":
            n = gaussian_filter1d(n, NORMAL_SMOOTHING_M / PLAN_STEP_M, axis=0, mode="nearest")
            beam = -n / np.linalg.norm(n, axis=1, keepdims=True)
        else:
            beam = np.broadcast_to(spec.direction, p.shape)
        # Sensor +x along the line axis (not the travel direction), so the wrist does not
        # turn half a revolution at every line change.
        axis_wp = np.array([1.0, 0.0, 0.0]) if axis == "x" else np.array([0.0, 1.0, 0.0])
        R_wp = _frames(beam, np.broadcast_to(axis_wp, beam.shape))
        origin_wp = p - spec.standoff_m * beam
        T_line = np.empty((len(p), 4, 4))
        T_line[:] = np.eye(4)
        T_line[:, :3, :3] = T_wp[:3, :3] @ R_wp
        T_line[:, :3, 3] = transform_points(T_wp, origin_wp)
        # Path parameter: surface arc length, stretched where the sensor must turn faster
        # than ANGULAR_SPEED_RAD_S at the scan speed.
        ds = np.linalg.norm(np.diff(p, axis=0), axis=1)
        dtheta = np.linalg.norm(Rotation.from_matrix(
            np.einsum("nji,njk->nik", R_wp[:-1], R_wp[1:])).as_rotvec(), axis=1)
        ds_eff = np.maximum(ds, dtheta * spec.speed_m_s / ANGULAR_SPEED_RAD_S)
        s_path = np.concatenate([[0.0], np.cumsum(ds_eff)])
        lines.append((i, float(v), T_line, s_path))
    if not lines:
        raise TwinError("the scan region does not cover the part: no scan line hits the nominal CAD model")

    poses, labels = [], []
    prev = None
    for i, _v, T_line, s_path in lines:
        start, end = T_line[0], T_line[-1]
        above_start = start.copy()
        above_start[:3, 3] -= spec.retract_m * start[:3, 2]
        if prev is None:
            seg = [above_start[None]]
        else:
            seg = [_straight(prev, above_start, spec.transit_speed_m_s, dt)[1:]]
        seg.append(_straight(above_start, start, spec.transit_speed_m_s, dt)[1:])
        for s_ in seg:
            poses.append(s_)
            labels.append(np.full(len(s_), -1))
        scan = _segment(T_line, s_path, spec.speed_m_s, dt)[1:]
        poses.append(scan)
        labels.append(np.full(len(scan), i))
        retract = end.copy()
        retract[:3, 3] -= spec.retract_m * end[:3, 2]
        r = _straight(end, retract, spec.transit_speed_m_s, dt)[1:]
        poses.append(r)
        labels.append(np.full(len(r), -1))
        prev = retract
    T_all = np.concatenate(poses)
    line = np.concatenate(labels).astype(np.int32)
    t = np.arange(len(T_all)) * dt
    return ScanPlan(t, T_all, line, np.array([ln[1] for ln in lines]), dt)

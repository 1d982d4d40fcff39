"""Scan lines on the nominal CAD model, the motion through them, and what they predict.

The pieces :func:`twin.plan.plan_scan` assembles a plan from (see :mod:`twin.plan`): the plan's
types (:class:`ScanPlan`, :class:`PassInfo`), planning rays cast at the nominal CAD model, the
lines of the ``[scan]`` table's single pass and of a pass with a view direction
(:func:`pass_runs`), the sensor poses along a line, the motion between lines and passes
(:func:`straight_poses`, trapezoidal speed profiles, poses every ``dt``), document 001's level
raster (:func:`plan_level_raster`), and the observability the planned points predict.

Frames: the workpiece frame for planning points, normals and views; the world frame for the
sensor poses. Units: metres, radians, seconds.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import mujoco
import mujoco.batch
import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.spatial.transform import Rotation, Slerp

from algorithms.arraytypes import BoolArray, FloatArray, IntArray
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.raycast import GRID_SHIFT_M
from algorithms.geometry.se3 import transform_points
from algorithms.registration.uncertainty import OBSERVABILITY_TOL, information_rows, observability
from twin.cell import Cell
from twin.errors import TwinError
from twin.robot import WORKPIECE_GROUPS
from twin.scenario import PassSpec, ScanSpec

PLAN_STEP_M = 0.001          # ray spacing along a line on the CAD model
NORMAL_SMOOTHING_M = 0.003   # Gaussian smoothing of the normals along a line (sigma)
ACCELERATION_M_S2 = 0.5      # trapezoidal profile acceleration of every segment
# Where the beam follows a curved normal the sensor also turns; the path slows down so that it
# turns at most this fast (the wrist joints of the UR5e reach pi rad/s; IK needs headroom).
ANGULAR_SPEED_RAD_S = 0.5

# Multi-pass lines. A line ends where the face normal turns by more than SHARP_EDGE_DEG
# between neighbouring rays (an edge) or where neighbouring hits lie farther apart than
# STEP_JUMP_FACTOR times the farthest a surface within the incidence limit can put them (a
# step); hits seen within INCIDENCE_MARGIN_DEG of the sensor's limit are left out, so that the
# part's small offset from the nominal pose does not lose them; lines shorter than MIN_LINE_M
# are dropped (their approach and retract would cost more than they give).
SHARP_EDGE_DEG = 25.0
STEP_JUMP_FACTOR = 1.5
INCIDENCE_MARGIN_DEG = 5.0
MIN_LINE_M = 0.004
# Planning rays start this far before the region, back along the view.
RAY_START_M = 0.05
# A coordinate direction counts as fixed when less than this part of it lies in the weak
# subspace of the predicted information.
FIXED_WEAK_FRACTION = 0.5
COORDINATE_NAMES = ("rx", "ry", "rz", "x", "y", "z")


@dataclass(frozen=True)
class PassInfo:
    """One pass of a plan, as the report shows it.

    Attributes:
        name: the pass's name.
        beam: "fixed" or "normal".
        beam_wp: (3,) the view direction in the workpiece frame (the beam when fixed; the
            planning direction when the beam follows the normal).
        lines: number of scan lines of the pass.
        first_line: global index of its first scan line.
        reason: why the pass is in the plan.
        predicted_min_relative_eigenvalue: smallest relative eigenvalue of the predicted
            information of this pass and the ones before it (see
            :func:`algorithms.registration.uncertainty.observability`).
        fixed: the coordinate directions the passes so far fix ("x", ..., "rz"), predicted.
    """

    name: str
    beam: str
    beam_wp: tuple[float, float, float]
    lines: int
    first_line: int
    reason: str
    predicted_min_relative_eigenvalue: float
    fixed: tuple[str, ...]

    def to_dict(self) -> dict:
        return {
            "name": self.name, "beam": self.beam, "beam_wp": [float(v) for v in self.beam_wp],
            "lines": self.lines, "first_line": self.first_line, "reason": self.reason,
            "predicted_min_relative_eigenvalue": float(self.predicted_min_relative_eigenvalue),
            "fixed": list(self.fixed),
        }


def _view3(view: FloatArray) -> tuple[float, float, float]:
    """A (3,) view direction as the report's tuple of floats."""
    x, y, z = (float(c) for c in view)
    return x, y, z


@dataclass(frozen=True)
class ScanPlan:
    """Sensor poses every ``dt`` seconds.

    Attributes:
        t: (K,) times [s], exactly ``dt`` apart from 0.
        T_world_sensor: (K, 4, 4) planned sensor poses (world).
        line: (K,) scan-line index (unique across passes), -1 during approach, retract, line
            and pass changes.
        line_y_m: (L,) cross-line coordinate of each line in its pass's plane [m].
        dt: step [s].
        line_pass: (L,) the pass index of each scan line (``line_pass[line]``; one pass: zeros).
        passes: what each pass is and why it was planned.
        notes: what the planner could not do (unreachable views, directions left weak).
    """

    t: np.ndarray
    T_world_sensor: np.ndarray
    line: np.ndarray
    line_y_m: np.ndarray
    dt: float
    line_pass: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int32))
    passes: tuple[PassInfo, ...] = ()
    notes: tuple[str, ...] = ()

    @property
    def duration_s(self) -> float:
        return float(self.t[-1]) if len(self.t) else 0.0


@dataclass(frozen=True)
class _Line:
    """One planned scan line: its sensor poses along a path parameter, with the motion settings."""

    index: int
    pass_index: int
    cross_m: float
    T_world_sensor: np.ndarray
    s_path: np.ndarray
    speed_m_s: float
    transit_speed_m_s: float
    retract_m: float


@dataclass(frozen=True)
class _Run:
    """A run of planning hits that makes one line (workpiece frame)."""

    row: int
    cross_m: float
    points_wp: np.ndarray
    normals_wp: np.ndarray
    smooth_normals_wp: np.ndarray


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


def straight_poses(T_a: np.ndarray, T_b: np.ndarray, speed: float, dt: float) -> np.ndarray:
    """(K, 4, 4) poses every ``dt`` of a rest-to-rest straight move from ``T_a`` to ``T_b`` at
    ``speed`` [m/s] (trapezoidal, ``ACCELERATION_M_S2``), rotation by slerp."""
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


def _cast_wp(cell: Cell, batch: mujoco.batch.Batch, start_wp: FloatArray,
             direction_wp: FloatArray) -> tuple[BoolArray, FloatArray, FloatArray]:
    """Cast rays from ``start_wp`` along ``direction_wp`` (workpiece frame) at the nominal CAD
    model; returns hit mask, points and face normals (workpiece frame)."""
    T = cell.T_world_workpiece
    start_w = transform_points(T, start_wp)
    dir_w = np.broadcast_to(T[:3, :3] @ direction_wp, start_w.shape).copy()
    dist, _, normal = batch.ray(start_w, dir_w, geomgroup=WORKPIECE_GROUPS, flg_static=True, normal=True)
    dist, normal = dist[0], normal[0]
    hit = dist >= 0
    p_w = start_w + dir_w * dist[:, None]
    R = T[:3, :3]
    return hit, (p_w - T[:3, 3]) @ R, normal @ R


def _cast_line(cell: Cell, batch: mujoco.batch.Batch, u: FloatArray, v: float, axis: str,
               direction_wp: FloatArray) -> tuple[BoolArray, FloatArray, FloatArray]:
    """Planning rays of one single-pass line; returns hit mask, points and normals (workpiece frame)."""
    top = cell.mesh.bounds[1, 2]
    if axis == "x":
        xy = np.column_stack([u, np.full_like(u, v)])
    else:
        xy = np.column_stack([np.full_like(u, v), u])
    start_wp = np.column_stack([xy, np.full(len(u), top)])
    # The region is a grid on the plane of the part's top (z = max z of the mesh): each ray
    # passes through its grid point and starts 50 mm higher, back along the beam.
    start_wp = start_wp - direction_wp * (0.05 / max(-direction_wp[2], 0.2))
    return _cast_wp(cell, batch, start_wp, direction_wp)


def _line_poses(T_world_workpiece: np.ndarray, p: np.ndarray, beam: np.ndarray, axis_wp: np.ndarray,
                standoff_m: float, speed_m_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Sensor poses (world) along one line and their path parameter.

    Args:
        p: (n, 3) surface points [m], beam: (n, 3) unit beams, axis_wp: (3,) sensor +x
            direction (projected off the beam), all in the workpiece frame.
    """
    R_wp = _frames(beam, np.broadcast_to(axis_wp, beam.shape))
    origin_wp = p - standoff_m * beam
    T_line = np.empty((len(p), 4, 4))
    T_line[:] = np.eye(4)
    T_line[:, :3, :3] = T_world_workpiece[:3, :3] @ R_wp
    T_line[:, :3, 3] = transform_points(T_world_workpiece, origin_wp)
    # Path parameter: surface arc length, stretched where the sensor must turn faster
    # than ANGULAR_SPEED_RAD_S at the scan speed.
    ds = np.linalg.norm(np.diff(p, axis=0), axis=1)
    dtheta = np.linalg.norm(Rotation.from_matrix(
        np.einsum("nji,njk->nik", R_wp[:-1], R_wp[1:])).as_rotvec(), axis=1)
    ds_eff = np.maximum(ds, dtheta * speed_m_s / ANGULAR_SPEED_RAD_S)
    return T_line, np.concatenate([[0.0], np.cumsum(ds_eff)])


def _beam_along(normals: np.ndarray) -> np.ndarray:
    """Unit beams against the normals smoothed along a line."""
    n = gaussian_filter1d(normals, NORMAL_SMOOTHING_M / PLAN_STEP_M, axis=0, mode="nearest")
    return -n / np.linalg.norm(n, axis=1, keepdims=True)


def _longest_run(hit: BoolArray) -> IntArray | None:
    """Indices of the longest run of consecutive hits (the line's span on the part), or None
    when it has fewer than two."""
    if hit.sum() < 2:
        return None
    idx = np.flatnonzero(hit)
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
    run = max(runs, key=len)
    return run if len(run) >= 2 else None


def _plan_single_pass(cell: Cell, spec: ScanSpec, dt: float) -> ScanPlan:
    """The raster of the ``[scan]`` table's own keys (each line the longest run of hits)."""
    (x0, y0), (x1, y1) = scan_region(cell)
    axis = spec.line_axis
    (u0, u1), (v0, v1) = ((x0, x1), (y0, y1)) if axis == "x" else ((y0, y1), (x0, x1))
    v_lines = np.arange(v0, v1 - GRID_SHIFT_M, spec.line_spacing_m) + GRID_SHIFT_M
    if len(v_lines) > spec.max_lines:
        v_lines = v_lines[: spec.max_lines]
    u = np.arange(u0, u1 - GRID_SHIFT_M, PLAN_STEP_M) + GRID_SHIFT_M
    plan_dir_wp = np.array([0.0, 0.0, -1.0]) if spec.beam == "normal" else spec.direction
    # Sensor +x along the line axis (not the travel direction), so the wrist does not turn half
    # a revolution at every line change.
    axis_wp = np.array([1.0, 0.0, 0.0]) if axis == "x" else np.array([0.0, 1.0, 0.0])
    batch = mujoco.batch.Batch(cell.model, 1, nthread=1)
    lines: list[_Line] = []
    pts: list[FloatArray] = []
    for i, v in enumerate(v_lines):
        hit, p, n = _cast_line(cell, batch, u, float(v), axis, plan_dir_wp)
        run = _longest_run(hit)
        if run is None:
            continue
        p, n = p[run], n[run]
        pts.append(p)
        if len(lines) % 2 == 1:
            p, n = p[::-1], n[::-1]
        beam = _beam_along(n) if spec.beam == "normal" else np.broadcast_to(spec.direction, p.shape)
        T_line, s_path = _line_poses(cell.T_world_workpiece, p, beam, axis_wp, spec.standoff_m, spec.speed_m_s)
        lines.append(_Line(i, 0, float(v), T_line, s_path, spec.speed_m_s, spec.transit_speed_m_s,
                           spec.retract_m))
    if not lines:
        raise TwinError("the scan region does not cover the part: no scan line hits the nominal CAD model")
    points = np.concatenate(pts)
    rel, fixed = _predicted(points, _smooth_normals(cell.index, points), OBSERVABILITY_TOL)
    info = PassInfo("scan", spec.beam, _view3(plan_dir_wp), len(lines), lines[0].index,
                    "the [scan] table's single pass" + (f": covers {', '.join(fixed)}" if fixed else ""),
                    rel, fixed)
    plan = _assemble(cell, lines, dt, (info,), ())
    # One entry per planned line, in order (rows without hits have no entry).
    return replace(plan, line_y_m=np.array([ln.cross_m for ln in lines]), line_pass=np.zeros(len(lines), np.int32))


def plan_level_raster(cell: Cell, margin_m: float, line_spacing_m: float, speed_m_s: float,
                      dt: float = 0.001) -> ScanPlan:
    """A level raster at one height, beam straight down, over the nominal part's footprint
    grown by ``margin_m`` on every side (world x-y): document 001's coarse acquisition of a
    part that may lie tens of millimetres and degrees off its nominal pose, so the lines are
    not laid on the nominal CAD model. Lines run along the longer side of the footprint; the
    sensor flies ``near + 2 mm`` above the part's nominal top, so the part's top lies in the
    window and the table (for parts up to the window's depth) beyond it."""
    spec = cell.scenario.scan
    sensor = cell.scenario.sensor
    corners = transform_points(cell.T_world_workpiece, np.asarray(cell.mesh.vertices))
    lo = corners[:, :2].min(axis=0) - margin_m
    hi = corners[:, :2].max(axis=0) + margin_m
    z_s = float(corners[:, 2].max()) + sensor.window_m[0] + 0.002
    along = int(np.argmax(hi - lo))
    across = 1 - along
    rows = np.arange(lo[across] + line_spacing_m / 2, hi[across], line_spacing_m)
    lines = []
    for i, v in enumerate(rows):
        a, b = np.empty(3), np.empty(3)
        a[along], b[along] = (lo[along], hi[along]) if i % 2 == 0 else (hi[along], lo[along])
        a[across] = b[across] = v
        a[2] = b[2] = z_s
        axis = np.zeros(3)
        axis[along] = 1.0
        R = _frames(np.array([[0.0, 0.0, -1.0]]), axis[None])[0]
        T_line = np.stack([np.eye(4), np.eye(4)])
        T_line[:, :3, :3] = R
        T_line[0, :3, 3], T_line[1, :3, 3] = a, b
        lines.append(_Line(i, 0, float(v), T_line, np.array([0.0, float(np.linalg.norm(b - a))]), speed_m_s,
                           spec.transit_speed_m_s, spec.retract_m))
    info = PassInfo("coarse raster", "fixed", (0.0, 0.0, -1.0), len(lines), 0,
                    f"a level raster {margin_m * 1e3:.0f} mm beyond the nominal footprint, {z_s * 1e3:.0f} mm above "
                    "the table: the part may lie far off its nominal pose", float("nan"), ())
    plan = _assemble(cell, lines, dt, (info,), ())
    return replace(plan, line_y_m=rows.copy(), line_pass=np.zeros(len(lines), np.int32))


# --------------------------------------------------------------------------- passes


def _pass_axes(p: PassSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(u, v, d): line axis, cross-line axis and view of a pass (orthonormal, workpiece frame)."""
    d = p.view
    u = p.line_axis - (p.line_axis @ d) * d
    u /= np.linalg.norm(u)
    return u, np.cross(d, u), d


def _region_box(cell: Cell, p: PassSpec) -> tuple[np.ndarray, np.ndarray]:
    """The pass's region clipped to the part's bounding box (workpiece frame) [m]."""
    lo_part, hi_part = cell.mesh.bounds
    if p.region_m is None:
        return lo_part.copy(), hi_part.copy()
    lo = np.array(list(p.region_m[0]) + [lo_part[2]] * (3 - len(p.region_m[0])))
    hi = np.array(list(p.region_m[1]) + [hi_part[2]] * (3 - len(p.region_m[1])))
    lo_c, hi_c = np.maximum(lo, lo_part), np.minimum(hi, hi_part)
    if np.any(lo_c >= hi_c):
        raise TwinError(
            f"scan pass {p.name!r}: region_m {[list(p.region_m[0]), list(p.region_m[1])]} lies outside the part "
            f"(bounds {np.round(lo_part, 4).tolist()} to {np.round(hi_part, 4).tolist()} m, workpiece frame)")
    return lo_c, hi_c


def _split_runs(ok: np.ndarray, p: np.ndarray, n: np.ndarray, step_m: float, max_incidence_rad: float) -> list:
    """Index runs of consecutive usable hits that cross no sharp edge and no step."""
    jump_m = STEP_JUMP_FACTOR * step_m / np.cos(max_incidence_rad)
    gap = np.linalg.norm(np.diff(p, axis=0), axis=1) > jump_m
    edge = np.einsum("ij,ij->i", n[:-1], n[1:]) < np.cos(np.radians(SHARP_EDGE_DEG))
    cut = ~ok[:-1] | ~ok[1:] | gap | edge
    runs, start = [], 0
    for k in np.flatnonzero(cut):
        runs.append(np.arange(start, k + 1))
        start = int(k) + 1
    runs.append(np.arange(start, len(ok)))
    return [r for r in runs if ok[r].all()]


def _trim(run: np.ndarray, p: np.ndarray, margin_m: float) -> np.ndarray:
    """Drop the points within ``margin_m`` (arc length) of either end of a run."""
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p[run], axis=0), axis=1))])
    keep = (s >= margin_m) & (s <= s[-1] - margin_m)
    return run[keep]


def _smooth_normals(index: MeshIndex, points_wp: np.ndarray) -> np.ndarray:
    """Normals of the smooth surface under points on the mesh (facets fake no information)."""
    cp = index.query(points_wp)
    return index.smooth_normals(cp.face, cp.foot)


def pass_runs(cell: Cell, batch: mujoco.batch.Batch, p: PassSpec, index: MeshIndex) -> list[_Run]:
    """The lines of one pass on the nominal CAD model, in raster order (before direction
    alternation), each with its planning points, face normals and smooth-surface normals
    (workpiece frame)."""
    u_ax, v_ax, d = _pass_axes(p)
    lo, hi = _region_box(cell, p)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    cu, cv, cd = corners @ u_ax, corners @ v_ax, corners @ d
    u = np.arange(cu.min(), cu.max() - GRID_SHIFT_M, PLAN_STEP_M) + GRID_SHIFT_M
    # Rows centred across the region, half a spacing or more in from its sides (a row on the
    # very edge of the part would miss it at the true pose).
    n_rows = int(np.floor((cv.max() - cv.min()) / p.line_spacing_m))
    v_rows = 0.5 * (cv.min() + cv.max()) + (np.arange(n_rows) - (n_rows - 1) / 2) * p.line_spacing_m + GRID_SHIFT_M
    if len(u) < 2 or len(v_rows) == 0:
        raise TwinError(f"scan pass {p.name!r}: its region is thinner than one line spacing seen along its view")
    uu, vv = np.meshgrid(u, v_rows)
    start = uu.ravel()[:, None] * u_ax + vv.ravel()[:, None] * v_ax + (cd.min() - RAY_START_M) * d
    hit, pts, nrm = _cast_wp(cell, batch, start, d)
    max_inc = np.radians(cell.scenario.sensor.max_incidence_deg - INCIDENCE_MARGIN_DEG)
    inside = np.all((pts >= lo - 1e-9) & (pts <= hi + 1e-9), axis=1)
    seen = -(nrm @ d) >= np.cos(max_inc)
    ok = (hit & inside & seen).reshape(uu.shape)
    pts, nrm = pts.reshape(*uu.shape, 3), nrm.reshape(*uu.shape, 3)
    runs = []
    for row in range(len(v_rows)):
        for r in _split_runs(ok[row], pts[row], nrm[row], PLAN_STEP_M, max_inc):
            r = _trim(r, pts[row], p.edge_margin_m)
            if len(r) < 3 or np.linalg.norm(pts[row, r[-1]] - pts[row, r[0]]) < MIN_LINE_M:
                continue
            runs.append((row, r))
    if not runs:
        return []
    smooth = np.split(_smooth_normals(index, np.concatenate([pts[row, r] for row, r in runs])),
                      np.cumsum([len(r) for _, r in runs])[:-1])
    return [_Run(row, float(v_rows[row]), pts[row, r], nrm[row, r], sm)
            for (row, r), sm in zip(runs, smooth, strict=True)]


def _pass_lines(cell: Cell, p: PassSpec, pass_index: int, runs: list[_Run], first_index: int) -> list[_Line]:
    """Sensor poses of a pass's runs: rows alternate direction, each run is one line."""
    u_ax, _, d = _pass_axes(p)
    rows = sorted({r.row for r in runs})
    out: list[_Line] = []
    for k, row in enumerate(rows):
        in_row = [r for r in runs if r.row == row]
        if k % 2 == 1:
            in_row = [_Run(r.row, r.cross_m, r.points_wp[::-1], r.normals_wp[::-1], r.smooth_normals_wp[::-1])
                      for r in in_row[::-1]]
        for r in in_row:
            if len(out) >= p.max_lines:
                return out
            beam = _beam_along(r.normals_wp) if p.beam == "normal" else np.broadcast_to(d, r.points_wp.shape)
            T_line, s_path = _line_poses(cell.T_world_workpiece, r.points_wp, beam, u_ax, p.standoff_m,
                                         p.speed_m_s)
            out.append(_Line(first_index + len(out), pass_index, r.cross_m, T_line, s_path, p.speed_m_s,
                             p.transit_speed_m_s, p.retract_m))
    return out


# --------------------------------------------------------------------------- motion


def _part_top_world_m(cell: Cell) -> float:
    """Highest point of the nominal part in the world [m]."""
    return float(transform_points(cell.T_world_workpiece, np.asarray(cell.mesh.vertices))[:, 2].max())


def _climb(T: np.ndarray, height_m: float) -> np.ndarray:
    """``T`` moved up to ``height_m``: back along its beam when it looks down by 30 deg or more,
    else straight up (world)."""
    out = T.copy()
    rise = height_m - T[2, 3]
    if rise <= 0:
        return out
    beam = T[:3, 2]
    if beam[2] <= -0.5:
        out[:3, 3] -= beam * (rise / -beam[2])
    else:
        out[2, 3] = height_m
    return out


def _assemble(cell: Cell, lines: list[_Line], dt: float, infos: tuple[PassInfo, ...],
              notes: tuple[str, ...]) -> ScanPlan:
    """Approach, scan, retract every line; climb above the part between passes."""
    safe_z = _part_top_world_m(cell) + cell.scenario.scan.transit_clearance_m
    poses, labels = [], []
    prev, prev_pass = None, None
    for ln in lines:
        T_line = ln.T_world_sensor
        start, end = T_line[0], T_line[-1]
        above_start = start.copy()
        above_start[:3, 3] -= ln.retract_m * start[:3, 2]
        if prev is None:
            seg = [above_start[None]]
        elif ln.pass_index != prev_pass:
            height = max(safe_z, prev[2, 3], above_start[2, 3])
            up, down = _climb(prev, height), _climb(above_start, height)
            seg = [straight_poses(prev, up, ln.transit_speed_m_s, dt)[1:],
                   straight_poses(up, down, ln.transit_speed_m_s, dt)[1:],
                   straight_poses(down, above_start, ln.transit_speed_m_s, dt)[1:]]
        else:
            seg = [straight_poses(prev, above_start, ln.transit_speed_m_s, dt)[1:]]
        seg.append(straight_poses(above_start, start, ln.transit_speed_m_s, dt)[1:])
        for s_ in seg:
            poses.append(s_)
            labels.append(np.full(len(s_), -1))
        scan = _segment(T_line, ln.s_path, ln.speed_m_s, dt)[1:]
        poses.append(scan)
        labels.append(np.full(len(scan), ln.index))
        retract = end.copy()
        retract[:3, 3] -= ln.retract_m * end[:3, 2]
        r = straight_poses(end, retract, ln.transit_speed_m_s, dt)[1:]
        poses.append(r)
        labels.append(np.full(len(r), -1))
        prev, prev_pass = retract, ln.pass_index
    T_all = np.concatenate(poses)
    line = np.concatenate(labels).astype(np.int32)
    t = np.arange(len(T_all)) * dt
    line_y = np.array([ln.cross_m for ln in lines])
    line_pass = np.array([ln.pass_index for ln in lines], dtype=np.int32)
    return ScanPlan(t, T_all, line, line_y, dt, line_pass, infos, notes)


# --------------------------------------------------------------------------- prediction


def _scaled_information(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(6, 6) information of ``[omega, v]`` about the points' centroid, rotations scaled by the
    characteristic length: the matrix :func:`observability` analyses."""
    d = points - points.mean(axis=0)
    L = float(np.sqrt(np.mean(np.einsum("ij,ij->i", d, d)))) or 1.0
    H = information_rows(d, normals)
    H[:, :3] /= L
    return np.einsum("ij,ik->jk", H, H) / len(points)


def _predicted(points: np.ndarray, normals: np.ndarray, tol: float) -> tuple[float, tuple[str, ...]]:
    """Smallest relative eigenvalue of the predicted information and the coordinate directions
    (about the centroid) it fixes at relative eigenvalue ``tol``."""
    if len(points) < 6:
        return 0.0, ()
    rel_min = float(observability(points, normals, tol).relative_eigenvalues[0])
    w, V = np.linalg.eigh(_scaled_information(points, normals))
    rel = np.clip(w, 0.0, None) / max(w[-1], 1e-300)
    weak = V[:, rel < tol]
    order = (3, 4, 5, 0, 1, 2)  # x, y, z, rx, ry, rz
    fixed = tuple(COORDINATE_NAMES[k] for k in order if np.linalg.norm(weak[k]) < FIXED_WEAK_FRACTION)
    return rel_min, fixed



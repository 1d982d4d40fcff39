"""Tool frames, flange poses and process paths (document 004, eqs. 11-13; document 003, step 5).

Contact frame (eq. 11): at a cutter-contact point ``p`` with unit surface normal ``v_n`` and
unit tangent ``v_t`` towards the next point, ``T_base_contact = [v_t v_e v_n p]``. Document
004 writes ``v_e = v_t x v_n``; with the columns in that order this is a reflection
(det = -1), so we take ``v_e = v_n x v_t``, the right-handed choice with the same axes.
``v_t`` is the chord to the next point projected onto the tangent plane (the last point of a
line takes the previous chord).

Options the process may need (``heading``, ``axis``, ``lead``/``tilt``):

* ``heading="travel"`` (eq. 11): x along the travel direction; ``"fixed"``: x along a fixed
  reference direction projected onto the plane normal to the tool axis, so the tool keeps
  its orientation about its axis along the whole path (no half turn of the wrist at each
  raster line change); ``"smooth"`` (the default for rotationally symmetric tools such as a
  polishing spindle): x starts along the reference direction at each line's first point and
  is then carried along the line by parallel transport (each x is the previous one projected
  onto the new plane), the tool turning as little as possible about its axis. "fixed" turns
  fast where the axis comes near the reference direction (steep flanks facing it); "smooth"
  does not.
* ``axis="normal"`` (eq. 11): tool z along the surface normal; ``"fixed"``: tool z along a
  fixed direction (a 3-axis process), constant along the path.
* ``lead`` (rad) leans the tool axis towards +x (the travel or heading direction), ``tilt``
  (rad) then turns it about the contact frame's x towards +y (sideways):
  ``R_tool = R_contact Rx(-tilt) Ry(lead)``, so that the axis in the contact frame is
  ``(sin lead, cos lead sin tilt, cos lead cos tilt)``.
* ``tip_radius_m``: a ball-end tool of that radius touches the surface at ``p`` whatever the
  lead and tilt: its centre is ``p + r v_n`` and the tool frame origin (the TCP, the tip of
  the tool on its axis) is ``p + r (v_n - z_tool)``. With ``r = 0`` the TCP is ``p``.

Flange pose (eq. 13): ``T_base_flange = T_base_tool @ inv(T_flange_tool)`` (document 004's
tool frame coincides with the contact frame, ``T_tool_contact = I``).

A process path (:class:`ProcessPath`) strings the lines together: approach along the tool
axis from ``retract_m`` above the first point, the line in contact, retract, a straight
transit in the air to the next approach point. Lines alternate direction (zig-zag).

CAD paths (:func:`cad_raster`): a raster of contact points on the CAD mesh (workpiece frame),
found by parallel ray casts, with the mesh's smooth normals; document 003's step 5 moves
them by the localization estimate (:func:`transform_frames`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.spatial.transform import Rotation

from algorithms.arraytypes import ArrayLike, BoolArray, FloatArray, IntArray, Pose
from algorithms.errors import AlgorithmError
from algorithms.geometry.arclength import ROTATION_LENGTH_M_PER_RAD, cumulative_length
from algorithms.geometry.raycast import GRID_SHIFT_M, raycast_parallel
from algorithms.geometry.se3 import as_pose, inv_pose
from algorithms.paths.regions import ProcessRegion, split_runs

if TYPE_CHECKING:
    import trimesh

SEGMENT_KINDS = ("approach", "process", "retract", "transit")
# Consecutive raster hits farther apart than this many point spacings: a step (or a hole).
STEP_FACTOR = 2.0

#: ``(n, 3) TCP positions -> (n,) bool``: whether the tool is clear of the part there.
ClearCheck = Callable[[FloatArray], ArrayLike]
#: (point (3,), unit normal (3,)) of a plane above the part [m].
SafePlane = tuple[ArrayLike, ArrayLike]


class ToolPathError(AlgorithmError):
    """Bad input to tool-frame or path construction."""


def _unit(v: FloatArray, what: str) -> FloatArray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    if np.any(n < 1e-12):
        i = int(np.flatnonzero(n.ravel() < 1e-12)[0])
        raise ToolPathError(f"{what} has zero length at index {i}")
    return v / n


def _fixed_vector(v: ArrayLike | None, name: str) -> FloatArray:
    a = np.asarray(v, dtype=np.float64)
    if a.shape != (3,) or not np.all(np.isfinite(a)) or np.linalg.norm(a) < 1e-12:
        raise ToolPathError(f"{name} must be a finite non-zero (3,) vector, got {v!r}")
    return a / np.linalg.norm(a)


def contact_frames(points: ArrayLike, normals: ArrayLike, heading: str = "travel",
                   heading_direction: ArrayLike | None = None, axis: str = "normal",
                   axis_direction: ArrayLike | None = None) -> FloatArray:
    """Eq. (11) frames along one line of contact points.

    Args:
        points: (K, 3) [m] contact points in travel order, K >= 2.
        normals: (K, 3) unit outward surface normals.
        heading: ``"travel"``, ``"fixed"`` or ``"smooth"`` (see module).
        heading_direction: (3,) reference x for ``"fixed"`` and ``"smooth"`` (same frame as points).
        axis: ``"normal"`` or ``"fixed"``.
        axis_direction: (3,) tool z for ``axis="fixed"``.

    Returns:
        (K, 4, 4) ``T_frame_contact`` poses, z = the tool axis direction (outward).
    """
    p = np.asarray(points, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 2 or n.shape != p.shape:
        raise ToolPathError(f"points and normals must both be (K, 3) with K >= 2, got {p.shape} and {n.shape}")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(n))):
        raise ToolPathError("points or normals contain NaN or infinite values")
    if heading not in ("travel", "fixed", "smooth") or axis not in ("normal", "fixed"):
        raise ToolPathError(f"heading must be travel|fixed|smooth and axis normal|fixed, got {heading!r}, {axis!r}")
    if axis == "normal":
        z = _unit(n, "normal")
    else:
        z = np.broadcast_to(_fixed_vector(axis_direction, "axis_direction"), p.shape)
    if heading == "travel":
        d = np.diff(p, axis=0)
        d = np.vstack([d, d[-1:]])
    else:
        d = np.broadcast_to(_fixed_vector(heading_direction, "heading_direction"), p.shape)
    x = d - np.einsum("ij,ij->i", d, z)[:, None] * z
    norm = np.linalg.norm(x, axis=1)
    bad = np.flatnonzero(norm < 1e-9 * np.maximum(np.linalg.norm(d, axis=1), 1e-300))
    if len(bad):
        raise ToolPathError(
            f"tangent undefined at point {int(bad[0])} {p[bad[0]].round(6).tolist()}: the "
            f"{'chord to the next point' if heading == 'travel' else 'heading direction'} is parallel to the tool axis"
        )
    x = x / norm[:, None]
    if heading == "smooth":
        for k in range(1, len(x)):
            v = x[k - 1] - (x[k - 1] @ z[k]) * z[k]
            nv = np.linalg.norm(v)
            if nv < 1e-9:
                raise ToolPathError(f"heading undefined at point {k}: the tool axis turns by 90 degrees in one step")
            x[k] = v / nv
    y = np.cross(z, x)
    T = np.zeros((len(p), 4, 4))
    T[:, :3, 0], T[:, :3, 1], T[:, :3, 2], T[:, :3, 3] = x, y, z, p
    T[:, 3, 3] = 1.0
    return T


def tool_frames(T_contact: ArrayLike, lead_rad: float = 0.0, tilt_rad: float = 0.0,
                tip_radius_m: float = 0.0) -> FloatArray:
    """Tool (TCP) frames from contact frames: lead/tilt and the ball-end offset (see module).

    Args:
        T_contact: (K, 4, 4) contact frames (z = outward normal or the fixed axis).
        lead_rad: tool lead [rad], |angle| < pi/2.
        tilt_rad: tool tilt [rad], |angle| < pi/2.
        tip_radius_m: ball-end radius [m] (0 for a point or flat tip).

    Returns:
        (K, 4, 4) ``T_frame_tool``.
    """
    T = np.asarray(T_contact, dtype=np.float64)
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise ToolPathError(f"T_contact must be (K, 4, 4), got {T.shape}")
    for name, v in (("lead", lead_rad), ("tilt", tilt_rad)):
        if not (np.isfinite(v) and abs(v) < np.pi / 2):
            raise ToolPathError(f"{name} must be a finite angle below 90 degrees, got {v!r} rad")
    if not (np.isfinite(tip_radius_m) and tip_radius_m >= 0):
        raise ToolPathError(f"tip_radius_m must be >= 0, got {tip_radius_m!r}")
    R_off = Rotation.from_euler("yx", [lead_rad, -tilt_rad]).as_matrix()  # extrinsic: Rx(-tilt) @ Ry(lead)
    out = T.copy()
    out[:, :3, :3] = T[:, :3, :3] @ R_off
    out[:, :3, 3] = T[:, :3, 3] + tip_radius_m * (T[:, :3, 2] - out[:, :3, 2])
    return out


def flange_poses(T_base_tool: ArrayLike, T_flange_tool: ArrayLike) -> FloatArray:
    """Eq. (13): ``T_base_flange = T_base_tool @ inv(T_flange_tool)``.

    Raises:
        ToolPathError: the tool transform is not a rigid (4, 4) transform.
    """
    try:
        T_ft = as_pose(T_flange_tool, "tool transform T_flange_tool")
    except AlgorithmError as exc:
        raise ToolPathError(str(exc)) from None
    T = np.asarray(T_base_tool, dtype=np.float64)
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise ToolPathError(f"T_base_tool must be (K, 4, 4), got {T.shape}")
    return T @ inv_pose(T_ft)


def transform_frames(T_a_b: ArrayLike, T_b_frames: ArrayLike) -> FloatArray:
    """(K, 4, 4) frames given in b expressed in a (document 003 step 5: CAD path by the estimate)."""
    T = as_pose(T_a_b, "T_a_b")
    return T @ np.asarray(T_b_frames, dtype=np.float64)


@dataclass(frozen=True)
class ProcessPath:
    """A process program as poses to visit, in one frame (the robot base frame).

    Attributes:
        T_tool: (K, 4, 4) tool (TCP) poses.
        contact: (K, 3) [m] contact points; NaN on poses in the air.
        normal: (K, 3) unit surface normals at the contact points; NaN in the air.
        segment: (K,) segment index of each pose; a pose shared by two segments (their
            junction) is stored once and labelled with the earlier one; ``segments`` gives
            the inclusive index ranges, which share their junctions.
        segments: tuple of (start, end, kind, line) with ``end`` inclusive, ``kind`` in
            SEGMENT_KINDS and ``line`` the process line (-1 for moves in the air).
        s: (K,) [m] path parameter within the pose's segment (position arc length plus
            ROTATION_LENGTH_M_PER_RAD per radian turned).
        tip_radius_m: the ball-end radius the poses were made for.
    """

    T_tool: FloatArray
    contact: FloatArray
    normal: FloatArray
    segment: IntArray
    segments: tuple[tuple[int, int, str, int], ...]
    s: FloatArray
    tip_radius_m: float = 0.0
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def n_lines(self) -> int:
        """The number of process lines."""
        return sum(1 for s in self.segments if s[2] == "process")

    def process_mask(self) -> BoolArray:
        """(K,) True on the poses in contact (the process lines)."""
        return np.isfinite(self.contact[:, 0])


def transform_path(T_a_b: ArrayLike, path: ProcessPath) -> ProcessPath:
    """The same path with every pose, point and normal given in frame b expressed in frame a.

    Document 003's step 5: a CAD path (workpiece frame) moved by the localization estimate
    ``T_base_workpiece`` lands where the part really is.
    """
    T = as_pose(T_a_b, "T_a_b")
    return ProcessPath(T @ path.T_tool, path.contact @ T[:3, :3].T + T[:3, 3], path.normal @ T[:3, :3].T,
                       path.segment.copy(), path.segments, path.s.copy(), path.tip_radius_m, dict(path.info))


def _straight(T_a: Pose, T_b: Pose, step_m: float, turn_sign: float = 0.0) -> FloatArray:
    """Poses from T_a to T_b: linear position, slerp rotation, about ``step_m`` apart.

    ``turn_sign`` picks the direction of an (ambiguous) half turn about T_a's z.
    """
    R_rel = T_a[:3, :3].T @ T_b[:3, :3]
    rv = Rotation.from_matrix(R_rel).as_rotvec()
    ang = float(np.linalg.norm(rv))
    if ang > np.pi - 1e-3 and turn_sign != 0.0:
        # Half turn: go about the tool axis in the requested sense.
        z_local = np.array([0.0, 0.0, 1.0])
        if abs(rv @ z_local) > 0.9 * ang:
            rv = np.sign(turn_sign) * ang * z_local
    length = float(np.linalg.norm(T_b[:3, 3] - T_a[:3, 3])) + ROTATION_LENGTH_M_PER_RAD * ang
    n = max(1, int(np.ceil(length / step_m)))
    f = np.linspace(0.0, 1.0, n + 1)
    out = np.repeat(np.eye(4)[None], n + 1, axis=0)
    out[:, :3, 3] = T_a[:3, 3] + f[:, None] * (T_b[:3, 3] - T_a[:3, 3])
    out[:, :3, :3] = T_a[:3, :3] @ Rotation.from_rotvec(f[:, None] * rv).as_matrix()
    out[-1] = T_b
    return out


def _transit(up_a: Pose, up_b: Pose, step_m: float, turn_sign: float, clear: ClearCheck | None,
             safe_plane: SafePlane | None) -> FloatArray:
    """A move in the air between two lines: straight when ``clear`` accepts it (or no check
    is given), else up to the safe plane, across it and down."""
    straight = _straight(up_a, up_b, step_m, turn_sign)
    if clear is None or safe_plane is None or bool(np.all(clear(straight[:, :3, 3]))):
        return straight
    point, normal = (np.asarray(v, dtype=np.float64) for v in safe_plane)
    high_a, high_b = up_a.copy(), up_b.copy()
    high_a[:3, 3] += max(0.0, float((point - up_a[:3, 3]) @ normal)) * normal
    high_b[:3, 3] += max(0.0, float((point - up_b[:3, 3]) @ normal)) * normal
    legs = [_straight(up_a, high_a, step_m), _straight(high_a, high_b, step_m, turn_sign),
            _straight(high_b, up_b, step_m)]
    return np.concatenate([legs[0], legs[1][1:], legs[2][1:]])


def assemble_path(lines_T_tool: Sequence[ArrayLike], lines_contact: Sequence[ArrayLike],
                  lines_normal: Sequence[ArrayLike], retract_m: float = 0.02, transit_step_m: float = 0.002,
                  tip_radius_m: float = 0.0, clear: ClearCheck | None = None,
                  safe_plane: SafePlane | None = None) -> ProcessPath:
    """String process lines into one program (see module docstring).

    Args:
        lines_T_tool: L arrays (n_i, 4, 4) tool poses per line, each in its travel order
            (:func:`build_path` reverses every other line for a zig-zag).
        lines_contact: L arrays (n_i, 3) contact points, same order.
        lines_normal: L arrays (n_i, 3) normals, same order.
        retract_m: lift along the tool axis before and after each line [m].
        transit_step_m: pose spacing of moves in the air [m].
        tip_radius_m: recorded with the path.
        clear: optional callable ``(n, 3) TCP positions -> (n,) bool``: whether the tool is
            clear of the part there; a transit it rejects goes over ``safe_plane``.
        safe_plane: (point (3,), unit normal (3,)) a plane above the part, same frame.
    """
    if len(lines_T_tool) == 0:
        raise ToolPathError("a process path needs at least one line")
    if not (np.isfinite(retract_m) and retract_m > 0):
        raise ToolPathError(f"retract_m must be > 0, got {retract_m!r}")
    if not (np.isfinite(transit_step_m) and transit_step_m > 0):
        raise ToolPathError(f"transit_step_m must be > 0, got {transit_step_m!r}")
    pieces = []
    prev_up = None
    for i, T in enumerate(lines_T_tool):
        T = np.asarray(T, dtype=np.float64)
        if T.ndim != 3 or T.shape[1:] != (4, 4) or len(T) < 2:
            raise ToolPathError(f"line {i}: tool poses must be (n, 4, 4) with n >= 2, got {T.shape}")
        up_start = T[0].copy()
        up_start[:3, 3] += retract_m * T[0, :3, 2]
        up_end = T[-1].copy()
        up_end[:3, 3] += retract_m * T[-1, :3, 2]
        if prev_up is not None:
            pieces.append(("transit", _transit(prev_up, up_start, transit_step_m, (-1.0) ** i, clear, safe_plane),
                           -1))
        pieces.append(("approach", _straight(up_start, T[0], transit_step_m), -1))
        pieces.append(("process", T, i))
        pieces.append(("retract", _straight(T[-1], up_end, transit_step_m), -1))
        prev_up = up_end
    T_parts, s_parts, seg_ids = [], [], []
    segs: list[tuple[int, int, str, int]] = []
    k = 0
    for kind, P, line in pieces:
        # Consecutive pieces share their junction pose; it is stored once, with the earlier piece.
        Pk = P if k == 0 else P[1:]
        start = 0 if k == 0 else k - 1
        T_parts.append(Pk)
        s_parts.append(cumulative_length(P)[len(P) - len(Pk):])
        seg_ids.append(np.full(len(Pk), len(segs)))
        k += len(Pk)
        segs.append((start, k - 1, kind, line))
    T_all = np.concatenate(T_parts)
    contact = np.full((len(T_all), 3), np.nan)
    normal = np.full((len(T_all), 3), np.nan)
    for (start, end, kind, line) in segs:
        if kind == "process":
            contact[start:end + 1] = np.asarray(lines_contact[line], dtype=np.float64)
            normal[start:end + 1] = np.asarray(lines_normal[line], dtype=np.float64)
    return ProcessPath(T_all, contact, normal, np.concatenate(seg_ids), tuple(segs),
                       np.concatenate(s_parts), float(tip_radius_m))


@dataclass(frozen=True)
class ToolSettings:
    """How contact points become tool poses (see the module docstring; angles in radians)."""

    heading: str = "smooth"
    heading_direction: tuple[float, ...] = (1.0, 0.0, 0.0)
    axis: str = "normal"
    axis_direction: tuple[float, ...] = (0.0, 0.0, 1.0)
    lead_rad: float = 0.0
    tilt_rad: float = 0.0
    tip_radius_m: float = 0.0
    retract_m: float = 0.02
    transit_step_m: float = 0.002
    zigzag: bool = True


def build_path(lines_contact: Sequence[ArrayLike], lines_normal: Sequence[ArrayLike],
               settings: ToolSettings = ToolSettings(), T_frame_ref: ArrayLike | None = None,
               clear: ClearCheck | None = None, safe_plane: SafePlane | None = None,
               lines_axis: Sequence[ArrayLike] | None = None) -> ProcessPath:
    """Contact points and normals per line -> a zig-zag :class:`ProcessPath` of tool poses.

    Args:
        lines_contact: L arrays (n_i, 3) [m], all lines in the same direction.
        lines_normal: L arrays (n_i, 3) unit outward normals.
        settings: tool orientation options.
        T_frame_ref: optional (4, 4) pose of the frame the fixed directions are given in
            (e.g. ``T_base_workpiece``: heading along the part's x); default: the points' frame.
        clear: collision check of transits (:func:`assemble_path`).
        safe_plane: the plane transits go over (:func:`assemble_path`).
        lines_axis: optional L arrays (n_i, 3) of unit tool axes, one per contact point (a
            ball-end tool tilted about its ball's centre: the ball touches the same point, the
            tip sits at ``c + r (n - axis)``); they replace the settings' axis, lead and tilt.
    """
    R_ref = np.eye(3) if T_frame_ref is None else as_pose(T_frame_ref, "T_frame_ref")[:3, :3]
    hd = R_ref @ _fixed_vector(settings.heading_direction, "heading_direction")
    ad = R_ref @ _fixed_vector(settings.axis_direction, "axis_direction")
    if lines_axis is not None and len(lines_axis) != len(lines_contact):
        raise ToolPathError(f"lines_axis must hold one array per line ({len(lines_contact)}), got {len(lines_axis)}")
    Ts, cs, ns = [], [], []
    for i, (c, n) in enumerate(zip(lines_contact, lines_normal, strict=True)):
        c = np.asarray(c, dtype=np.float64)
        n = np.asarray(n, dtype=np.float64)
        a = None if lines_axis is None else np.asarray(lines_axis[i], dtype=np.float64)
        if a is not None and a.shape != n.shape:
            raise ToolPathError(f"line {i}: lines_axis {a.shape} must match its normals {n.shape}")
        rev = settings.zigzag and i % 2 == 1
        if rev:
            c, n = c[::-1], n[::-1]
            a = None if a is None else a[::-1]
        try:
            if a is None:
                Tc = contact_frames(c, n, settings.heading, hd, settings.axis, ad)
                T = tool_frames(Tc, settings.lead_rad, settings.tilt_rad, settings.tip_radius_m)
            else:
                T = contact_frames(c, a, settings.heading, hd, "normal", ad)
                T[:, :3, 3] += settings.tip_radius_m * (n - T[:, :3, 2])
        except ToolPathError as exc:
            raise ToolPathError(f"line {i}: {exc}") from None
        Ts.append(T)
        cs.append(c)
        ns.append(n)
    return assemble_path(Ts, cs, ns, settings.retract_m, settings.transit_step_m, settings.tip_radius_m,
                         clear, safe_plane)


def cad_raster(mesh: trimesh.Trimesh, line_spacing_m: float = 0.004, point_spacing_m: float = 0.001,
               margin_m: float = 0.005, line_axis: str = "x",
               region: tuple[tuple[float, float], tuple[float, float]] | None = None,
               normals: Callable[[IntArray, FloatArray], ArrayLike] | None = None,
               process_region: ProcessRegion | None = None) -> tuple[list[FloatArray], list[FloatArray]]:
    """A raster of contact points on the CAD model, seen from +z (workpiece frame).

    Lines run along ``line_axis``, ``line_spacing_m`` apart, points ``point_spacing_m``
    apart, inside the footprint shrunk by ``margin_m`` (or ``region`` ((xmin, ymin),
    (xmax, ymax))), shifted by GRID_SHIFT_M off round numbers. Each raster line is cut into
    pieces at holes, steps (consecutive hits farther apart than ``STEP_FACTOR`` point
    spacings), sharp edges and the border of ``process_region``
    (:func:`algorithms.paths.regions.split_runs`); every piece becomes a line.

    Args:
        mesh: the CAD model (its ``vertices`` (V, 3) [m] and ``faces`` (F, 3)), workpiece frame.
        normals: optional callable ``(face (N,), points (N, 3)) -> (N, 3)`` smooth unit
            normals (e.g. ``MeshIndex.smooth_normals``); default: the face normals.
        process_region: optional :class:`ProcessRegion` (which surfaces are processed).

    Returns:
        (lines, normals): lists of (n_i, 3) arrays, pieces in increasing cross coordinate
        (then along the line), all in the +line_axis direction.
    """
    for name, v in (("line_spacing_m", line_spacing_m), ("point_spacing_m", point_spacing_m)):
        if not (np.isfinite(v) and v > 0):
            raise ToolPathError(f"{name} must be > 0, got {v!r}")
    if line_axis not in ("x", "y"):
        raise ToolPathError(f"line_axis must be 'x' or 'y', got {line_axis!r}")
    V = np.asarray(mesh.vertices, dtype=np.float64)
    F = np.asarray(mesh.faces, dtype=np.int64)
    lo, hi = V.min(axis=0), V.max(axis=0)
    if region is None:
        (x0, y0), (x1, y1) = (lo[0] + margin_m, lo[1] + margin_m), (hi[0] - margin_m, hi[1] - margin_m)
    else:
        (x0, y0), (x1, y1) = region
    if not (x1 > x0 and y1 > y0):
        raise ToolPathError(f"raster region is empty: x [{x0:g}, {x1:g}], y [{y0:g}, {y1:g}] m")
    (u0, u1), (v0, v1) = ((x0, x1), (y0, y1)) if line_axis == "x" else ((y0, y1), (x0, x1))
    vs = np.arange(v0, v1 - GRID_SHIFT_M, line_spacing_m) + GRID_SHIFT_M
    us = np.arange(u0, u1 - GRID_SHIFT_M, point_spacing_m) + GRID_SHIFT_M
    U, W = np.meshgrid(us, vs)
    xy = np.column_stack([U.ravel(), W.ravel()]) if line_axis == "x" else np.column_stack([W.ravel(), U.ravel()])
    origins = np.column_stack([xy, np.full(len(xy), hi[2] + 0.01)])
    hit, P, face = raycast_parallel(V, F, origins, [0.0, 0.0, -1.0])
    hit, P, face = hit.reshape(U.shape), P.reshape(U.shape + (3,)), face.reshape(U.shape)
    lines, norms = [], []
    for j in range(len(vs)):
        idx = np.flatnonzero(hit[j])
        if len(idx) < 2:
            continue
        p = P[j, idx]
        f = face[j, idx]
        if normals is None:
            tri = V[F[f]]
            n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            n /= np.linalg.norm(n, axis=1, keepdims=True)
        else:
            n = np.asarray(normals(f, p), dtype=np.float64)
        # Lines end at holes, steps, sharp edges and the border of the process region.
        keep = None if process_region is None else process_region.select(p, n, f)
        for run in split_runs(p, n, keep, max_gap_m=STEP_FACTOR * point_spacing_m, min_points=2):
            lines.append(p[run])
            norms.append(n[run])
    if len(lines) == 0:
        raise ToolPathError("the raster region does not cover the model: no line hits it")
    return lines, norms

"""Segmented process paths: build, check, solve, and drop what cannot be processed.

A process path (lines of contact points and normals) is built into a program of poses
(:func:`algorithms.paths.toolpath.build_path`, transits over a safe plane where a straight
one would pass near the part), then every pose is checked: the five-axis IK on the nominal
cell (unreachable, singular, discontinuous), the tool's shank, holder and ball against the
exact part at the estimate (:func:`clearance_problems`) and the arm's links against the table
(:func:`table_problems`). A bad stretch is dropped (its line split there, with a retract, a
transit and a re-approach), listed as :class:`Dropped`, and the path rebuilt and solved
again, the dropped margin doubling each round; with ``strict`` the first bad pose fails the
stage instead (:class:`StageFailed`). Before the first drop for the arm's sake, the tool's
tilt freedom is used for it (:func:`steer_for_the_arm`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from algorithms.geometry.kinematics import dh_forward, ur_inverse, wrap_angle
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import inv_pose, transform_points
from algorithms.paths.tilt import ToolProfile, clear_axes, foot_gap_m, profile_gaps_m, steer_axes, tool_profile
from algorithms.paths.toolpath import ProcessPath, ToolSettings, build_path, transform_path
from twin.cell import TOOL_BALL_SITE, Cell
from twin.robot import UR5E_DH
from twin.scenario import Scenario
from twin.stages import StageFailed
from twin.trajectory import TABLE_CLEARANCE_M, PathIK, PathProblem, TableCheck, site_in_flange, solve_tool_path

DROP_MARGIN_POINTS = 2     # contact points dropped on each side of a bad pose (first round)
MAX_DROP_ROUNDS = 8        # solve, drop, rebuild: at most this many times
# The shank and holder keep this far from the part: more than the replay's collision shape
# (a 1 mm height field, twin.replay.HFIELD_RES_M) stands out from the exact part, which at a
# concave corner (a punch meeting its base) cuts the corner across a cell.
CLEARANCE_M = 0.003
CLEARANCE_STEP_M = 0.002   # spacing of the clearance checks along the tool
# The foot of a tilted shank (from the ball's equator to the first profile sample, as near a
# wall as the ball is) keeps this far from the exact part: more than the replay's height field
# stands out from a wall (a cell, 1 mm). An axis on the normal needs no such check: a wall near
# its foot is as near the first profile sample, held CLEARANCE_M off.
SHANK_FOOT_GAP_M = 0.0015
BALL_TOLERANCE_M = 1e-4    # the ball may touch (approach, retract) but not enter the part in the air
# The tilt freedom against the arm's problems (unreachable, singular, discontinuous poses): the
# stretch around each is re-tilted for the arm (:func:`steer_for_the_arm`) before anything is dropped.
STEER_WINDOW_POINTS = 8    # contact points on each side of an arm problem that share the new tilt
STEER_RAMP_POINTS = 4      # ... and over which it ramps in and out
# A line this short is not re-tilted: its approach, few points and retract follow each other too
# closely for the servos to follow a new tilt.
STEER_MIN_LINE_POINTS = 2 * STEER_WINDOW_POINTS + 1
WRIST_SIN_MIN = 0.05       # |sin q5| below this: too near the wrist singularity for a steered axis
ARM_PROBLEMS = ("unreachable", "singular", "discontinuous")


@dataclass(frozen=True)
class Dropped:
    """A stretch of a process path left out: ``points`` contact points around ``position_m``
    (robot base frame), on process line ``line`` of the path as it was when it was dropped."""

    line: int
    points: int
    position_m: tuple
    reason: str

    def to_dict(self) -> dict:
        return {"line": self.line, "points": self.points, "position_m": [round(float(v), 6) for v in self.position_m],
                "reason": self.reason}


def _profile(scenario: Scenario) -> ToolProfile:
    """The tool above its ball, sampled every CLEARANCE_STEP_M up to the flange."""
    p = scenario.path
    reach = float(np.linalg.norm(p.T_flange_tool[:3, 3])) - p.tip_radius_m
    return tool_profile(reach, p.tip_radius_m, p.shank_radius_m, p.holder_radius_m, p.holder_length_m,
                        CLEARANCE_STEP_M)


def clearance_problems(path: ProcessPath, scenario: Scenario, T_base_workpiece: np.ndarray,
                       index: MeshIndex) -> list[PathProblem]:
    """Poses whose shank or holder comes within CLEARANCE_M of the part (at the estimate),
    or whose ball enters the part on a move in the air.

    The tool axis runs from the ball centre back to the flange; it is sampled every
    CLEARANCE_STEP_M beyond the ball, each sample with the radius of what is there.
    """
    p = scenario.path
    profile = _profile(scenario)
    if len(profile.distance_m) == 0:
        return []
    T_wb = inv_pose(T_base_workpiece)
    T = T_wb @ path.T_tool
    centre = T[:, :3, 3] + p.tip_radius_m * T[:, :3, 2]
    short = profile_gaps_m(centre, T[:, :3, 2], profile, index.signed_distance, CLEARANCE_M)
    bad = np.flatnonzero(np.min(short, axis=1) < CLEARANCE_M)
    out = []
    # the ball itself on moves in the air (approach, retract, transit): never into the part
    ball = index.signed_distance(centre) - p.tip_radius_m
    for i in np.flatnonzero(~path.process_mask() & (ball < -BALL_TOLERANCE_M)):
        out.append(PathProblem(int(i), "collision", tuple(path.T_tool[i, :3, 3]),
                               f"the ball goes {-ball[i] * 1e3:.2f} mm into the part on a move in the air"))
    for i in bad:
        j = int(np.argmin(short[i]))
        out.append(PathProblem(int(i), "collision", tuple(path.T_tool[i, :3, 3]),
                               f"the tool {profile.distance_m[j] * 1e3:.0f} mm up its axis comes "
                               f"{short[i, j] * 1e3:.2f} mm from the part"))
    out += _tilted_shank_problems(path, T, centre, T_wb, profile, index)
    return out


def _tilted_shank_problems(path: ProcessPath, T: np.ndarray, centre: np.ndarray, T_wb: np.ndarray,
                           profile: ToolProfile, index: MeshIndex) -> list[PathProblem]:
    """Process poses whose axis is tilted from the normal ([path] max_tilt_deg) and whose shank's
    foot comes within SHANK_FOOT_GAP_M of the part (:func:`algorithms.paths.tilt.foot_gap_m`)."""
    on = np.flatnonzero(path.process_mask())
    axis = T[on, :3, 2]
    tilted = np.sum(axis * (path.normal[on] @ T_wb[:3, :3].T), axis=1) < np.cos(1e-6)
    on = on[tilted]
    gap = foot_gap_m(centre[on], axis[tilted], profile, index.signed_distance)
    return [PathProblem(int(i), "collision", tuple(path.T_tool[i, :3, 3]),
                        f"the tilted shank's foot comes {g * 1e3:.2f} mm from the part")
            for i, g in zip(on, gap, strict=True) if g < SHANK_FOOT_GAP_M]


def tilted_axes(lines, normals, scenario: Scenario, T_base_workpiece: np.ndarray, index: MeshIndex,
                T_base_frame: np.ndarray | None) -> list[np.ndarray]:
    """The tool axis at each contact point (:func:`algorithms.paths.tilt.clear_axes`): the
    normal, tilted within ``path.max_tilt_deg`` where the shank or holder would not clear the
    part; in the lines' frame (``T_base_frame`` maps it to the base; None: the base)."""
    p = scenario.path
    T_wp_frame = inv_pose(T_base_workpiece) @ (np.eye(4) if T_base_frame is None else T_base_frame)
    R = T_wp_frame[:3, :3]
    profile = _profile(scenario)
    out = []
    for ln, nm in zip(lines, normals, strict=True):
        axes_wp = clear_axes(transform_points(T_wp_frame, np.asarray(ln)), np.asarray(nm) @ R.T, p.tip_radius_m,
                             profile, index.signed_distance, float(np.radians(p.max_tilt_deg)), CLEARANCE_M,
                             SHANK_FOOT_GAP_M)
        out.append(axes_wp @ R)
    return out


def arm_cost(T_flange_ball: np.ndarray, T_base_workpiece: np.ndarray, branch: int, retract_m: float):
    """The arm's trouble along consecutive ball centres and tool axes (workpiece frame), on one
    branch of the closed-form IK: the largest step of a joint between consecutive points
    [rad] (joints 1-5: the spin about the tool axis is free); inf where the branch has no
    solution (there, or ``retract_m`` up the axis from the first and the last point, where a
    line's approach starts and its retract ends) or the wrist comes within WRIST_SIN_MIN of
    its singularity. Returns the function (centres (M, 3), axes (M, 3)) -> float."""
    R, t = T_base_workpiece[:3, :3], T_base_workpiece[:3, 3]
    T_ball_flange = inv_pose(T_flange_ball)

    def cost(centres: np.ndarray, axes: np.ndarray) -> float:
        ends = [0, len(centres) - 1]
        c = np.concatenate([centres, centres[ends] + retract_m * axes[ends]]) @ R.T + t
        z = np.concatenate([axes, axes[ends]]) @ R.T
        # one reference for the spin along the whole run, so the frames turn continuously
        ref = np.eye(3)[int(np.argmin(np.abs(z.mean(axis=0))))]
        x = np.cross(z, ref)
        x /= np.linalg.norm(x, axis=1, keepdims=True)
        T = np.tile(np.eye(4), (len(z), 1, 1))
        T[:, :3, 0], T[:, :3, 1], T[:, :3, 2], T[:, :3, 3] = x, np.cross(z, x), z, c
        sol = ur_inverse(T @ T_ball_flange, UR5E_DH, branches=[branch])
        if not np.all(sol.valid[:, branch]) or np.min(sol.wrist_sin[:, branch]) < WRIST_SIN_MIN:
            return np.inf
        q = sol.q[: len(centres), branch, :5]
        return float(np.max(np.abs(wrap_angle(np.diff(q, axis=0))), initial=0.0))

    return cost


def _branch_of(q: np.ndarray) -> int:
    """The closed-form IK branch a joint vector lies on (the nearest solution of its own
    flange pose, joints 1-5)."""
    sol = ur_inverse(dh_forward(q, UR5E_DH), UR5E_DH)
    d = np.linalg.norm(wrap_angle(sol.q[0, :, :5] - q[None, :5]), axis=1)
    return int(np.argmin(np.where(sol.valid[0], d, np.inf)))


def steer_for_the_arm(path: ProcessPath, ik: PathIK, problems, lines, normals, axes, sc: Scenario, nominal: Cell,
                      T_base_workpiece: np.ndarray, index: MeshIndex,
                      T_base_frame: np.ndarray | None) -> tuple[list[np.ndarray], int]:
    """Use the tilt freedom against the arm's problems: around every
    unreachable, singular or discontinuous pose (STEER_WINDOW_POINTS on each side of its
    contact point; a pose in the air counts for the end of its line) the
    axes are re-chosen in the cone (:func:`algorithms.paths.tilt.steer_axes`: the axes
    smoothed along the line, or one tilt for the stretch) for the smallest joint step on the
    branch the arm took coming in (:func:`arm_cost`), the tool kept clear of the part. Lines
    shorter than STEER_MIN_LINE_POINTS are left as they are (dropped as before). Returns the
    axes (in the lines' frame) and the number of stretches re-chosen."""
    p = sc.path
    T_wp_frame = inv_pose(T_base_workpiece) @ (np.eye(4) if T_base_frame is None else T_base_frame)
    R = T_wp_frame[:3, :3]
    profile = _profile(sc)
    T_flange_ball = site_in_flange(nominal, TOOL_BALL_SITE)
    stretches: dict[int, list[int]] = {}
    for prob in problems:   # a pose in the air counts for the end of the line it leaves or reaches
        if prob.kind in ARM_PROBLEMS:
            at = _line_point(path, prob.index)
            if at is not None:
                stretches.setdefault(at[0], []).append(at[1])
    out = [np.array(a) for a in axes]
    done = 0
    for line, points in stretches.items():
        poses = _line_poses(path, line)
        if len(poses) < STEER_MIN_LINE_POINTS:
            continue
        for lo, hi in _merge_windows(sorted(points), STEER_WINDOW_POINTS, len(poses)):
            cost = arm_cost(T_flange_ball, T_base_workpiece, _branch_of(ik.q[poses[max(0, lo - 1)]]), p.retract_m)
            new = steer_axes(transform_points(T_wp_frame, np.asarray(lines[line])), np.asarray(normals[line]) @ R.T,
                             out[line] @ R.T, lo, hi, cost, p.tip_radius_m, profile, index.signed_distance,
                             float(np.radians(p.max_tilt_deg)), CLEARANCE_M, SHANK_FOOT_GAP_M, ramp=STEER_RAMP_POINTS)
            if new is not None:
                out[line] = new @ R
                done += 1
    return out, done


def _merge_windows(points: list[int], half: int, n: int) -> list[tuple[int, int]]:
    """Windows [j - half, j + half] around sorted points, merged where they overlap: (lo, hi)."""
    out: list[tuple[int, int]] = []
    for j in points:
        lo, hi = max(0, j - half), min(n, j + half + 1)
        if out and lo <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], hi))
        else:
            out.append((lo, hi))
    return out


def table_problems(nominal: Cell, path: ProcessPath, q: np.ndarray) -> list[PathProblem]:
    """Poses at which a link of the arm comes within TABLE_CLEARANCE_M of the table."""
    check = TableCheck(nominal, TABLE_CLEARANCE_M)
    out = []
    for i in range(len(q)):
        hit = check.nearest(q[i])
        if hit is not None:
            out.append(PathProblem(i, "collision", tuple(path.T_tool[i, :3, 3]),
                                   f"the arm's {hit[0]} comes {hit[1] * 1e3:.1f} mm from the table"))
    return out


def _transit_check(scenario: Scenario, index: MeshIndex, T_base_workpiece: np.ndarray,
                   T_base_frame: np.ndarray | None):
    """The clearance test of transits and the safe plane above the part, in the frame the
    lines are given in (the workpiece frame when ``T_base_frame`` is the estimate, else the
    base frame): a transit is clear when the ball stays ``retract_m / 2`` above the part."""
    p = scenario.path
    T_frame_wp = inv_pose(T_base_frame) @ T_base_workpiece if T_base_frame is not None else T_base_workpiece
    T_wp_frame = inv_pose(T_frame_wp)
    top = float(index.vertices[:, 2].max())
    safe_point = transform_points(T_frame_wp, np.array([[0.0, 0.0, top + p.retract_m]]))[0]
    up = T_frame_wp[:3, :3] @ np.array([0.0, 0.0, 1.0])

    def clear(tcp: np.ndarray) -> np.ndarray:
        # TCP -> ball centre: the tool axis in the air is close to "up" on every transit
        centre = transform_points(T_wp_frame, tcp + p.tip_radius_m * up)
        return index.signed_distance(centre) >= p.tip_radius_m + 0.5 * p.retract_m

    return clear, (safe_point, up)


def _line_point(path: ProcessPath, index: int) -> tuple[int, int] | None:
    """(line, point) of the contact point a pose belongs to, in the lines' own order; a move in
    the air belongs to the end of the line it leaves or the start of the one it reaches."""
    a, b, kind, line = path.segments[path.segment[index]]
    if kind == "process":
        j = index - a
    else:
        nxt = [s for s in path.segments if s[2] == "process" and s[0] >= b]
        prv = [s for s in path.segments if s[2] == "process" and s[1] <= a]
        if kind == "retract" and prv:
            line, j = prv[-1][3], prv[-1][1] - prv[-1][0]
        elif nxt:
            line, j = nxt[0][3], 0
        else:
            return None
    a_line = next(s for s in path.segments if s[2] == "process" and s[3] == line)
    n = a_line[1] - a_line[0] + 1
    return line, ((n - 1 - j) if line % 2 == 1 else j)   # odd lines run reversed (zig-zag)


def _line_poses(path: ProcessPath, line: int) -> np.ndarray:
    """The pose index of each contact point of a line, in the line's own order."""
    a, b = next((s[0], s[1]) for s in path.segments if s[2] == "process" and s[3] == line)
    idx = np.arange(a, b + 1)
    return idx[::-1] if line % 2 == 1 else idx


def _drop_masks(path: ProcessPath, problems, lines, margin: int) -> tuple[list[np.ndarray], list[Dropped]]:
    """Keep-masks over the lines' points after dropping ``margin`` points on each side of
    every pose in ``problems``."""
    keep = [np.ones(len(ln), dtype=bool) for ln in lines]
    reasons: dict[tuple[int, int], str] = {}
    for prob in problems:
        at = _line_point(path, prob.index)
        if at is None:
            continue
        line, j_orig = at
        n = len(_line_poses(path, line))
        lo, hi = max(0, j_orig - margin), min(n, j_orig + margin + 1)
        keep[line][lo:hi] = False
        reasons.setdefault((line, j_orig), f"{prob.kind}: {prob.detail}")
    dropped = [Dropped(line, margin * 2 + 1, tuple(lines[line][j]), why)
               for (line, j), why in sorted(reasons.items())]
    return keep, dropped


def split_kept(lines, normals, keep, *more) -> tuple[list, ...]:
    """The runs of kept points (two or more) of each line, as new lines; ``more``: other
    per-point arrays (e.g. tool axes) split the same way."""
    out: tuple[list, ...] = tuple([] for _ in range(2 + len(more)))
    for k, *arrays in zip(keep, lines, normals, *more, strict=True):
        idx = np.flatnonzero(k)
        if len(idx) < 2:
            continue
        for run in np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1):
            if len(run) >= 2:
                for dest, arr in zip(out, arrays, strict=True):
                    dest.append(arr[run])
    return out


def _count_kinds(problems) -> str:
    kinds: dict[str, int] = {}
    for p in problems:
        kinds[p.kind] = kinds.get(p.kind, 0) + 1
    return ", ".join(f"{n} {kind}" for kind, n in sorted(kinds.items()))


def solve_with_drops(name: str, lines, normals, settings: ToolSettings, T_frame_ref, nominal: Cell,
                     T_base_workpiece: np.ndarray, index: MeshIndex, strict: bool,
                     T_base_frame: np.ndarray | None = None,
                     steer: bool = True) -> tuple[ProcessPath, PathIK, list[Dropped]]:
    """Build the path and check the tool's clearance, then (once the tool is clear) solve the
    five-axis IK and check the arm against the table; drop every bad stretch and rebuild,
    until nothing is bad (module docstring). With a tilt cone (``[path] max_tilt_deg``) and
    ``steer``, the first time the arm has problems the axes around them are re-chosen for it
    (:func:`steer_for_the_arm`) and the path solved again before anything is dropped.

    ``lines``/``normals`` are in the frame ``T_base_frame`` maps to the base (None: the base).

    Raises:
        StageFailed: ``strict`` and a stretch is bad, or nothing is left.
    """
    sc = nominal.scenario
    p = sc.path
    dropped: list[Dropped] = []
    lines, normals = list(lines), list(normals)
    axes = tilted_axes(lines, normals, sc, T_base_workpiece, index, T_base_frame) if p.max_tilt_deg > 0 else None
    clear, safe_plane = _transit_check(sc, index, T_base_workpiece, T_base_frame)
    steered = axes is None or not steer   # the tilt is re-chosen for the arm once, before anything is dropped for it
    for round_ in range(MAX_DROP_ROUNDS):
        path = build_path(lines, normals, settings, T_frame_ref=T_frame_ref, clear=clear, safe_plane=safe_plane,
                          lines_axis=axes)
        if T_base_frame is not None:
            path = transform_path(T_base_frame, path)
        # the tool against the part first (geometry only); the IK once the tool is clear
        problems = clearance_problems(path, sc, T_base_workpiece, index)
        if not problems:
            ik = solve_tool_path(nominal, path, p.T_flange_tool, p.feed_m_s, p.transit_speed_m_s, free_spin=True)
            problems = sorted(table_problems(nominal, path, ik.q) + list(ik.problems), key=lambda q: q.index)
            if not problems:
                return path, ik, dropped
            if not steered:
                steered = True
                axes, n_steered = steer_for_the_arm(path, ik, problems, lines, normals, axes, sc, nominal,
                                                    T_base_workpiece, index, T_base_frame)
                if n_steered:
                    continue
        if strict:
            raise StageFailed(name, f"{len(problems)} bad pose(s) (--strict: {_count_kinds(problems)}); "
                                    f"first: {problems[0].describe()}")
        # the margin doubles each round: a stretch still bad after a drop is wider than thought
        keep, more = _drop_masks(path, problems, lines, DROP_MARGIN_POINTS * 2**round_)
        if T_base_frame is not None:   # the report and the recording give positions in the base frame
            at = transform_points(T_base_frame, np.array([d.position_m for d in more]).reshape(-1, 3))
            more = [dataclasses.replace(d, position_m=tuple(p_base)) for d, p_base in zip(more, at, strict=True)]
        dropped += more
        if axes is None:
            lines, normals = split_kept(lines, normals, keep)
        else:
            lines, normals, axes = split_kept(lines, normals, keep, axes)
        if not lines:
            raise StageFailed(name, f"no stretch of the path can be processed ({_count_kinds(problems)}); "
                                    f"first: {problems[0].describe()}")
    raise StageFailed(name, f"bad poses remain after {MAX_DROP_ROUNDS} rounds of dropping; "
                            f"first: {problems[0].describe()}")



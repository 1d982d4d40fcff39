"""Joint trajectories along a process path: mink IK pose by pose, then a time law.

IK (:func:`solve_path`) runs on the NOMINAL cell (what the controller believes), on the
``flange`` site: the targets are the flange poses of eq. (13). Each pose is solved by
differential IK with mink (a FrameTask, a tiny posture regulariser, configuration limits and
velocity limits), warm-started from the previous pose's solution: the joint path stays on
one branch because no step can jump (each QP step moves a joint at most ``v_max * dt``, with
``dt`` the time the path allots to that step at its commanded speed). Every pose is then
checked:

* unreachable: the frame error stays above ``twin.ik.UNREACHABLE_POSITION_M`` /
  ``UNREACHABLE_ORIENTATION_RAD`` after ``MAX_ITERATIONS`` (out of reach, a joint limit, or
  a speed the velocity limits cannot follow);
* singular: the smallest singular value of the Jacobian (rotation rows scaled by
  ``JACOBIAN_LENGTH_M`` so both halves are in metres per radian) is below ``SINGULAR_SIGMA``;
* discontinuous: a joint moves more than ``JUMP_RAD`` between consecutive poses (a branch
  flip).

Problems are never skipped: they are collected with the pose index and position, and
:func:`solve_path` raises :class:`PathError` listing them unless asked to return them.

The time law is :func:`algorithms.paths.timing.time_law`.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass

import mujoco
import numpy as np

from algorithms.errors import AlgorithmError
from algorithms.geometry.arclength import step_lengths
from algorithms.geometry.kinematics import ur_inverse
from algorithms.geometry.se3 import inv_pose
from algorithms.paths.timing import Trajectory, time_law
from algorithms.paths.toolpath import ProcessPath, flange_poses
from twin.cell import TOOL_BALL_SITE, Cell
from twin.errors import TwinError
from twin.ik import IKSolver, reachable
from twin.robot import ACCELERATION_LIMIT_RAD_S2, HOME_Q, UR5E_DH, VELOCITY_LIMIT_RAD_S

__all__ = ["PathError", "PathIK", "PathProblem", "Trajectory", "plan_joint_trajectory", "solve_path", "solve_tool_path",
           "time_law_for"]

POSITION_TOL_M = 1e-6
ORIENTATION_TOL_RAD = 1e-5
MAX_ITERATIONS = 50
FIRST_POSE_ITERATIONS = 2000
JACOBIAN_LENGTH_M = 0.1
SINGULAR_SIGMA = 2e-3   # m/rad: 1 rad/s of joint speed moves the flange < 2 mm/s somewhere
JUMP_RAD = 0.2
TABLE_CLEARANCE_M = 0.002   # the arm's links keep this far above the table
# Joint accelerations of a process path are held to this fraction of the arm's limits: the
# servos lag in proportion to the acceleration, and a five-axis path that turns the tool
# about a small radius (a sphere, a punch's flank) would otherwise lag off the path.
PATH_ACCELERATION_FRACTION = 0.5


class PathError(TwinError):
    """A path the robot cannot follow; ``problems`` lists every bad pose."""

    def __init__(self, message: str, problems: tuple[PathProblem, ...] = ()) -> None:
        super().__init__(message)
        self.problems = problems


@dataclass(frozen=True)
class PathProblem:
    """One bad pose: ``kind`` in unreachable, singular, discontinuous."""

    index: int
    kind: str
    position_m: tuple
    detail: str

    def describe(self) -> str:
        p = self.position_m
        return f"pose {self.index} at ({p[0]:.4f}, {p[1]:.4f}, {p[2]:.4f}) m: {self.kind} ({self.detail})"


@dataclass(frozen=True)
class PathIK:
    """Joint solution of a pose sequence.

    Attributes:
        q: (K, 6) joint angles [rad].
        position_error_m: (K,) remaining flange position error [m].
        orientation_error_rad: (K,) remaining flange orientation error [rad].
        sigma_min: (K,) smallest singular value of the scaled Jacobian [m/rad].
        iterations: (K,) QP steps used per pose.
        problems: every unreachable, singular or discontinuous pose.
        time_s: wall time [s]; ``time_per_pose_ms`` the same per pose.
        first_pose_time_s: of which the first pose (solved from the start guess) [s].
    """

    q: np.ndarray
    position_error_m: np.ndarray
    orientation_error_rad: np.ndarray
    sigma_min: np.ndarray
    iterations: np.ndarray
    problems: tuple
    time_s: float
    first_pose_time_s: float = 0.0

    @property
    def time_per_pose_ms(self) -> float:
        return 1e3 * self.time_s / max(len(self.q), 1)

    @property
    def tracking_time_per_pose_ms(self) -> float:
        """Per pose after the first (warm-started path following) [ms]."""
        return 1e3 * (self.time_s - self.first_pose_time_s) / max(len(self.q) - 1, 1)


def _step_dt(T: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """Time the path allots to each step (K,) at the given speeds (the first pose gets 1 s)."""
    return np.concatenate([[1.0], np.maximum(step_lengths(T) / speed[1:], 1e-4)])


def solve_path(cell: Cell, T_base_flange: np.ndarray, q_start: np.ndarray | None = None,
               dt: np.ndarray | None = None, on_problem: str = "raise", site: str = "flange",
               free_spin: bool = False) -> PathIK:
    """Joint angles for a sequence of flange poses (robot base frame), see the module docstring.

    Args:
        cell: the NOMINAL cell.
        T_base_flange: (K, 4, 4) flange poses [m], base frame.
        q_start: (6,) initial guess for the first pose (default: the home posture).
        dt: (K,) time allotted to reach each pose from the previous one [s] (velocity limit
            of the IK steps); default: 1 mm per 10 ms.
        on_problem: ``"raise"`` (default) or ``"report"`` (return them in ``problems``).
        site: the site that follows the poses (``"flange"``, or ``twin.cell.TOOL_BALL_SITE``).
        free_spin: leave the rotation about the site's z free (a tool symmetric about its axis).

    Raises:
        PathError: any unreachable, singular or discontinuous pose (``on_problem="raise"``).
    """
    if on_problem not in ("raise", "report"):
        raise TwinError(f"on_problem must be 'raise' or 'report', got {on_problem!r}")
    T = np.asarray(T_base_flange, dtype=np.float64)
    if T.ndim != 3 or T.shape[1:] != (4, 4) or len(T) == 0:
        raise TwinError(f"T_base_flange must be (K, 4, 4) with K >= 1, got {T.shape}")
    if not np.all(np.isfinite(T)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(T.reshape(len(T), -1)), axis=1))[0])
        raise TwinError(f"flange pose {bad} contains NaN or infinite values")
    k = len(T)
    if dt is None:
        dt = _step_dt(T, np.full(k, 0.1)) if k > 1 else np.ones(1)
    dt = np.asarray(dt, dtype=np.float64)
    T_world = cell.T_world_base @ T
    t0 = time.perf_counter()
    s = IKSolver(cell.model, site, POSITION_TOL_M, ORIENTATION_TOL_RAD, free_spin=free_spin, avoid_table=free_spin)
    s.set_q(HOME_Q if q_start is None else q_start)
    q = np.empty((k, 6))
    pe = np.empty(k)
    oe = np.empty(k)
    sig = np.empty(k)
    its = np.empty(k, dtype=np.int64)
    for i in range(k):
        if i == 0:
            # The first pose from the start guess with its full frame (the spin too): the arm
            # lands on the start guess's branch; the spin is freed from the next pose on.
            s.set_spin_free(False)
            pe[i], oe[i], its[i] = first_pose(s, cell, site, T_world[0], HOME_Q if q_start is None else q_start)
            s.set_spin_free(free_spin)
            pe[i], oe[i] = s.errors()
            first_time = time.perf_counter() - t0
        else:
            if i >= 2:
                # First-order predictor: on a smooth path one QP step then usually suffices.
                s.predict(2.0 * q[i - 1] - q[i - 2])
            pe[i], oe[i], its[i] = s.solve(T_world[i], float(dt[i]), MAX_ITERATIONS, stop_when_stalled=True)
        q[i] = s.q
        sig[i] = s.sigma_min(JACOBIAN_LENGTH_M)
    elapsed = time.perf_counter() - t0
    problems: list[PathProblem] = []
    for j in np.flatnonzero(~reachable(pe, oe)):
        problems.append(PathProblem(int(j), "unreachable", tuple(T[j, :3, 3]),
                                    f"flange stays {pe[j] * 1e3:.3f} mm / {np.degrees(oe[j]):.3f} deg off"))
    for j in np.flatnonzero(sig < SINGULAR_SIGMA):
        msg = f"smallest Jacobian singular value {sig[j] * 1e3:.3f} mm/rad < {SINGULAR_SIGMA * 1e3:g}"
        problems.append(PathProblem(int(j), "singular", tuple(T[j, :3, 3]), msg))
    if k > 1:
        jump = np.max(np.abs(np.diff(q, axis=0)), axis=1)
        for j in np.flatnonzero(jump > JUMP_RAD):
            problems.append(PathProblem(int(j + 1), "discontinuous", tuple(T[j + 1, :3, 3]),
                                        f"a joint moves {jump[j]:.3f} rad from the previous pose (> {JUMP_RAD} rad)"))
    problems.sort(key=lambda p: (p.index, p.kind))
    result = PathIK(q, pe, oe, sig, its, tuple(problems), elapsed, first_time)
    if problems and on_problem == "raise":
        raise PathError(_summarise(problems, k), tuple(problems))
    return result


class TableCheck:
    """Whether the arm's links keep a clearance from the table (and, given ``part_clearance_m``,
    from the part's collision shape) at a joint configuration: MuJoCo's collision detection on
    a copy of the model with a margin on each obstacle (the base and the shoulder turret, which
    stand on the table, are left out).

    Args:
        cell: the nominal cell; with ``part_clearance_m``, one built with the part's collision
            shape (geom ``workpiece_collision``, :func:`twin.replay.add_collision_checks`).
        clearance_m: from the table [m]; part_clearance_m: from the part [m] (None: unchecked).
    """

    def __init__(self, cell: Cell, clearance_m: float, part_clearance_m: float | None = None) -> None:
        self.model = copy.copy(cell.model)
        self.table = self.model.geom("table").id
        self.clearance_m = clearance_m
        # each obstacle's clearance, by geom id (-inf: not an obstacle)
        self.limit_m = np.full(self.model.ngeom, -np.inf)
        self.limit_m[self.table] = clearance_m
        if part_clearance_m is not None:
            self.limit_m[self.model.geom("workpiece_collision").id] = part_clearance_m
        obstacles = np.isfinite(self.limit_m)
        self.model.geom_margin[obstacles] = self.limit_m[obstacles]
        self.data = mujoco.MjData(self.model)
        self.adr = cell.qpos_adr
        # the geoms of the bodies that stand on the table (by geom id)
        self.standing = np.array([self.model.body(self.model.geom_bodyid[g]).name in ("base", "shoulder_pan_link")
                                  for g in range(self.model.ngeom)])

    def nearest(self, q: np.ndarray) -> tuple[str, float] | None:
        """(geom name, distance [m]) of the link nearest an obstacle within its clearance, or None."""
        self.data.qpos[self.adr] = q
        mujoco.mj_kinematics(self.model, self.data)   # the geoms' poses: all the collision needs
        mujoco.mj_collision(self.model, self.data)
        if self.data.ncon == 0:
            return None
        c = self.data.contact[: self.data.ncon]
        first = np.isfinite(self.limit_m[c.geom1])
        obstacle, other = np.where(first, c.geom1, c.geom2), np.where(first, c.geom2, c.geom1)
        hit = np.isfinite(self.limit_m[obstacle]) & ~np.isfinite(self.limit_m[other]) \
            & ~self.standing[other] & (c.dist < self.limit_m[obstacle])
        if not hit.any():
            return None
        k = int(np.flatnonzero(hit)[np.argmin(c.dist[hit])])
        return self.model.geom(int(other[k])).name, float(c.dist[k])


def site_in_flange(cell: Cell, site: str) -> np.ndarray:
    """(4, 4) a site's pose in the flange site's frame (DH frame 6): fixed, whatever the joints."""
    data = mujoco.MjData(cell.model)
    mujoco.mj_kinematics(cell.model, data)
    T_world_flange, T_world_site = (np.eye(4), np.eye(4))
    for T, name in ((T_world_flange, "flange"), (T_world_site, site)):
        T[:3, :3] = data.site(name).xmat.reshape(3, 3)
        T[:3, 3] = data.site(name).xpos
    return inv_pose(T_world_flange) @ T_world_site


def first_pose(s: IKSolver, cell: Cell, site: str, T_world_target: np.ndarray,
                q_start: np.ndarray) -> tuple[float, float, int]:
    """Solve the first pose from ``q_start``; if that ends off target (stuck at a joint limit,
    or the start lies on another branch) or with the arm in the table, from each closed-form
    solution of the pose (the UR geometry's eight branches), nearest ``q_start`` first. Returns (position error,
    orientation error, iterations) of the solution kept."""
    table = TableCheck(cell, TABLE_CLEARANCE_M)
    s.set_q(q_start)
    pe, oe, its = s.solve(T_world_target, 0.05, FIRST_POSE_ITERATIONS, velocity_limited=False)
    if reachable(pe, oe) and table.nearest(s.q) is None:
        return pe, oe, its
    best = (pe, oe, its, s.q)
    T_base_flange = inv_pose(cell.T_world_base) @ T_world_target @ inv_pose(site_in_flange(cell, site))
    sol = ur_inverse(T_base_flange, UR5E_DH)
    seeds = sol.q[0][sol.valid[0]]
    for q in seeds[np.argsort(np.linalg.norm(seeds - q_start, axis=1))]:
        s.set_q(q)
        pe, oe, its = s.solve(T_world_target, 0.05, FIRST_POSE_ITERATIONS, velocity_limited=False)
        if reachable(pe, oe) and table.nearest(s.q) is None:
            return pe, oe, its
        if pe < best[0]:
            best = (pe, oe, its, s.q)
    s.set_q(best[3])
    return best[0], best[1], best[2]


def _summarise(problems: list[PathProblem], k: int) -> str:
    kinds: dict[str, list[PathProblem]] = {}
    for p in problems:
        kinds.setdefault(p.kind, []).append(p)
    parts = []
    for kind, ps in kinds.items():
        idx = [p.index for p in ps]
        parts.append(f"{len(ps)} {kind} pose(s) of {k} (indices {idx[0]}..{idx[-1]})")
    return "path cannot be followed: " + "; ".join(parts) + "; first: " + problems[0].describe()


def plan_joint_trajectory(cell: Cell, path: ProcessPath, T_flange_tool: np.ndarray, feed_m_s: float,
                          transit_speed_m_s: float, acceleration_m_s2: float,
                          q_start: np.ndarray | None = None,
                          touchdown_acceleration_m_s2: float | None = None,
                          free_spin: bool = False) -> tuple[PathIK, Trajectory]:
    """IK along the path and the time law, in one call.

    With ``free_spin`` (a ball-end tool, symmetric about its axis) the IK holds the ball
    centre (``twin.cell.TOOL_BALL_SITE``) and the tool axis and leaves the spin about the axis
    free; otherwise it follows the flange poses of eq. (13).

    Raises:
        PathError: unreachable, singular or discontinuous poses (with their indices and positions).
        TwinError: bad tool transform, feed or speeds.
    """
    if not (np.isfinite(acceleration_m_s2) and acceleration_m_s2 > 0):
        raise TwinError(f"path acceleration must be a positive number, got {acceleration_m_s2!r}")
    ik = solve_tool_path(cell, path, T_flange_tool, feed_m_s, transit_speed_m_s, q_start, free_spin)
    if ik.problems:
        # Say where on the program the first bad pose is (line, move), not only its index.
        first = ik.problems[0]
        a, b, kind, line = path.segments[path.segment[first.index]]
        where = f"process line {line}" if kind == "process" else f"{kind} move (poses {a}..{b})"
        raise PathError(f"{_summarise(list(ik.problems), len(ik.q))} [{where}]", ik.problems)
    return ik, time_law_for(path, ik, feed_m_s, transit_speed_m_s, acceleration_m_s2, touchdown_acceleration_m_s2)


def time_law_for(path: ProcessPath, ik: PathIK, feed_m_s: float, transit_speed_m_s: float,
                 acceleration_m_s2: float, touchdown_acceleration_m_s2: float | None = None) -> Trajectory:
    """The time law of a solved path with the UR5e's joint limits."""
    return time_law(path, ik.q, feed_m_s, transit_speed_m_s, acceleration_m_s2, VELOCITY_LIMIT_RAD_S,
                    PATH_ACCELERATION_FRACTION * ACCELERATION_LIMIT_RAD_S2,
                    touchdown_acceleration_m_s2=touchdown_acceleration_m_s2)


def solve_tool_path(cell: Cell, path: ProcessPath, T_flange_tool: np.ndarray, feed_m_s: float,
                    transit_speed_m_s: float, q_start: np.ndarray | None = None,
                    free_spin: bool = False) -> PathIK:
    """IK along a process path; every bad pose is returned in ``problems`` (never raised)."""
    for name, v in (("feed rate", feed_m_s), ("transit speed", transit_speed_m_s)):
        if not (np.isfinite(v) and v > 0):
            raise TwinError(f"{name} must be a positive number, got {v!r}")
    try:
        T_bf = flange_poses(path.T_tool, T_flange_tool)
    except AlgorithmError as exc:
        raise TwinError(str(exc)) from None
    speed = np.full(len(T_bf), transit_speed_m_s)
    speed[path.process_mask()] = feed_m_s
    dt = _step_dt(path.T_tool, speed)
    if not free_spin:
        return solve_path(cell, T_bf, q_start=q_start, dt=dt, on_problem="report")
    if not np.allclose(T_flange_tool, cell.scenario.path.T_flange_tool, atol=1e-12) or \
            abs(path.tip_radius_m - cell.scenario.path.tip_radius_m) > 1e-12:
        raise TwinError("the five-axis IK needs the cell's own tool (scenario [path] tool and tip_radius_m)")
    T_ball = path.T_tool.copy()
    T_ball[:, :3, 3] += path.tip_radius_m * T_ball[:, :3, 2]
    return solve_path(cell, T_ball, q_start=q_start, dt=dt, on_problem="report", site=TOOL_BALL_SITE,
                      free_spin=True)


def joint_move(q_a: np.ndarray, q_b: np.ndarray, dt: float,
               velocity_limit_rad_s: np.ndarray = VELOCITY_LIMIT_RAD_S,
               acceleration_limit_rad_s2: np.ndarray = ACCELERATION_LIMIT_RAD_S2) -> tuple[np.ndarray, np.ndarray]:
    """A synchronised point-to-point joint move, rest to rest: every joint follows the same
    trapezoidal profile in time, scaled so that the slowest joint meets its limits.

    Args:
        q_a, q_b: (6,) start and end joints [rad]; dt: sample period [s].

    Returns:
        (q_ref, qd_ref), each (K, 6), K >= 2 samples ``dt`` apart, from ``q_a`` to exactly ``q_b``.
    """
    q_a = np.asarray(q_a, dtype=np.float64)
    delta = np.asarray(q_b, dtype=np.float64) - q_a
    span = np.abs(delta)
    if not np.any(span > 1e-12):
        return np.stack([q_a, q_a]), np.zeros((2, 6))
    moving = span > 1e-12
    # the fraction of the move s in [0, 1]: its speed and acceleration limits from each joint's
    v = float(np.min(velocity_limit_rad_s[moving] / span[moving]))
    a = float(np.min(acceleration_limit_rad_s2[moving] / span[moving]))
    t_acc = v / a
    if a * t_acc**2 >= 1.0:  # triangle profile
        t_acc = np.sqrt(1.0 / a)
        v = a * t_acc
    t_flat = (1.0 - a * t_acc**2) / v
    total = 2 * t_acc + t_flat
    t = np.arange(int(np.ceil(total / dt - 1e-9)) + 1) * dt
    t = np.minimum(t, total)
    t_dec = np.maximum(total - t, 0.0)
    s = np.where(t < t_acc, 0.5 * a * t**2,
                 np.where(t < t_acc + t_flat, 0.5 * a * t_acc**2 + v * (t - t_acc), 1.0 - 0.5 * a * t_dec**2))
    sd = np.where(t < t_acc, a * t, np.where(t < t_acc + t_flat, v, a * t_dec))
    s[-1], sd[-1] = 1.0, 0.0
    return q_a + s[:, None] * delta, sd[:, None] * delta

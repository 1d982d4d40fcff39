"""Joint trajectories along a process path: mink IK pose by pose, then a time law.

IK (:func:`solve_path`) runs on the NOMINAL cell (what the controller believes), on the
``flange`` site: the targets are the flange poses of eq. (13). Each pose is solved by
differential IK with mink (a FrameTask, a tiny posture regulariser, configuration limits and
velocity limits), warm-started from the previous pose's solution: the joint path stays on
one branch because no step can jump (each QP step moves a joint at most ``v_max * dt``, with
``dt`` the time the path allots to that step at its commanded speed). Every pose is then
checked:

* unreachable: the frame error stays above ``UNREACHABLE_POSITION_M`` /
  ``UNREACHABLE_ORIENTATION_RAD`` after ``MAX_ITERATIONS`` (out of reach, a joint limit, or
  a speed the velocity limits cannot follow);
* singular: the smallest singular value of the Jacobian (rotation rows scaled by
  ``JACOBIAN_LENGTH_M`` so both halves are in metres per radian) is below ``SINGULAR_SIGMA``;
* discontinuous: a joint moves more than ``JUMP_RAD`` between consecutive poses (a branch
  flip).

Problems are never skipped: they are collected with the pose index and position, and
:func:`solve_path` raises :class:`PathError` listing them unless asked to return them.

Time law (:func:`time_law`): every segment of the path (approach, process line, retract,
transit) goes rest to rest along its path parameter ``s`` at the segment's speed: on process
lines ``s`` is the TCP's arc length and the speed the feed; in the air ``s`` also counts
``ROTATION_LENGTH_M_PER_RAD`` per radian the tool turns. A path acceleration limit and the
joint velocity and acceleration limits apply.
With ``q(s)`` a cubic spline through the IK solutions, the joint rates are
``qd = q'(s) sd`` and ``qdd = q''(s) sd^2 + q'(s) sdd``: a velocity limit curve
``sd <= min(v, v_max / |q'|, sqrt(a_max / 2 |q''|))`` and forward/backward passes with the
acceleration left over (a numerical time-optimal parameterisation) give ``sd(s)``; the 1 ms
samples are then checked against the limits and a segment that still exceeds them is slowed
and redone.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import mink
import mujoco
import numpy as np
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation

from algorithms.paths.toolpath import ROTATION_LENGTH_M_PER_RAD, ProcessPath
from twin.cell import Cell
from twin.errors import TwinError
from twin.robot import ACCELERATION_LIMIT_RAD_S2, HOME_Q, JOINT_NAMES, VELOCITY_LIMIT_RAD_S

POSITION_TOL_M = 1e-6
ORIENTATION_TOL_RAD = 1e-5
MAX_ITERATIONS = 50
FIRST_POSE_ITERATIONS = 2000
UNREACHABLE_POSITION_M = 1e-4
UNREACHABLE_ORIENTATION_RAD = 1e-3
JACOBIAN_LENGTH_M = 0.1
SINGULAR_SIGMA = 2e-3   # m/rad: 1 rad/s of joint speed moves the flange < 2 mm/s somewhere
JUMP_RAD = 0.2
POSTURE_COST = 1e-6
# Time law: fine grid along each segment, share of the limits planned for.
FINE_STEP_M = 2e-4
LIMIT_SHARE = 0.95
MAX_RETIME = 6


class PathError(TwinError):
    """A path the robot cannot follow; ``problems`` lists every bad pose."""

    def __init__(self, message: str, problems: tuple = ()):
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


class _Solver:
    """mink differential IK on the flange site, kept warm between poses."""

    def __init__(self, model: mujoco.MjModel, site: str):
        self.model = model
        self.configuration = mink.Configuration(model)
        self.task = mink.FrameTask(site, "site", position_cost=1.0, orientation_cost=1.0, lm_damping=1e-9)
        self.posture = mink.PostureTask(model, cost=POSTURE_COST)
        self.limits_pos = mink.ConfigurationLimit(model)
        self.velocity = mink.VelocityLimit(model, {n: float(v) for n, v in zip(JOINT_NAMES, VELOCITY_LIMIT_RAD_S)})
        self.site_id = model.site(site).id
        self.jacp = np.zeros((3, model.nv))
        self.jacr = np.zeros((3, model.nv))

    def errors(self) -> tuple[float, float]:
        e = self.task.compute_error(self.configuration)
        return float(np.sqrt(e[0] ** 2 + e[1] ** 2 + e[2] ** 2)), float(np.sqrt(e[3] ** 2 + e[4] ** 2 + e[5] ** 2))

    def solve(self, T_world: np.ndarray, dt: float, max_iter: int, velocity_limited: bool = True):
        self.task.set_target(mink.SE3.from_matrix(T_world))
        self.posture.set_target(self.configuration.q)
        limits = [self.limits_pos, self.velocity] if velocity_limited else [self.limits_pos]
        pe, oe = self.errors()
        it = 0
        while it < max_iter and (pe > POSITION_TOL_M or oe > ORIENTATION_TOL_RAD):
            try:
                v = mink.solve_ik(self.configuration, [self.task, self.posture], dt, solver="daqp",
                                  damping=1e-12, limits=limits)
            except mink.exceptions.NoSolutionFound:
                # No step satisfies the limits from here (a joint pressed against its range):
                # the pose stays where it is and is reported if it is off.
                break
            self.configuration.integrate_inplace(v, dt)
            pe, oe = self.errors()
            it += 1
        return pe, oe, it

    def predict(self, q: np.ndarray) -> None:
        """Warm start at ``q``, kept inside the joint ranges (the limits' QP needs a feasible start)."""
        lo = self.model.jnt_range[:6, 0] + 1e-6
        hi = self.model.jnt_range[:6, 1] - 1e-6
        self.configuration.update(np.clip(q, lo, hi))

    def sigma_min(self) -> float:
        mujoco.mj_jacSite(self.model, self.configuration.data, self.jacp, self.jacr, self.site_id)
        J = np.vstack([self.jacp, JACOBIAN_LENGTH_M * self.jacr])
        return float(np.linalg.svd(J, compute_uv=False)[-1])


def _step_dt(T: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """Time the path allots to each step (K,) at the given speeds (the first pose gets 1 s)."""
    dp = np.linalg.norm(np.diff(T[:, :3, 3], axis=0), axis=1)
    rel = np.einsum("nji,njk->nik", T[:-1, :3, :3], T[1:, :3, :3])
    da = np.linalg.norm(Rotation.from_matrix(rel).as_rotvec(), axis=1)
    ds = dp + ROTATION_LENGTH_M_PER_RAD * da
    return np.concatenate([[1.0], np.maximum(ds / speed[1:], 1e-4)])


def solve_path(cell: Cell, T_base_flange: np.ndarray, q_start: np.ndarray | None = None,
               dt: np.ndarray | None = None, on_problem: str = "raise", site: str = "flange") -> PathIK:
    """Joint angles for a sequence of flange poses (robot base frame), see the module docstring.

    Args:
        cell: the NOMINAL cell.
        T_base_flange: (K, 4, 4) flange poses [m], base frame.
        q_start: (6,) initial guess for the first pose (default: the home posture).
        dt: (K,) time allotted to reach each pose from the previous one [s] (velocity limit
            of the IK steps); default: 1 mm per 10 ms.
        on_problem: ``"raise"`` (default) or ``"report"`` (return them in ``problems``).

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
    s = _Solver(cell.model, site)
    q0 = HOME_Q if q_start is None else np.asarray(q_start, dtype=np.float64)
    s.configuration.update(q0)
    q = np.empty((k, 6))
    pe = np.empty(k)
    oe = np.empty(k)
    sig = np.empty(k)
    its = np.empty(k, dtype=np.int64)
    for i in range(k):
        if i == 0:
            pe[i], oe[i], its[i] = s.solve(T_world[0], 0.05, FIRST_POSE_ITERATIONS, velocity_limited=False)
            first_time = time.perf_counter() - t0
        else:
            if i >= 2:
                # First-order predictor: on a smooth path one QP step then usually suffices.
                s.predict(2.0 * q[i - 1] - q[i - 2])
            pe[i], oe[i], its[i] = s.solve(T_world[i], float(dt[i]), MAX_ITERATIONS)
        q[i] = s.configuration.q[:6]
        sig[i] = s.sigma_min()
    elapsed = time.perf_counter() - t0
    problems = []
    for i in np.flatnonzero((pe > UNREACHABLE_POSITION_M) | (oe > UNREACHABLE_ORIENTATION_RAD)):
        problems.append(PathProblem(int(i), "unreachable", tuple(T[i, :3, 3]),
                                    f"flange stays {pe[i] * 1e3:.3f} mm / {np.degrees(oe[i]):.3f} deg off"))
    for i in np.flatnonzero(sig < SINGULAR_SIGMA):
        problems.append(PathProblem(int(i), "singular", tuple(T[i, :3, 3]),
                                    f"smallest Jacobian singular value {sig[i] * 1e3:.3f} mm/rad < {SINGULAR_SIGMA * 1e3:g}"))
    if k > 1:
        jump = np.max(np.abs(np.diff(q, axis=0)), axis=1)
        for i in np.flatnonzero(jump > JUMP_RAD):
            problems.append(PathProblem(int(i + 1), "discontinuous", tuple(T[i + 1, :3, 3]),
                                        f"a joint moves {jump[i]:.3f} rad from the previous pose (> {JUMP_RAD} rad)"))
    problems.sort(key=lambda p: (p.index, p.kind))
    result = PathIK(q, pe, oe, sig, its, tuple(problems), elapsed, first_time)
    if problems and on_problem == "raise":
        raise PathError(_summarise(problems, k), tuple(problems))
    return result


def _summarise(problems: list, k: int) -> str:
    kinds = {}
    for p in problems:
        kinds.setdefault(p.kind, []).append(p)
    parts = []
    for kind, ps in kinds.items():
        idx = [p.index for p in ps]
        parts.append(f"{len(ps)} {kind} pose(s) of {k} (indices {idx[0]}..{idx[-1]})")
    return "path cannot be followed: " + "; ".join(parts) + "; first: " + problems[0].describe()


@dataclass(frozen=True)
class Trajectory:
    """A timed joint trajectory sampled every ``dt``.

    Attributes:
        t: (N,) [s].
        q: (N, 6) joint references [rad]; ``qd`` (N, 6) [rad/s] (the servo feed-forward);
            ``qdd`` (N, 6) [rad/s^2].
        segment: (N,) segment index (into ``path.segments``) of each sample.
        t_path: (K,) time at which each path pose is reached [s].
        q_path: (K, 6) the IK solutions the trajectory interpolates.
        velocity_ratio: largest ``|qd| / v_max`` over samples and joints.
        acceleration_ratio: largest ``|qdd| / a_max``.
        speed_m_s: (N,) commanded path speed [m/s] (path parameter rate).
    """

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    segment: np.ndarray
    t_path: np.ndarray
    q_path: np.ndarray
    velocity_ratio: float
    acceleration_ratio: float
    speed_m_s: np.ndarray = field(repr=False)
    dt: float = 0.001

    @property
    def duration_s(self) -> float:
        return float(self.t[-1]) if len(self.t) else 0.0


def _segment_profile(qs: np.ndarray, T: np.ndarray, v_seg: float, a_path: float, vmax: np.ndarray,
                     amax: np.ndarray, share: float, rotation_length: float):
    """Rest-to-rest profile of one segment: fine grid s, speeds, spline q(s), knot arc lengths."""
    dp = np.linalg.norm(np.diff(T[:, :3, 3], axis=0), axis=1)
    rel = np.einsum("nji,njk->nik", T[:-1, :3, :3], T[1:, :3, :3])
    da = np.linalg.norm(Rotation.from_matrix(rel).as_rotvec(), axis=1)
    ds = dp + rotation_length * da
    if np.sum(ds) <= 1e-9:  # a turn on the spot: time it by the angle
        ds = dp + ROTATION_LENGTH_M_PER_RAD * da
    keep = np.concatenate([[True], ds > 1e-12])
    s_knots_all = np.concatenate([[0.0], np.cumsum(ds)])
    s_knots = s_knots_all[keep]
    length = float(s_knots[-1])
    if length <= 1e-12:
        return None, s_knots_all
    spline = CubicSpline(s_knots, qs[keep], axis=0)
    m = max(8, int(np.ceil(length / FINE_STEP_M)))
    s = np.linspace(0.0, length, m + 1)
    d1 = np.abs(spline(s, 1))
    d2 = np.abs(spline(s, 2))
    with np.errstate(divide="ignore"):
        v_lim = np.minimum(
            v_seg,
            np.minimum(np.min(share * vmax / d1, axis=1), np.min(np.sqrt(0.5 * share * amax / d2), axis=1)),
        )
    h = np.diff(s)

    def a_avail(i, v):
        with np.errstate(divide="ignore", invalid="ignore"):
            a_j = (share * amax - d2[i] * v * v) / d1[i]
        a_j = np.where(np.isfinite(a_j), a_j, np.inf)
        return max(0.0, min(a_path, float(np.min(a_j))))

    v = v_lim.copy()
    v[0] = 0.0
    v[-1] = 0.0
    for i in range(m):
        v[i + 1] = min(v[i + 1], np.sqrt(v[i] ** 2 + 2.0 * a_avail(i, v[i]) * h[i]))
    for i in range(m, 0, -1):
        v[i - 1] = min(v[i - 1], np.sqrt(v[i] ** 2 + 2.0 * a_avail(i, v[i]) * h[i - 1]))
    # A grid point where the limits allow no speed at all would stall the profile.
    floor = 1e-6
    v[1:-1] = np.maximum(v[1:-1], floor)
    dt = 2.0 * h / (v[:-1] + v[1:])
    t = np.concatenate([[0.0], np.cumsum(dt)])
    return (spline, s, v, t), s_knots_all


def _evaluate(profile, tau: np.ndarray):
    """s, sd, sdd and q, qd, qdd at local times ``tau`` of a segment profile."""
    spline, s_f, v_f, t_f = profile
    tau = np.clip(tau, 0.0, t_f[-1])
    i = np.clip(np.searchsorted(t_f, tau, side="right") - 1, 0, len(s_f) - 2)
    h = s_f[i + 1] - s_f[i]
    a = (v_f[i + 1] ** 2 - v_f[i] ** 2) / (2.0 * h)
    dtau = tau - t_f[i]
    s = np.minimum(s_f[i] + v_f[i] * dtau + 0.5 * a * dtau**2, s_f[-1])
    sd = np.maximum(v_f[i] + a * dtau, 0.0)
    q = spline(s)
    d1 = spline(s, 1)
    d2 = spline(s, 2)
    return q, d1 * sd[:, None], d2 * (sd**2)[:, None] + d1 * a[:, None], sd


def time_law(path: ProcessPath, q_path: np.ndarray, feed_m_s: float, transit_speed_m_s: float,
             acceleration_m_s2: float, dt: float = 0.001, vmax: np.ndarray = VELOCITY_LIMIT_RAD_S,
             amax: np.ndarray = ACCELERATION_LIMIT_RAD_S2, touchdown_acceleration_m_s2: float | None = None
             ) -> Trajectory:
    """Time the joint path (see the module docstring) and sample it every ``dt``.

    Args:
        path: the process path (its ``T_tool`` poses give the path parameter).
        q_path: (K, 6) IK solutions at the path poses.
        feed_m_s: speed on process lines [m/s], > 0.
        transit_speed_m_s: speed of the moves in the air [m/s], > 0.
        acceleration_m_s2: path acceleration limit [m/s^2], > 0.
        touchdown_acceleration_m_s2: acceleration limit of the approach and retract moves
            (touch-down and lift-off along the tool axis) [m/s^2]; default: the same.

    Raises:
        TwinError: a speed or acceleration of zero or below, shapes.
    """
    if touchdown_acceleration_m_s2 is None:
        touchdown_acceleration_m_s2 = acceleration_m_s2
    for name, v in (("feed rate", feed_m_s), ("transit speed", transit_speed_m_s),
                    ("path acceleration", acceleration_m_s2), ("time step", dt),
                    ("touch-down acceleration", touchdown_acceleration_m_s2)):
        if not (np.isfinite(v) and v > 0):
            raise TwinError(f"{name} must be a positive number, got {v!r}")
    q_path = np.asarray(q_path, dtype=np.float64)
    if q_path.shape != (len(path.T_tool), 6):
        raise TwinError(f"q_path must be ({len(path.T_tool)}, 6), got {q_path.shape}")
    vmax = np.asarray(vmax, dtype=np.float64)
    amax = np.asarray(amax, dtype=np.float64)
    profiles = []
    t_path = np.zeros(len(q_path))
    t_start = 0.0
    for si, (a, b, kind, line) in enumerate(path.segments):
        speed = feed_m_s if kind == "process" else transit_speed_m_s
        acc = touchdown_acceleration_m_s2 if kind in ("approach", "retract") else acceleration_m_s2
        share = LIMIT_SHARE
        for _ in range(MAX_RETIME):
            # On a process line the feed is the TCP's speed; moves in the air also count the
            # tool's turning (ROTATION_LENGTH_M_PER_RAD per radian) so a turn takes time.
            prof, s_knots = _segment_profile(q_path[a:b + 1], path.T_tool[a:b + 1], speed, acc, vmax, amax,
                                             share, 0.0 if kind == "process" else ROTATION_LENGTH_M_PER_RAD)
            if prof is None:
                break
            tt = np.arange(0.0, prof[3][-1] + dt, dt)
            _, qd, qdd, _ = _evaluate(prof, tt)
            r = max(float(np.max(np.abs(qd) / vmax)), float(np.sqrt(np.max(np.abs(qdd) / amax))))
            if r <= 1.0:
                break
            share *= 0.98 / r
        duration = 0.0 if prof is None else float(prof[3][-1])
        if prof is not None:
            t_path[a:b + 1] = t_start + np.interp(s_knots, prof[1], prof[3])
        else:
            t_path[a:b + 1] = t_start
        profiles.append((t_start, duration, prof, a, b))
        t_start += duration
    n = int(np.ceil(t_start / dt - 1e-9)) + 1
    t = np.arange(n) * dt
    q = np.empty((n, 6))
    qd = np.zeros((n, 6))
    qdd = np.zeros((n, 6))
    sd = np.zeros(n)
    seg = np.empty(n, dtype=np.int64)
    starts = np.array([p[0] for p in profiles])
    which = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(profiles) - 1)
    # Samples after a zero-length segment's start belong to the next one with time.
    for si, (t0, dur, prof, a, b) in enumerate(profiles):
        sel = np.flatnonzero(which == si)
        if len(sel) == 0:
            continue
        seg[sel] = si
        if prof is None:
            q[sel] = q_path[b]
            continue
        q[sel], qd[sel], qdd[sel], sd[sel] = _evaluate(prof, t[sel] - t0)
    vr = float(np.max(np.abs(qd) / vmax)) if n else 0.0
    ar = float(np.max(np.abs(qdd) / amax)) if n else 0.0
    return Trajectory(t, q, qd, qdd, seg, t_path, q_path.copy(), vr, ar, sd, dt)


def plan_joint_trajectory(cell: Cell, path: ProcessPath, T_flange_tool: np.ndarray, feed_m_s: float,
                          transit_speed_m_s: float, acceleration_m_s2: float,
                          q_start: np.ndarray | None = None,
                          touchdown_acceleration_m_s2: float | None = None) -> tuple[PathIK, Trajectory]:
    """Flange poses (eq. 13), IK along the path and the time law, in one call.

    Raises:
        PathError: unreachable, singular or discontinuous poses (with their indices and positions).
        TwinError: bad tool transform, feed or speeds.
    """
    from algorithms.errors import AlgorithmError
    from algorithms.paths.toolpath import flange_poses

    for name, v in (("feed rate", feed_m_s), ("transit speed", transit_speed_m_s),
                    ("path acceleration", acceleration_m_s2)):
        if not (np.isfinite(v) and v > 0):
            raise TwinError(f"{name} must be a positive number, got {v!r}")
    try:
        T_bf = flange_poses(path.T_tool, T_flange_tool)
    except AlgorithmError as exc:
        raise TwinError(str(exc)) from None
    speed = np.full(len(T_bf), transit_speed_m_s)
    speed[path.process_mask()] = feed_m_s
    try:
        ik = solve_path(cell, T_bf, q_start=q_start, dt=_step_dt(path.T_tool, speed))
    except PathError as exc:
        # Say where on the program the first bad pose is (line, move), not only its index.
        first = exc.problems[0]
        a, b, kind, line = path.segments[path.segment[first.index]]
        where = f"process line {line}" if kind == "process" else f"{kind} move (poses {a}..{b})"
        raise PathError(f"{exc} [{where}]", exc.problems) from None
    return ik, time_law(path, ik.q, feed_m_s, transit_speed_m_s, acceleration_m_s2,
                        touchdown_acceleration_m_s2=touchdown_acceleration_m_s2)

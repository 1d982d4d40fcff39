"""The time law of a joint path: rest-to-rest segments within joint velocity and acceleration limits.

Every segment of the path (approach, process line, retract,
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

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import CubicSpline

from algorithms.arraytypes import ArrayLike, FloatArray, IntArray
from algorithms.errors import AlgorithmError
from algorithms.geometry.arclength import ROTATION_LENGTH_M_PER_RAD, step_lengths
from algorithms.paths.toolpath import ProcessPath

# Fine grid along each segment, share of the limits planned for, re-timing passes.
FINE_STEP_M = 2e-4
LIMIT_SHARE = 0.95
MAX_RETIME = 6


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

    t: FloatArray
    q: FloatArray
    qd: FloatArray
    qdd: FloatArray
    segment: IntArray
    t_path: FloatArray
    q_path: FloatArray
    velocity_ratio: float
    acceleration_ratio: float
    speed_m_s: FloatArray = field(repr=False)
    dt: float = 0.001

    @property
    def duration_s(self) -> float:
        """Time of the last sample [s] (0 when empty)."""
        return float(self.t[-1]) if len(self.t) else 0.0


def _segment_profile(qs: FloatArray, T: FloatArray, v_seg: float, a_path: float, vmax: FloatArray,
                     amax: FloatArray, share: float, rotation_length: float):
    """Rest-to-rest profile of one segment: fine grid s, speeds, spline q(s), knot arc lengths."""
    ds = step_lengths(T, rotation_length)
    if np.sum(ds) <= 1e-9:  # a turn on the spot: time it by the angle
        ds = step_lengths(T, ROTATION_LENGTH_M_PER_RAD)
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

    # the passes run on Python floats: the same IEEE operations as numpy's, without its per-call
    # overhead (2.9x faster on a 1,000-point segment, the same speeds bit for bit)
    limit = (share * amax).tolist()
    d1_rows, d2_rows = d1.tolist(), d2.tolist()

    def a_avail(i: int, v: float) -> float:
        """The path acceleration the joints leave at grid point i and speed v (a joint with
        q' = 0 sets no limit)."""
        best = a_path
        for lim, c1, c2 in zip(limit, d1_rows[i], d2_rows[i], strict=True):
            if c1 != 0.0:
                best = min(best, (lim - c2 * v * v) / c1)
        return max(0.0, best)

    speeds = v_lim.tolist()
    speeds[0] = 0.0
    speeds[-1] = 0.0
    steps = h.tolist()
    for i in range(m):
        speeds[i + 1] = min(speeds[i + 1], math.sqrt(speeds[i] ** 2 + 2.0 * a_avail(i, speeds[i]) * steps[i]))
    for i in range(m, 0, -1):
        speeds[i - 1] = min(speeds[i - 1], math.sqrt(speeds[i] ** 2 + 2.0 * a_avail(i, speeds[i]) * steps[i - 1]))
    v = np.array(speeds)
    # A grid point where the limits allow no speed at all would stall the profile.
    floor = 1e-6
    v[1:-1] = np.maximum(v[1:-1], floor)
    dt = 2.0 * h / (v[:-1] + v[1:])
    t = np.concatenate([[0.0], np.cumsum(dt)])
    return (spline, s, v, t), s_knots_all


def _evaluate(profile, tau: FloatArray):
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


def time_law(path: ProcessPath, q_path: ArrayLike, feed_m_s: float, transit_speed_m_s: float,
             acceleration_m_s2: float, vmax: FloatArray, amax: FloatArray, dt: float = 0.001,
             touchdown_acceleration_m_s2: float | None = None) -> Trajectory:
    """Time the joint path (see the module docstring) and sample it every ``dt``.

    Args:
        path: the process path (its ``T_tool`` poses give the path parameter).
        q_path: (K, 6) IK solutions at the path poses.
        feed_m_s: speed on process lines [m/s], > 0.
        transit_speed_m_s: speed of the moves in the air [m/s], > 0.
        acceleration_m_s2: path acceleration limit [m/s^2], > 0.
        vmax: (J,) joint velocity limits [rad/s]; amax: (J,) joint acceleration limits [rad/s^2].
        dt: sample period [s].
        touchdown_acceleration_m_s2: acceleration limit of the approach and retract moves
            (touch-down and lift-off along the tool axis) [m/s^2]; default: the same.

    Raises:
        AlgorithmError: a speed or acceleration of zero or below, shapes.
    """
    if touchdown_acceleration_m_s2 is None:
        touchdown_acceleration_m_s2 = acceleration_m_s2
    for name, v in (("feed rate", feed_m_s), ("transit speed", transit_speed_m_s),
                    ("path acceleration", acceleration_m_s2), ("time step", dt),
                    ("touch-down acceleration", touchdown_acceleration_m_s2)):
        if not (np.isfinite(v) and v > 0):
            raise AlgorithmError(f"{name} must be a positive number, got {v!r}")
    q_path = np.asarray(q_path, dtype=np.float64)
    if q_path.shape != (len(path.T_tool), len(vmax)):
        raise AlgorithmError(f"q_path must be ({len(path.T_tool)}, {len(vmax)}), got {q_path.shape}")
    vmax = np.asarray(vmax, dtype=np.float64)
    amax = np.asarray(amax, dtype=np.float64)
    profiles = []
    t_path = np.zeros(len(q_path))
    t_start = 0.0
    for a, b, kind, _line in path.segments:
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
    t = np.arange(n, dtype=np.float64) * dt
    q = np.empty((n, 6))
    qd = np.zeros((n, 6))
    qdd = np.zeros((n, 6))
    sd = np.zeros(n)
    seg = np.empty(n, dtype=np.int64)
    starts = np.array([p[0] for p in profiles])
    which = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(profiles) - 1)
    # Samples after a zero-length segment's start belong to the next one with time.
    for si, (t0, _dur, prof, _a, b) in enumerate(profiles):
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

"""A verified joint trajectory as a robot program: URScript (Universal Robots) and a joint CSV.

The twin verifies each process path as joint references every 1 ms (:mod:`twin.replay`). A UR
controller takes streamed joint targets with ``servoj`` at its own period, 2 ms on the
e-Series (:data:`SERVO_PERIOD_S`): the script holds every second reference, each as
``servoj(q, t=0.002, lookahead_time, gain)``, preceded by a ``movej`` to the first one (the
approach from wherever the robot stands, which the twin does not verify) and followed by
``stopj``. Joint angles are written in radians with 9 decimals (1 nrad: under 1 nm at the
tool). Before writing, the trajectory is checked against the arm's joint ranges and speed
limits; a trajectory past them is refused, not written.

:func:`read_urscript` reads such a script back (the ``servoj`` targets and their period) and
:func:`servo_trajectory` turns them into 1 ms references as a servo following them does (a
cubic spline through the targets, its derivative as the velocity feed-forward), to replay in
the twin.
"""

from __future__ import annotations

import re

import numpy as np
from scipy.interpolate import CubicSpline

from algorithms.paths.timing import Trajectory
from twin.errors import TwinError

#: The e-Series controller's period, the ``t`` of every ``servoj`` [s].
SERVO_PERIOD_S = 0.002
#: ``servoj``'s look-ahead [s] and gain: UR's defaults for smooth streamed paths.
LOOKAHEAD_S = 0.1
GAIN = 300
#: The ``movej`` to the first target: joint acceleration [rad/s^2] and speed [rad/s].
APPROACH_ACCELERATION = 0.5
APPROACH_SPEED = 0.2
JOINT_DECIMALS = 9

_SERVOJ = re.compile(r"^\s*servoj\(\[([^\]]*)\]\s*,\s*t\s*=\s*([0-9.eE+-]+)")
_DEF = re.compile(r"^\s*def\s+([A-Za-z_][A-Za-z0-9_]*)\s*\(\s*\)\s*:")


def _q(q: np.ndarray) -> str:
    return "[" + ", ".join(f"{x:.{JOINT_DECIMALS}f}" for x in q) + "]"


def check_limits(traj: Trajectory, q_lo: np.ndarray, q_hi: np.ndarray, name: str) -> None:
    """Refuse a trajectory outside the joint ranges or faster than the arm's speed limits.

    Raises:
        TwinError: naming the joint, the time and the value.
    """
    below, above = traj.q < q_lo, traj.q > q_hi
    if below.any() or above.any():
        k, j = np.argwhere(below | above)[0]
        raise TwinError(f"{name}: joint {j + 1} at t = {traj.t[k]:.3f} s is {traj.q[k, j]:.4f} rad, outside its "
                        f"range [{q_lo[j]:.4f}, {q_hi[j]:.4f}]: not written as a robot program")
    if traj.velocity_ratio > 1.0:
        raise TwinError(f"{name}: the trajectory reaches {traj.velocity_ratio:.2f} times a joint's speed limit: "
                        "not written as a robot program")


def write_urscript(name: str, traj: Trajectory, q_lo: np.ndarray, q_hi: np.ndarray, note: str = "") -> str:
    """The URScript program of ``traj`` (see the module docstring); ``name`` is its function's name."""
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
        raise TwinError(f"URScript function name {name!r} must be letters, digits and underscores")
    check_limits(traj, q_lo, q_hi, name)
    step = round(SERVO_PERIOD_S / traj.dt)
    if step < 1 or abs(step * traj.dt - SERVO_PERIOD_S) > 1e-12:
        raise TwinError(f"{name}: the trajectory's step {traj.dt} s does not divide the servo period "
                        f"{SERVO_PERIOD_S} s")
    idx = np.arange(0, len(traj.t), step)
    if idx[-1] != len(traj.t) - 1:
        idx = np.append(idx, len(traj.t) - 1)  # the last reference too (held for one period)
    lines = [f"# {name}: {len(idx)} joint targets, every {SERVO_PERIOD_S * 1e3:g} ms, "
             f"{traj.t[-1] - traj.t[0]:.3f} s; joints [rad] base, shoulder, elbow, wrist 1, wrist 2, wrist 3",
             "# written from the trajectory the twin replayed and verified at 1 ms"
             + (f" ({note})" if note else ""),
             "# the movej to the first target starts from wherever the robot stands: not verified by the twin",
             f"def {name}():",
             f"  movej({_q(traj.q[0])}, a={APPROACH_ACCELERATION}, v={APPROACH_SPEED})"]
    lines += [f"  servoj({_q(traj.q[k])}, t={SERVO_PERIOD_S}, lookahead_time={LOOKAHEAD_S}, gain={GAIN})"
              for k in idx[1:]]
    lines += ["  stopj(2.0)", "end", f"{name}()"]
    return "\n".join(lines) + "\n"


def write_joint_csv(traj: Trajectory) -> str:
    """The trajectory's 1 ms references as CSV: t_s, q1_rad ... q6_rad, qd1_rad_s ... qd6_rad_s."""
    head = ["t_s", *(f"q{j}_rad" for j in range(1, 7)), *(f"qd{j}_rad_s" for j in range(1, 7))]
    rows = np.column_stack([traj.t, traj.q, traj.qd])
    return ",".join(head) + "\n" + "\n".join(",".join(f"{x:.9f}" for x in r) for r in rows) + "\n"


def read_urscript(text: str, source: str = "script") -> tuple[str, float, np.ndarray]:
    """The function name, the servo period [s] and the (N, 6) joint targets [rad] of a script
    this module wrote (its ``movej`` target first, then every ``servoj``'s).

    Raises:
        TwinError: no ``def``, no ``servoj``, targets that are not six numbers, or periods that differ.
    """
    name = None
    first = None
    targets: list[list[float]] = []
    periods: set[float] = set()
    for number, line in enumerate(text.splitlines(), start=1):
        if name is None and (m := _DEF.match(line)):
            name = m.group(1)
        if first is None and line.strip().startswith("movej(["):
            first = line.strip()[len("movej(["):].split("]")[0]
        if m := _SERVOJ.match(line):
            try:
                q = [float(x) for x in m.group(1).split(",")]
                periods.add(float(m.group(2)))
            except ValueError:
                raise TwinError(f"{source}:{number}: servoj's joints are not numbers") from None
            if len(q) != 6 or not np.all(np.isfinite(q)):
                raise TwinError(f"{source}:{number}: servoj takes six finite joint angles, got {len(q)}")
            targets.append(q)
    if name is None or first is None or not targets:
        raise TwinError(f"{source}: not a servoj program (a def, a movej to the first target and servoj lines)")
    if len(periods) != 1:
        raise TwinError(f"{source}: the servoj periods differ ({sorted(periods)}): one period is read")
    q0 = [float(x) for x in first.split(",")]
    return name, periods.pop(), np.array([q0, *targets])


def servo_trajectory(period_s: float, q_targets: np.ndarray, dt: float = 0.001) -> tuple[np.ndarray, np.ndarray,
                                                                                       np.ndarray]:
    """1 ms references through the targets: (t, q, qd), a cubic spline through them and its
    derivative (the velocity feed-forward), the last target included."""
    t_targets = period_s * np.arange(len(q_targets))
    spline = CubicSpline(t_targets, q_targets, axis=0, bc_type="clamped")
    t = np.arange(0.0, t_targets[-1] + dt / 2, dt)
    return t, spline(t), spline(t, 1)

"""Serial-arm forward kinematics (Denavit-Hartenberg), the closed-form inverse kinematics of
UR-geometry arms, and document 004's point mapping.

Pure numpy, vectorised over samples, so it runs on joint logs from a real robot.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from algorithms.arraytypes import ArrayLike, BoolArray, FloatArray
from algorithms.errors import AlgorithmError
from algorithms.geometry.se3 import as_pose


@dataclass(frozen=True)
class DHTable:
    """Standard Denavit-Hartenberg parameters of a six-axis arm.

    Link i transform: ``Rz(q_i + theta_offset_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``.

    Attributes:
        a: (6,) link lengths [m].
        d: (6,) link offsets [m].
        alpha: (6,) link twists [rad].
        theta_offset: (6,) joint zero offsets [rad].
    """

    a: tuple[float, ...]
    d: tuple[float, ...]
    alpha: tuple[float, ...]
    theta_offset: tuple[float, ...] = (0.0,) * 6


def dh_forward(q: ArrayLike, dh: DHTable) -> FloatArray:
    """Flange poses ``T_base_flange`` for many joint vectors.

    Args:
        q: (N, 6) or (6,) joint angles [rad].
        dh: the arm's DH table.

    Returns:
        (N, 4, 4) or (4, 4) poses of the flange (DH frame 6) in the base frame.
    """
    q = np.asarray(q, dtype=np.float64)
    single = q.ndim == 1
    q = np.atleast_2d(q)
    if q.shape[1] != len(dh.a):
        raise AlgorithmError(f"q must have {len(dh.a)} columns, got shape {q.shape}")
    n = q.shape[0]
    T = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    for i in range(len(dh.a)):
        th = q[:, i] + dh.theta_offset[i]
        ct, st = np.cos(th), np.sin(th)
        ca, sa = np.cos(dh.alpha[i]), np.sin(dh.alpha[i])
        A = np.zeros((n, 4, 4))
        A[:, 0, 0] = ct
        A[:, 0, 1] = -st * ca
        A[:, 0, 2] = st * sa
        A[:, 0, 3] = dh.a[i] * ct
        A[:, 1, 0] = st
        A[:, 1, 1] = ct * ca
        A[:, 1, 2] = -ct * sa
        A[:, 1, 3] = dh.a[i] * st
        A[:, 2, 1] = sa
        A[:, 2, 2] = ca
        A[:, 2, 3] = dh.d[i]
        A[:, 3, 3] = 1.0
        T = T @ A
    return T[0] if single else T


def reconstruct_points(q: ArrayLike, d: ArrayLike, dh: DHTable, T_flange_sensor: ArrayLike) -> FloatArray:
    """Document 004's eq. (2): ``p_base = T_base_flange(q) @ T_flange_sensor @ [0, 0, d, 1]``.

    Args:
        q: (N, 6) joint readings [rad], paired with ``d`` sample by sample.
        d: (N,) distances along the sensor's +z [m]; NaN for invalid samples.
        dh: the believed (nominal) kinematics.
        T_flange_sensor: (4, 4) the believed hand-eye transform.

    Returns:
        (N, 3) points in the robot base frame [m]; NaN rows where ``d`` is NaN.
    """
    d = np.asarray(d, dtype=np.float64)
    q = np.atleast_2d(np.asarray(q, dtype=np.float64))
    if d.ndim != 1 or q.shape[0] != d.shape[0]:
        raise AlgorithmError(f"q (N, 6) and d (N,) must pair sample by sample, got {q.shape} and {d.shape}")
    T_fs = as_pose(T_flange_sensor, "T_flange_sensor")
    T_base_sensor = dh_forward(q, dh) @ T_fs
    return T_base_sensor[:, :3, 3] + T_base_sensor[:, :3, 2] * d[:, None]


def reconstruct_line_points(q: ArrayLike, d: ArrayLike, beam_dirs_sensor: ArrayLike, dh: DHTable,
                            T_flange_sensor: ArrayLike) -> FloatArray:
    """Eq. (2) for a line profiler: ``p = T_base_flange(q) T_flange_sensor [d_b u_b, 1]`` per beam b.

    Args:
        q: (N, 6) joint readings [rad], one per profile.
        d: (N, B) distances along each beam [m]; NaN where invalid.
        beam_dirs_sensor: (B, 3) unit beam directions in the sensor frame.
        dh: the believed (nominal) kinematics.
        T_flange_sensor: (4, 4) the believed hand-eye transform.

    Returns:
        (N, B, 3) points in the robot base frame [m]; NaN where ``d`` is NaN.
    """
    d = np.asarray(d, dtype=np.float64)
    u = np.asarray(beam_dirs_sensor, dtype=np.float64)
    q = np.atleast_2d(np.asarray(q, dtype=np.float64))
    if d.ndim != 2 or d.shape[0] != q.shape[0] or u.shape != (d.shape[1], 3):
        raise AlgorithmError(
            f"q (N, 6), d (N, B) and beam_dirs_sensor (B, 3) must agree, got {q.shape}, {d.shape}, {u.shape}")
    T = dh_forward(q, dh) @ as_pose(T_flange_sensor, "T_flange_sensor")
    local = d[:, :, None] * u[None, :, :]
    # R p for every beam of a profile: a batched matrix product, faster than einsum here
    out = np.matmul(local, T[:, :3, :3].transpose(0, 2, 1))
    out += T[:, None, :3, 3]
    return out


#: Branch bits of :func:`ur_inverse`: branch ``b`` takes the shoulder solution ``b >> 2 & 1``,
#: the wrist solution ``b >> 1 & 1`` and the elbow solution ``b & 1`` (0: the ``+`` root).
UR_BRANCHES = 8


@dataclass(frozen=True)
class URInverse:
    """The eight closed-form solutions of a UR-geometry arm for N flange poses.

    Attributes:
        q: (N, 8, 6) joint angles [rad] in (-pi, pi], one row per branch (see ``UR_BRANCHES``);
            NaN where the branch has no solution.
        valid: (N, 8) bool, the branch has a solution.
        wrist_sin: (N, 8) |sin q5|: 0 at the wrist singularity (axes 4 and 6 aligned).
        elbow_sin: (N, 8) |sin q3|: 0 with the arm stretched or folded.
        shoulder_m: (N,) distance of the wrist centre from the shoulder-singular cylinder
            [m]: 0 where the wrist centre lies on the cylinder of radius d4 about the base z
            axis (the two shoulder solutions meet).
    """

    q: FloatArray
    valid: BoolArray
    wrist_sin: FloatArray
    elbow_sin: FloatArray
    shoulder_m: FloatArray


def _check_ur_geometry(dh: DHTable) -> None:
    a, d, alpha = np.asarray(dh.a), np.asarray(dh.d), np.asarray(dh.alpha)
    ok = (len(a) == 6 and a[0] == 0 and a[3] == 0 and a[4] == 0 and a[5] == 0 and d[1] == 0 and d[2] == 0
          and np.allclose(alpha, (np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0), atol=1e-12)
          and np.all(np.asarray(dh.theta_offset) == 0))
    if not ok:
        raise AlgorithmError("ur_inverse needs the UR geometry: a = (0, a2, a3, 0, 0, 0), d2 = d3 = 0, "
                             "alpha = (pi/2, 0, 0, pi/2, -pi/2, 0), no joint offsets")


def wrap_angle(angle: FloatArray) -> FloatArray:
    """Angles wrapped to (-pi, pi]."""
    return np.pi - np.mod(np.pi - angle, 2 * np.pi)


def ur_inverse(T_base_flange: ArrayLike, dh: DHTable, branches: Iterable[int] | None = None) -> URInverse:
    """Closed-form inverse kinematics of a UR-geometry arm (three parallel middle axes, a
    spherical-like wrist offset by d4, d5, d6): all eight solutions of every pose.

    q1 from the wrist centre ``p05 = p - d6 z6`` (its coordinate along z1 must equal d4);
    q5 and q6 from the flange orientation seen in frame 1 (``R16 = Rz(q2+q3+q4) Ry(-q5)
    Rz(q6)``); q2 and q3 from the planar two-link problem for the origin of frame 3;
    q4 from what is left. Where the wrist is singular (sin q5 = 0) q6 is set to 0 (any q6
    with the matching q4 is a solution).

    Args:
        T_base_flange: (N, 4, 4) or (4, 4) flange poses (DH frame 6) in the base frame.
        dh: the arm's DH table (UR geometry; checked).
        branches: the branches to solve (default all eight); the others come back invalid.

    Returns:
        URInverse with (N, ...) arrays (N = 1 for a single pose).
    """
    _check_ur_geometry(dh)
    wanted = _check_branches(branches)
    T = np.asarray(T_base_flange, dtype=np.float64)
    if T.shape[-2:] != (4, 4):
        raise AlgorithmError(f"T_base_flange must be (N, 4, 4) or (4, 4), got {T.shape}")
    T = T.reshape(-1, 4, 4)
    shoulder = _shoulder(T, dh)
    out = URInverse(q=np.full((len(T), UR_BRANCHES, 6), np.nan), valid=np.zeros((len(T), UR_BRANCHES), dtype=bool),
                    wrist_sin=np.zeros((len(T), UR_BRANCHES)), elbow_sin=np.zeros((len(T), UR_BRANCHES)),
                    shoulder_m=shoulder.distance_m)
    for i1, s1_sign in enumerate((1.0, -1.0)):
        if not any(b >> 2 == i1 for b in wanted):
            continue
        q1 = shoulder.psi + np.pi / 2 + s1_sign * shoulder.phi
        R16, p16 = _in_frame1(T, q1, dh.d[0])
        c5 = np.clip(R16[:, 2, 2], -1.0, 1.0)
        for i5, s5_sign in enumerate((1.0, -1.0)):
            if not any(b >> 1 == 2 * i1 + i5 for b in wanted):
                continue
            wrist = _wrist(R16, p16, s5_sign * np.arccos(c5), dh)
            # the elbow: the cosine law of the two-link problem (a2, a3) reaching (x3, y3)
            c3 = (wrist.x3**2 + wrist.y3**2 - dh.a[1] ** 2 - dh.a[2] ** 2) / (2 * dh.a[1] * dh.a[2])
            ok = shoulder.reachable & (np.abs(c3) <= 1.0)
            for i3, s3_sign in enumerate((1.0, -1.0)):
                b = 4 * i1 + 2 * i5 + i3
                if b in wanted:
                    _store_branch(out, b, ok, q1, wrist, s3_sign * np.arccos(np.clip(c3, -1.0, 1.0)), dh)
    return out


def ur_branch(q: ArrayLike, dh: DHTable) -> int:
    """The :func:`ur_inverse` branch a configuration lies on: the branch whose solution of its
    own flange pose is nearest it (angles compared modulo 2 pi)."""
    q = np.asarray(q, dtype=np.float64)
    sol = ur_inverse(dh_forward(q, dh), dh)
    dq = np.abs(wrap_angle(sol.q[0] - q))
    return int(np.nanargmin(np.where(sol.valid[0], np.nanmax(dq, axis=1), np.inf)))


def _check_branches(branches: Iterable[int] | None) -> set[int]:
    wanted = set(range(UR_BRANCHES)) if branches is None else {int(b) for b in branches}
    if not wanted <= set(range(UR_BRANCHES)):
        raise AlgorithmError(f"branches must lie in 0..{UR_BRANCHES - 1}, got {sorted(wanted)}")
    return wanted


@dataclass(frozen=True)
class _Shoulder:
    """The wrist centre ``p05`` seen from the base z axis, for q1 = psi + pi/2 +- phi.

    Attributes:
        psi: (N,) azimuth of the wrist centre [rad].
        phi: (N,) ``arccos(d4 / rho)`` with rho its distance from the base z axis [rad].
        reachable: (N,) rho >= d4 (the shoulder has a solution).
        distance_m: (N,) ``sqrt(rho^2 - d4^2)``, 0 on the shoulder-singular cylinder [m].
    """

    psi: FloatArray
    phi: FloatArray
    reachable: BoolArray
    distance_m: FloatArray


def _shoulder(T: FloatArray, dh: DHTable) -> _Shoulder:
    d4, d6 = dh.d[3], dh.d[5]
    R, p = T[:, :3, :3], T[:, :3, 3]
    p05 = p - d6 * R[:, :, 2]
    rho = np.hypot(p05[:, 0], p05[:, 1])
    return _Shoulder(psi=np.arctan2(p05[:, 1], p05[:, 0]),
                     phi=np.arccos(np.clip(d4 / np.maximum(rho, 1e-300), -1.0, 1.0)),
                     reachable=rho >= d4, distance_m=np.sqrt(np.maximum(rho**2 - d4**2, 0.0)))


def _in_frame1(T: FloatArray, q1: FloatArray, d1: float) -> tuple[FloatArray, FloatArray]:
    """The flange orientation R16 (N, 3, 3) and position p16 (N, 3) [m] in DH frame 1."""
    n = len(T)
    c1, s1 = np.cos(q1), np.sin(q1)
    # R01 = Rz(q1) Rx(pi/2): its columns x1, y1, z1 in the base frame.
    x1 = np.column_stack([c1, s1, np.zeros(n)])
    y1 = np.column_stack([np.zeros(n), np.zeros(n), np.ones(n)])
    z1 = np.column_stack([s1, -c1, np.zeros(n)])
    R01 = np.stack([x1, y1, z1], axis=2)
    R16 = np.einsum("nji,njk->nik", R01, T[:, :3, :3])
    p16 = np.einsum("nji,nj->ni", R01, T[:, :3, 3] - np.array([0.0, 0.0, d1]))
    return R16, p16


@dataclass(frozen=True)
class _Wrist:
    """One wrist solution (N,) each: q5, sin q5, q6, q2 + q3 + q4 [rad], and the origin
    (x3, y3) [m] of frame 3 in frame 1 that the arm's two-link problem must reach."""

    q5: FloatArray
    s5: FloatArray
    q6: FloatArray
    q234: FloatArray
    x3: FloatArray
    y3: FloatArray


def _wrist(R16: FloatArray, p16: FloatArray, q5: FloatArray, dh: DHTable) -> _Wrist:
    """q6 and q234 from ``R16 = Rz(q234) Ry(-q5) Rz(q6)``, then the origin of frame 3."""
    n = len(q5)
    d5, d6 = dh.d[4], dh.d[5]
    s5 = np.sin(q5)
    singular = np.abs(s5) < 1e-12
    safe = np.where(singular, 1.0, s5)
    q6 = np.where(singular, 0.0, np.arctan2(-R16[:, 2, 1] / safe, R16[:, 2, 0] / safe))
    # q234 from R16 = Rz(q234) Ry(-q5) Rz(q6): Rz(q234) = R16 Rz(-q6) Ry(q5).
    c6, s6 = np.cos(q6), np.sin(q6)
    M = R16 @ np.stack([np.stack([c6, s6, np.zeros(n)], 1), np.stack([-s6, c6, np.zeros(n)], 1),
                        np.stack([np.zeros(n), np.zeros(n), np.ones(n)], 1)], 1)
    c5_, s5_ = np.cos(q5), np.sin(q5)
    Ry = np.stack([np.stack([c5_, np.zeros(n), s5_], 1), np.stack([np.zeros(n), np.ones(n), np.zeros(n)], 1),
                   np.stack([-s5_, np.zeros(n), c5_], 1)], 1)
    Rz234 = M @ Ry
    q234 = np.arctan2(Rz234[:, 1, 0], Rz234[:, 0, 0])
    # Origin of frame 3 in frame 1: the flange position less the wrist offsets d5, d6
    # and d4 (along z1), all known now.
    s234, c234 = np.sin(q234), np.cos(q234)
    z5_1 = np.column_stack([-c234 * s5_, -s234 * s5_, c5_])  # Rz(q234) Ry(-q5) e_z
    z4_1 = np.column_stack([s234, -c234, np.zeros(n)])     # Rz(q234) Rx(pi/2) e_z
    p14 = p16 - d6 * z5_1 - d5 * z4_1                       # z6 = z5 (alpha6 = 0)
    # frame 3's origin = frame 4's origin less d4 along z1
    return _Wrist(q5=q5, s5=s5, q6=q6, q234=q234, x3=p14[:, 0], y3=p14[:, 1])


def _store_branch(out: URInverse, b: int, ok: BoolArray, q1: FloatArray, wrist: _Wrist, q3: FloatArray,
                  dh: DHTable) -> None:
    """q2 from the two-link problem with elbow angle q3, q4 from what is left; branch ``b`` of ``out``."""
    a2, a3 = dh.a[1], dh.a[2]
    q2 = np.arctan2(wrist.y3, wrist.x3) - np.arctan2(a3 * np.sin(q3), a2 + a3 * np.cos(q3))
    q4 = wrist.q234 - q2 - q3
    sol = np.column_stack([q1, q2, q3, q4, wrist.q5, wrist.q6])
    out.q[:, b] = np.where(ok[:, None], wrap_angle(sol), np.nan)
    out.valid[:, b] = ok
    out.wrist_sin[:, b] = np.abs(wrist.s5)
    out.elbow_sin[:, b] = np.abs(np.sin(q3))

"""Serial-arm forward kinematics (Denavit-Hartenberg) and document 004's point mapping.

Pure numpy, vectorised over samples, so it runs on joint logs from a real robot.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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


def dh_forward(q, dh: DHTable) -> np.ndarray:
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


def reconstruct_points(q, d, dh: DHTable, T_flange_sensor) -> np.ndarray:
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


def reconstruct_line_points(q, d, beam_dirs_sensor, dh: DHTable, T_flange_sensor) -> np.ndarray:
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
    return np.einsum("nij,nbj->nbi", T[:, :3, :3], local) + T[:, None, :3, 3]

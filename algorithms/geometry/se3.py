"""SE(3) helpers: rigid checks, exponential map, pose error metrics.

Poses are (4, 4) float64 homogeneous matrices; ``T_a_b`` maps coordinates in frame b
into frame a. Twists are 6-vectors ``[omega, v]`` (angular part first) in radians and metres.
"""

from __future__ import annotations

import math

import numpy as np

from algorithms.arraytypes import ArrayLike, FloatArray, Pose
from algorithms.errors import AlgorithmError

RIGID_TOL = 1e-6


def as_pose(T: ArrayLike, name: str = "pose", tol: float = RIGID_TOL) -> Pose:
    """Return ``T`` as a (4, 4) float64 rigid transform or raise ``AlgorithmError``.

    Rigid means: last row [0, 0, 0, 1], rotation block orthonormal within ``tol`` and det = +1.
    """
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise AlgorithmError(f"{name} must be a 4x4 matrix, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise AlgorithmError(f"{name} contains NaN or infinite entries")
    if np.max(np.abs(T[3] - [0.0, 0.0, 0.0, 1.0])) > tol:
        raise AlgorithmError(f"{name} last row must be [0, 0, 0, 1], got {T[3].tolist()}")
    R = T[:3, :3]
    ortho = np.max(np.abs(R.T @ R - np.eye(3)))
    if ortho > tol:
        raise AlgorithmError(
            f"{name} rotation is not orthonormal (max |R^T R - I| = {ortho:.3g} > {tol:g})"
        )
    if np.linalg.det(R) < 0:
        raise AlgorithmError(f"{name} rotation is a reflection (det = -1); a proper rotation is required")
    return T


def make_pose(R: ArrayLike | None = None, p: ArrayLike | None = None) -> Pose:
    """Build a (4, 4) pose from a (3, 3) rotation and a (3,) translation [m]."""
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    if p is not None:
        T[:3, 3] = p
    return T


def inv_pose(T: Pose) -> Pose:
    """Inverse of a rigid transform, without a general matrix inverse."""
    R = T[:3, :3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ T[:3, 3]
    return out


def hat(w: FloatArray) -> FloatArray:
    """Skew-symmetric matrix of a 3-vector: ``hat(w) @ x == cross(w, x)``."""
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def exp_se3(xi: ArrayLike) -> Pose:
    """Exponential map of a twist ``[omega, v]`` to a (4, 4) pose."""
    xi = np.asarray(xi, dtype=np.float64)
    w, v = xi[:3], xi[3:]
    theta = np.linalg.norm(w)
    W = hat(w)
    if theta < 1e-9:
        R = np.eye(3) + W + 0.5 * W @ W
        V = np.eye(3) + 0.5 * W + W @ W / 6.0
    else:
        a = np.sin(theta) / theta
        b = (1.0 - np.cos(theta)) / theta**2
        c = (theta - np.sin(theta)) / theta**3
        R = np.eye(3) + a * W + b * W @ W
        V = np.eye(3) + b * W + c * W @ W
    return make_pose(R, V @ v)


def rotation_vector(R: FloatArray) -> FloatArray:
    """The rotation vector (axis times angle in [0, pi], radians) of a rotation matrix.

    The algorithm of scipy's ``Rotation.from_matrix(R).as_rotvec()`` (the unit quaternion from
    the largest of the trace and the diagonal, Markley's method; the angle from ``atan2``; a
    series below 1e-3 rad), written out so that a local fit does not load ``scipy.spatial``
    (0.27 s of ``twin localize``'s imports under ``python -X importtime``).
    """
    R = np.asarray(R, dtype=np.float64)
    trace = R[0, 0] + R[1, 1] + R[2, 2]
    i = int(np.argmax([R[0, 0], R[1, 1], R[2, 2], trace]))
    q = np.empty(4)  # x, y, z, w
    if i == 3:
        q[:] = R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1], 1.0 + trace
    else:
        j, k = (i + 1) % 3, (i + 2) % 3
        q[i] = 1.0 - trace + 2.0 * R[i, i]
        q[j] = R[j, i] + R[i, j]
        q[k] = R[k, i] + R[i, k]
        q[3] = R[k, j] - R[j, k]
    q /= np.linalg.norm(q)
    if q[3] < 0:
        q = -q
    angle = 2.0 * math.atan2(float(np.linalg.norm(q[:3])), float(q[3]))
    scale = angle / math.sin(0.5 * angle) if angle > 1e-3 else 2.0 + angle**2 / 12.0 + 7.0 * angle**4 / 2880.0
    return scale * q[:3]


def log_se3(T: Pose) -> FloatArray:
    """Logarithm of a pose: the twist ``[omega, v]`` with ``exp_se3(xi) == T``."""
    w = rotation_vector(T[:3, :3])
    theta = np.linalg.norm(w)
    W = hat(w)
    if theta < 1e-9:
        V_inv = np.eye(3) - 0.5 * W + W @ W / 12.0
    else:
        half = 0.5 * theta
        V_inv = np.eye(3) - 0.5 * W + (1.0 - half / np.tan(half)) / theta**2 * (W @ W)
    return np.concatenate([w, V_inv @ T[:3, 3]])


def rotation_error_rad(T_est: Pose, T_true: Pose) -> float:
    """Document 000's rotation error: the angle of ``R_est^T R_true`` [rad]."""
    R = T_est[:3, :3].T @ T_true[:3, :3]
    return float(np.linalg.norm(rotation_vector(R)))


def translation_error_m(T_est: Pose, T_true: Pose) -> float:
    """Document 000's translation error: distance between the two origins [m]."""
    return float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3]))


def transform_points(T: Pose, points: FloatArray) -> FloatArray:
    """Points (N, 3) [m] in frame b mapped by ``T = T_a_b`` into frame a."""
    return points @ T[:3, :3].T + T[:3, 3]

"""Length along a sequence of poses: position arc length plus a length per radian turned.

One definition for every stage that needs a path parameter (tool paths, IK step times,
the time law): ``ds_k = |p_(k+1) - p_k| + rotation_length_m_per_rad * angle(R_k^T R_(k+1))``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from algorithms.arraytypes import FloatArray

# Rotation-only moves count this many metres per radian when a length is needed.
ROTATION_LENGTH_M_PER_RAD = 0.1


def step_lengths(T: FloatArray, rotation_length_m_per_rad: float = ROTATION_LENGTH_M_PER_RAD) -> FloatArray:
    """(K-1,) [m] length of each step of a (K, 4, 4) pose sequence (see the module docstring)."""
    dp = np.linalg.norm(np.diff(T[:, :3, 3], axis=0), axis=1)
    if len(T) < 2:
        return dp
    return dp + rotation_length_m_per_rad * step_angles(T)


def step_angles(T: FloatArray) -> FloatArray:
    """(K-1,) [rad] rotation angle between consecutive poses of a (K, 4, 4) sequence."""
    rel = np.einsum("nji,njk->nik", T[:-1, :3, :3], T[1:, :3, :3])
    return np.linalg.norm(Rotation.from_matrix(rel).as_rotvec(), axis=1)


def cumulative_length(T: FloatArray, rotation_length_m_per_rad: float = ROTATION_LENGTH_M_PER_RAD) -> FloatArray:
    """(K,) [m] path parameter from 0 at the first pose (see :func:`step_lengths`)."""
    return np.concatenate([[0.0], np.cumsum(step_lengths(T, rotation_length_m_per_rad))])

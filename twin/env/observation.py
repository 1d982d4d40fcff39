"""What an active-localization agent observes: a ``Dict`` of float32 arrays, each bounded.

Every component is scale-free and in a fixed order, so one policy can read episodes of any
part, tolerance and placement scatter:

=============  =====  ==========  ===========================================================
 key           size   bounds      meaning
=============  =====  ==========  ===========================================================
 pose          6      [-1, 1]     the estimate relative to the nominal pose: ``tanh(xi / (3
                                  sigma_prior))`` per component of the twist ``xi = log(T_nom^-1
                                  T_est)`` ``[omega, v]`` (workpiece frame)
 std           6      [-1, 1]     each pose component's posterior standard deviation between
                                  the tolerance and the prior, ``log(std / tol) / log(prior /
                                  tol)`` clipped: 1 at the prior, 0 at the tolerance
 correlation   15     [-1, 1]     the posterior correlation matrix's upper triangle (row by
                                  row, ``[omega_x, omega_y, omega_z, v_x, v_y, v_z]``): with
                                  ``std``, the whole covariance, so which directions are weak
 worst_std     2      [-1, 1]     the stopping rule's worst rotation and translation standard
                                  deviations (the shape's free directions excepted), scaled as
                                  ``std``: the episode succeeds once both are <= 0
 coverage      14     [0, 1]      for each of ``NORMAL_BINS`` (directions in the workpiece
                                  frame), how many fitted points have their surface normal
                                  nearest it: ``1 - exp(-n / COVERAGE_POINTS)``
 surface       14     [0, 1]      the share of the part's area whose normal is nearest each bin
                                  (fixed per part: which surfaces there are to see)
 joints        6      [-1, 1]     the arm's joint positions, mapped linearly from the joints'
                                  ranges
 progress      3      [0, 1]      steps left over the budget; ``tanh`` of the last step's
                                  information gain over ``GAIN_SCALE_NATS`` (clipped at 0);
                                  ``log(1 + points) / log(1 + most points)``
=============  =====  ==========  ===========================================================

``gymnasium.wrappers.FlattenObservation`` (or :func:`flat`) turns it into one vector of 66
values, the keys in alphabetical order (gymnasium's ``Dict`` sorts them).
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces

#: The observation's components in order, with their sizes and bounds.
OBSERVATION_KEYS = {"pose": (6, -1.0), "std": (6, -1.0), "correlation": (15, -1.0), "worst_std": (2, -1.0),
                    "coverage": (14, 0.0), "surface": (14, 0.0), "joints": (6, -1.0), "progress": (3, 0.0)}
#: Directions of the surface normals the coverage is counted over (workpiece frame): the six
#: axes and the eight diagonals of a cube.
NORMAL_BINS = np.vstack([np.eye(3), -np.eye(3),
                         np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) / np.sqrt(3)])
#: Points of one normal bin at which its coverage reaches 1 - 1/e.
COVERAGE_POINTS = 30.0
#: An information gain [nats] at which the observed last gain reaches tanh(1).
GAIN_SCALE_NATS = 10.0
#: The pose is observed in units of this many prior standard deviations (through tanh).
POSE_SIGMAS = 3.0
_UPPER = np.triu_indices(6, 1)


def observation_space() -> spaces.Dict:
    """The ``Dict`` space of :data:`OBSERVATION_KEYS` (float32 boxes)."""
    return spaces.Dict({k: spaces.Box(np.float32(low), np.float32(1.0), (n,), dtype=np.float32)
                        for k, (n, low) in OBSERVATION_KEYS.items()})


def normal_bins(normals: np.ndarray) -> np.ndarray:
    """(M,) the index of the :data:`NORMAL_BINS` direction nearest each unit normal (M, 3)."""
    return np.argmax(np.asarray(normals, dtype=np.float64).reshape(-1, 3) @ NORMAL_BINS.T, axis=1)


def surface_shares(face_normals: np.ndarray, face_areas: np.ndarray) -> np.ndarray:
    """(14,) the share of the area whose normal is nearest each bin (sums to 1)."""
    share = np.bincount(normal_bins(face_normals), weights=face_areas, minlength=len(NORMAL_BINS))
    return share / max(float(share.sum()), 1e-300)


def coverage(counts: np.ndarray) -> np.ndarray:
    """(14,) the observed coverage of bins with ``counts`` fitted points each."""
    return 1.0 - np.exp(-np.asarray(counts, dtype=np.float64) / COVERAGE_POINTS)


def scaled_std(std: np.ndarray, prior: np.ndarray, tolerance: np.ndarray) -> np.ndarray:
    """``log(std / tol) / log(prior / tol)`` clipped to [-1, 1] (1 at the prior, 0 at the
    tolerance), elementwise."""
    std, prior, tolerance = (np.asarray(x, dtype=np.float64) for x in (std, prior, tolerance))
    return np.clip(np.log(np.maximum(std, 1e-300) / tolerance) / np.log(prior / tolerance), -1.0, 1.0)


def covariance_features(C: np.ndarray, prior_std: np.ndarray, tolerance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(``std`` (6,), ``correlation`` (15,)) of a pose covariance ``C`` (6, 6) [rad, m]."""
    std = np.sqrt(np.maximum(np.diag(C), 0.0))
    corr = C / np.outer(np.maximum(std, 1e-300), np.maximum(std, 1e-300))
    return scaled_std(std, prior_std, tolerance), np.clip(corr[_UPPER], -1.0, 1.0)


def scaled_joints(q: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """Joint positions mapped linearly from [low, high] to [-1, 1] (clipped)."""
    return np.clip(2.0 * (np.asarray(q) - low) / (high - low) - 1.0, -1.0, 1.0)


def flat(observation: dict) -> np.ndarray:
    """(66,) the observation as one vector, as ``gymnasium.wrappers.FlattenObservation`` gives
    it (gymnasium's ``Dict`` orders its keys alphabetically)."""
    return np.concatenate([np.asarray(observation[k], dtype=np.float32).ravel() for k in sorted(OBSERVATION_KEYS)])


def as_float32(values: dict) -> dict:
    """The observation dictionary in :data:`OBSERVATION_KEYS` order, float32, clipped to its
    bounds (rounding to float32 must not step outside them)."""
    return {k: np.clip(np.asarray(values[k], dtype=np.float32), np.float32(low), np.float32(1.0))
            for k, (_, low) in OBSERVATION_KEYS.items()}

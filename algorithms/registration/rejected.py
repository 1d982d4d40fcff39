"""What the points a robust fit rejected would say about its pose, were they sound: the
information they would carry against the kept points' and whether they form a coherent patch
(:mod:`algorithms.registration.review` asks its questions with it; the global search's
first-start check, :mod:`.global_search.search`, too).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from algorithms.arraytypes import FloatArray, Pose
from algorithms.geometry.se3 import inv_pose, transform_points
from algorithms.registration.uncertainty import information_rows

if TYPE_CHECKING:
    from algorithms.geometry.mesh_index import MeshIndex

__all__ = ["LOAD_BEARING_INFORMATION", "PATCH_FRACTION", "PATCH_MIN_POINTS", "PATCH_SIMILARITY", "PATCH_SPACING",
           "RejectedInformation", "coherent_fraction", "rejected_information"]

#: An unconfirmed fit is not trusted when the rejected points would add at least this fraction.
LOAD_BEARING_INFORMATION = 0.25
#: A rejected set is a coherent patch when at least this fraction of its points has a rejected
#: neighbour (within ``PATCH_SPACING`` typical point spacings) whose distance to the model is
#: within ``PATCH_SIMILARITY`` of its own, and it holds at least ``PATCH_MIN_POINTS`` points
#: (benchmarks/results_verdicts.md: sound fits with spurious returns stay below, the fits of a
#: mirrored part that looked good lie above).
PATCH_FRACTION = 0.12
PATCH_SPACING = 3.0
PATCH_SIMILARITY = 0.2
PATCH_MIN_POINTS = 10


@dataclass(frozen=True)
class RejectedInformation:
    """What the rejected points would say about the pose, were they sound.

    Attributes:
        n_rejected: finite points the outlier rule rejected.
        ratio: ``max eig(I_K^-1 I_R)`` (0 when nothing was rejected; inf when the kept points
            leave a direction free that the rejected ones would fix).
        direction: (6,) the unit twist ``[omega, v]`` (workpiece frame, about its origin)
            where the ratio is largest; zeros when nothing was rejected.
        centroid_m: (3,) the rejected points' mean, workpiece frame [m] (NaN when none).
        coherent_fraction: the fraction of rejected points with a near rejected neighbour at
            a similar distance from the model (:func:`coherent_fraction`).
    """

    n_rejected: int
    ratio: float
    direction: FloatArray
    centroid_m: FloatArray
    coherent_fraction: float = 0.0

    @property
    def patch(self) -> bool:
        """The rejected points form a coherent patch (a surface the model lacks, not noise)."""
        return self.n_rejected >= PATCH_MIN_POINTS and self.coherent_fraction >= PATCH_FRACTION


def rejected_information(Y: FloatArray, kept: np.ndarray, T_world_workpiece: Pose,
                         index: MeshIndex) -> RejectedInformation:
    """The information ratio of the rejected points (module docstring, question 1).

    Args:
        Y: (M, 3) finite points, world frame [m].
        kept: (M,) bool, the fit's inliers among them.
        T_world_workpiece: the fit's pose.
        index: the model's mesh index.
    """
    rejected = ~kept
    m = int(rejected.sum())
    if m == 0:
        return RejectedInformation(0, 0.0, np.zeros(6), np.full(3, np.nan))
    X = transform_points(inv_pose(T_world_workpiece), Y)
    cp = index.query(X)
    signed = np.einsum("ij,ij->i", X - cp.foot, cp.normal)
    G = information_rows(cp.foot, cp.normal)
    I_kept, I_rejected = G[kept].T @ G[kept], G[rejected].T @ G[rejected]
    # generalized symmetric eigenproblem I_R u = lambda I_K u, by whitening with I_K's eigenbasis
    w, V = np.linalg.eigh(I_kept)
    if w[0] <= 1e-12 * max(w[-1], 1e-300):
        ratio, direction = np.inf, V[:, 0]
    else:
        W = V / np.sqrt(w)
        lam, U = np.linalg.eigh(W.T @ I_rejected @ W)
        ratio, direction = float(lam[-1]), W @ U[:, -1]
    return RejectedInformation(m, float(ratio), direction / np.linalg.norm(direction), X[rejected].mean(axis=0),
                               coherent_fraction(X, rejected, signed))


def coherent_fraction(X: FloatArray, rejected: np.ndarray, signed_m: FloatArray) -> float:
    """The fraction of rejected points whose nearest rejected neighbour lies within
    ``PATCH_SPACING`` typical spacings (the median nearest-neighbour distance of all points) and
    differs in signed distance to the model by at most ``PATCH_SIMILARITY`` of the larger one.

    Points of a surface the model lacks (a feature, a fixture, another part) sit side by side at
    similar distances; spurious returns and mixed pixels scatter in both.
    """
    if int(rejected.sum()) < 2:
        return 0.0
    from scipy.spatial import cKDTree  # here: only a review loads scipy.spatial

    spacing = float(np.median(cKDTree(X).query(X, k=2)[0][:, 1]))
    R, d = X[rejected], signed_m[rejected]
    dist, j = cKDTree(R).query(R, k=2)
    near = dist[:, 1] <= PATCH_SPACING * max(spacing, 1e-12)
    similar = np.abs(d - d[j[:, 1]]) <= PATCH_SIMILARITY * np.maximum(np.abs(d), np.abs(d[j[:, 1]]))
    return float(np.mean(near & similar))

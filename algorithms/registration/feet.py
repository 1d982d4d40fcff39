"""Closest points on the model ("feet") of the measured points under the trial poses of the
local iteration (:mod:`algorithms.registration.local`): approximate while the points are far
from the model, exact after, from near-face lists when the start is already close."""

from __future__ import annotations

import numpy as np

from algorithms.arraytypes import FloatArray, IntArray, Pose
from algorithms.geometry.mesh_index import ClosestPoints, MeshIndex, NearFaces
from algorithms.geometry.se3 import inv_pose

__all__ = ["Feet", "apply_pose"]

#: Below this many points ``P @ R.T`` is fastest (BLAS stays on one thread).
_BLAS_MAX_POINTS = 4096


def apply_pose(T: Pose, P: FloatArray) -> FloatArray:
    """T applied to (N, 3) points [m], without BLAS threads (see
    :func:`algorithms.registration.pose_updates.gram`): the same as se3.transform_points."""
    R = T[:3, :3]
    if len(P) < _BLAS_MAX_POINTS:
        return P @ R.T + T[:3, 3]
    out = np.empty_like(P)
    x, y, z = P[:, 0], P[:, 1], P[:, 2]
    for k in range(3):
        out[:, k] = R[k, 0] * x + R[k, 1] * y + R[k, 2] * z + T[k, 3]
    return out


class Feet:
    """Closest points of the points ``Y`` (N, 3) [m] (world frame) under trial poses.

    From the tree, with each point's previous face as the hint: to within ``far_rel_error`` of
    the distance while the points' RMS distance exceeds ``far_rms_rel`` median edge lengths (a far
    point needs no exact foot to point the way), exactly after. When the start is already close
    (``near_from_start``: all points after a subset has converged), from each point's list of
    nearest faces (:meth:`MeshIndex.query_near`, exact), a few point-triangle tests a point.
    The lists are not started in mid-iteration: building them costs about what the hinted tree
    queries they would replace cost over the last few iterations.
    """

    def __init__(self, index: MeshIndex, Y: FloatArray, far_rms_rel: float, far_rel_error: float,
                 near_from_start: bool = False):
        self.index = index
        self.Y = Y
        self.near: NearFaces | None = None
        self.near_from_start = near_from_start
        self.far_m2 = (far_rms_rel * index.face_size) ** 2
        self.far_rel_error = far_rel_error
        #: the next tree query may be approximate (the points are still far from the model)
        self.far = not near_from_start

    def __call__(self, T: Pose, hint: IntArray | None = None) -> tuple[ClosestPoints, FloatArray]:
        """(ClosestPoints, (N, 3) [m] workpiece-frame points) at the pose T (T_world_workpiece);
        ``hint`` the faces of the points at the current pose."""
        Ym = apply_pose(inv_pose(T), self.Y)
        if self.near_from_start:
            cp, self.near = self.index.query_near(Ym, self.near)
            return cp, Ym
        if not self.far:
            return self.index.query(Ym, hint=hint), Ym
        cp = self.index.query(Ym, hint=hint, rel_error=self.far_rel_error)
        d = cp.distance
        self.far = float(d @ d) > self.far_m2 * len(d)
        return cp, Ym

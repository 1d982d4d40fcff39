"""Symmetry from the data: which subgroup ``G_0`` the measured points leave free.

At the pose found by Algorithm 1 the feet and the ideal-surface normals give the scaled
Fisher information of :func:`algorithms.registration.uncertainty.observability`; a direction
is **free** when its eigenvalue is below ``DETECTION_TOL`` (1e-4) times the largest, i.e. when
the points fix it more than 100 times worse (in standard deviation, over the part's size) than
the best-fixed direction. The free subspace is then matched to a subgroup of document 000's
table (plane, cylinder, sphere, cone, extruded, free-form; :mod:`.groups`) by its structure:
how many rotations it holds, their axis, pitch and the translations beside them (tolerances
``MATCH_TOL``). A subspace the table does not name (a screw, say) is used as it is
(``kind = "other"``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from algorithms.arraytypes import ArrayLike, FloatArray
from algorithms.geometry.se3 import hat as _hat
from algorithms.registration.symmetric.groups import SymmetryGroup, other_group, symmetry_group
from algorithms.registration.uncertainty import OBSERVABILITY_TOL, Observability, observability

__all__ = ["DETECTION_TOL", "MATCH_TOL", "SymmetryDetection", "detect_symmetry"]

#: A pose direction is free when its scaled information eigenvalue is below this fraction
#: of the largest (same scale as :data:`algorithms.registration.uncertainty.OBSERVABILITY_TOL`).
DETECTION_TOL = OBSERVABILITY_TOL
#: Matching a free subspace to the table: dimensionless (angles in rad, lengths / L).
MATCH_TOL = 1e-3


@dataclass(frozen=True)
class SymmetryDetection:
    """Which subgroup the data leave free.

    Attributes:
        group: the matched :class:`SymmetryGroup` (its ``kind`` names the table feature, or
            ``"other"``; ``freeform`` when nothing is free).
        observability: the information analysis it rests on (relative eigenvalues, weak
            directions, tolerance).
        match_error: how far the free subspace is from the matched group's ``g_0``
            (largest principal-angle sine, scaled units); 0 for free-form.
    """

    group: SymmetryGroup
    observability: Observability
    match_error: float


def detect_symmetry(feet: ArrayLike, normals: ArrayLike, tol: float = DETECTION_TOL) -> SymmetryDetection:
    """Find the subgroup ``G_0`` that measured points leave free, and match it to the table.

    Args:
        feet: (N, 3) [m] the points' feet on the model (workpiece frame), at a fitted pose.
        normals: (N, 3) unit normals of the ideal surface there (smooth normals on a mesh,
            :meth:`MeshIndex.smooth_normals`; facet normals would fake information).
        tol: relative eigenvalue below which a direction is free (``DETECTION_TOL``).

    Returns:
        SymmetryDetection.
    """
    obs = observability(feet, normals, tol)
    W = obs.weak_directions
    c0 = obs.centroid
    L = obs.characteristic_length_m
    k = len(W)
    if k == 0:
        return SymmetryDetection(symmetry_group("freeform", c0), obs, 0.0)
    # scaled twists about the centroid: [L omega, v_c]; rows orthonormal
    S = np.hstack([W[:, :3] * L, W[:, 3:] + np.cross(W[:, :3], c0)])
    S, _ = np.linalg.qr(S.T)
    S = S.T
    group = _match(S, c0, L, k)
    if group is None:
        return SymmetryDetection(other_group(W, c0, L), obs, 0.0)
    err = _subspace_error(S, group, c0, L)
    if err > 10 * MATCH_TOL:
        return SymmetryDetection(other_group(W, c0, L), obs, err)
    return SymmetryDetection(group, obs, err)


def _subspace_error(S: FloatArray, group: SymmetryGroup, c0: FloatArray, L: float) -> float:
    G = np.hstack([group.g0[:, :3] * L, group.g0[:, 3:] + np.cross(group.g0[:, :3], c0)])
    G, _ = np.linalg.qr(G.T)
    # sines of the principal angles between span(S) and span(G)
    resid = G - S.T @ (S @ G)
    return float(np.linalg.norm(resid, 2)) if resid.size else 0.0


def _match(S: FloatArray, c0: FloatArray, L: float, k: int) -> SymmetryGroup | None:
    """Match an orthonormal free subspace (scaled, about c0) to a table subgroup."""
    Om = S[:, :3]  # L * omega
    U, sv, Vt = np.linalg.svd(Om)
    rot_rank = int(np.sum(sv > MATCH_TOL))
    # basis of the free subspace split into rotational and translational parts
    if rot_rank == 0:
        if k == 1:
            return symmetry_group("extruded", c0, S[0, 3:])
        return None
    if rot_rank == 3 and k == 3:
        # sphere: every element is a rotation about the centre: v_c = (c - c0) x omega
        w = Om / L
        A = np.vstack([-_hat(wi) for wi in w])  # v_c = -omega x (c - c0)
        b = S[:, 3:].reshape(-1)
        d, *_ = np.linalg.lstsq(A, b, rcond=None)
        resid = np.linalg.norm(A @ d - b)
        if resid > MATCH_TOL:
            return None
        return symmetry_group("sphere", c0 + d)
    if rot_rank != 1:
        return None
    # the rotational element: combination U[:, 0] of the rows
    rot = U[:, 0] @ S
    trans = (U[:, 1:].T @ S) if k > 1 else np.zeros((0, 6))
    axis = rot[:3] / np.linalg.norm(rot[:3])
    # normalise to |omega| = 1 (omega = axis), unscale
    scale = np.dot(rot[:3], axis) / L
    v_c = rot[3:] / scale  # velocity of c0 for a unit rotation about the axis
    # remove from v_c the parts that are translations in the subspace
    T_dirs = trans[:, 3:] if len(trans) else np.zeros((0, 3))
    if np.any(np.linalg.norm(trans[:, :3], axis=1) > MATCH_TOL) if len(trans) else False:
        return None
    if len(T_dirs):
        Qt, _ = np.linalg.qr(T_dirs.T)
        v_c = v_c - Qt @ (Qt.T @ v_c)
    pitch = float(np.dot(v_c, axis))
    if abs(pitch) > MATCH_TOL * L:
        return None  # a screw motion: not in the table
    # point on the axis: v_c = a x (c0 - p), so c0 + a x v_c = p + (a.(c0 - p)) a
    p = c0 + np.cross(axis, v_c)
    if k == 1:
        return symmetry_group("cone", p, axis)
    if k == 2:
        t = T_dirs[0] / np.linalg.norm(T_dirs[0])
        if np.linalg.norm(np.cross(t, axis)) > MATCH_TOL:
            return None
        return symmetry_group("cylinder", p, axis)
    if k == 3:
        if np.max(np.abs(T_dirs @ axis)) / max(np.min(np.linalg.norm(T_dirs, axis=1)), 1e-300) > MATCH_TOL:
            return None
        # a plane: rotations about any axis along the normal; reference point: the centroid
        return symmetry_group("plane", c0, axis)
    return None


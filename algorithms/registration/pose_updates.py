"""The pose updates of the local methods (:mod:`algorithms.registration.local`), in numpy.

Each ``update_*`` takes the pose ``T`` (T_world_workpiece), the points ``Ym`` (N, 3) [m] mapped
into the workpiece frame, their closest points ``cp`` on the model and the inlier ``mask``, and
returns the next pose and the method's step measure (None where the method has none). All
systems are set up in the workpiece frame from the points ``y_i``, feet ``x_i``, face normals
``n_i`` and plane residuals ``s_i = <y_i - x_i, n_i>``. Hong-Tan's update and the compiled
point-to-plane system stay in :mod:`algorithms.registration.local`.
"""

from __future__ import annotations

import numpy as np

from algorithms.arraytypes import BoolArray, FloatArray, Pose
from algorithms.geometry.mesh_index import ClosestPoints
from algorithms.geometry.se3 import exp_se3, hat, inv_pose, make_pose
from algorithms.registration.kernels import EDGE_COS_TOL
from algorithms.registration.robust import Mask
from algorithms.registration.uncertainty import cross_into

__all__ = [
    "centered",
    "edge_feet",
    "gram",
    "normal_equations",
    "plane_rows",
    "solve_sym6",
    "update_fine_001",
    "update_icp",
    "update_tangent",
    "update_va",
]

#: Rows per block of :func:`gram`.
_GRAM_BLOCK = 2048


def gram(J: FloatArray) -> FloatArray:
    """J^T J in row blocks small enough that BLAS stays on one thread: BLAS worker threads
    spin after a call and contend with the closest-point threads on small machines."""
    A = np.zeros((J.shape[1], J.shape[1]))
    for i in range(0, len(J), _GRAM_BLOCK):
        Jc = J[i : i + _GRAM_BLOCK]
        A += Jc.T @ Jc
    return A


def normal_equations(J: FloatArray, b: FloatArray) -> tuple[FloatArray, FloatArray]:
    """J^T J and J^T b (see :func:`gram`)."""
    return gram(J), np.einsum("ij,i->j", J, b)


def solve_sym6(A: FloatArray, g: FloatArray) -> FloatArray:
    """Solve the symmetric 6x6 system A x = g, minimum-norm where A is singular."""
    d = np.sqrt(np.diag(A))
    d[d == 0] = 1.0
    B = A / d[:, None] / d[None, :]
    w, V = np.linalg.eigh(B)
    keep = w > w[-1] * 1e-13
    x = V[:, keep] @ ((V[:, keep].T @ (g / d)) / w[keep])
    return x / d


def edge_feet(Ym: FloatArray, cp: ClosestPoints, mask: Mask) -> tuple[FloatArray, FloatArray, BoolArray]:
    """The selected points' offsets ``y_i - x_i`` (M, 3) [m], plane residuals
    ``<y_i - x_i, n_i>`` (M,) [m] and which feet lie on an edge or a vertex (the offset off the
    face's normal by more than ``EDGE_COS_TOL``)."""
    off = Ym[mask] - cp.foot[mask]
    s = np.einsum("ij,ij->i", off, cp.normal[mask])
    return off, s, s * s < (1.0 - EDGE_COS_TOL) * np.einsum("ij,ij->i", off, off)


def plane_rows(Ym: FloatArray, cp: ClosestPoints, mask: Mask, center: FloatArray,
               edges: bool = False) -> tuple[FloatArray, FloatArray]:
    """Rows ``[(y_i - center) x n_i, n_i]`` (M, 6) and residuals ``s_i = <y_i - x_i, n_i>``
    (M,) [m] of the point-to-plane system, ``n_i`` the face's normal; with ``edges``, a foot on
    an edge or a vertex (``EDGE_COS_TOL``) uses the direction of its offset and its length
    instead: the gradient of its distance."""
    y = Ym[mask]
    n = cp.normal[mask]
    off, s, edge = edge_feet(Ym, cp, mask)
    if edges and edge.any():
        d = np.linalg.norm(off[edge], axis=1)
        n = n.copy()
        n[edge] = off[edge] / d[:, None]
        s[edge] = d
    J = np.empty((len(y), 6))
    cross_into(y - center, n, J)
    J[:, 3:] = n
    return J, s


def centered(T: Pose, c: FloatArray, xi: FloatArray) -> Pose:
    """T A_c exp(xi) A_c^-1: the workpiece-frame motion exp(-xi) about the point c [m]."""
    A = make_pose(None, c)
    return T @ A @ exp_se3(xi) @ inv_pose(A)


def update_icp(T: Pose, Ym: FloatArray, cp: ClosestPoints, mask: Mask) -> tuple[Pose, None]:
    """Besl-McKay ICP: the closed-form (Horn/Kabsch by SVD, det = +1) rigid ``D`` minimising
    ``sum |D y_i - x_i|^2``; ``g^k = g^(k-1) D^-1``."""
    y = Ym[mask]
    x = cp.foot[mask]
    yc = y.mean(axis=0)
    xc = x.mean(axis=0)
    H = np.einsum("ij,ik->jk", y - yc, x - xc)
    U, _, Vt = np.linalg.svd(H)
    S = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0])
    R = Vt.T @ S @ U.T
    D = make_pose(R, xc - R @ yc)
    return T @ inv_pose(D), None


def _small_motion_system(u: FloatArray, r: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Normal equations of ``omega x u_i + v = r_i`` (three rows per point, rows ``[u x e_k, e_k]``)."""
    A = np.zeros((6, 6))
    g = np.zeros(6)
    for k in range(3):
        e = np.zeros(3)
        e[k] = 1.0
        Jk = np.hstack([np.cross(u, e), np.broadcast_to(e, u.shape)])
        Ak, gk = normal_equations(Jk, r[:, k])
        A += Ak
        g += gk
    return A, g


def update_va(T: Pose, Ym: FloatArray, cp: ClosestPoints, mask: Mask) -> tuple[Pose, None]:
    """The variational algorithm (Li's group): one Gauss-Newton step on SE(3) of the
    point-to-point objective: ``xi`` minimises ``sum |y_i - x_i - (omega x y_i + v)|^2``;
    ``g^k = g^(k-1) exp(xi)``."""
    y = Ym[mask]
    r = y - cp.foot[mask]
    xi = solve_sym6(*_small_motion_system(y, r))
    return T @ exp_se3(xi), None


def update_tangent(T: Pose, Ym: FloatArray, cp: ClosestPoints, mask: Mask) -> tuple[Pose, None]:
    """Tangent planes at the feet: ``xi`` minimises ``sum (s_i - (y_i x n_i).omega - n_i.v)^2``;
    the small-motion matrix ``[I - hat(omega), -v]`` made a rotation (nearest, by SVD) and
    applied: a first-order retraction about the workpiece origin."""
    J, s = plane_rows(Ym, cp, mask, np.zeros(3))
    xi = solve_sym6(*normal_equations(J, s))
    M = np.eye(3) - hat(xi[:3])
    U, _, Vt = np.linalg.svd(M)
    R = U @ Vt
    D = make_pose(R, -xi[3:])
    return T @ inv_pose(D), None


def _rot_xyz(t: FloatArray) -> FloatArray:
    """Rz Ry Rx of the angles ``t`` (3,) [rad]."""
    cx, cy, cz = np.cos(t)
    sx, sy, sz = np.sin(t)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def update_fine_001(T: Pose, Ym: FloatArray, cp: ClosestPoints, mask: Mask) -> tuple[Pose, float]:
    """Document 001's fine stage: ``J = sum |T P_i - Q'_i|^2`` linearised for a small motion
    (sin t = t, cos t = 1) about the centroid ``S_k`` of the points (the variable iteration
    centre ``A_k``), solved for ``(theta, Delta)``; ``T_d`` built exactly from them
    (``Rz Ry Rx``), ``T'_d = A_k T_d A_k^-1``, ``T(k) = T'_d T(k-1)``.

    Returns:
        The new pose, and the step ``sum dtheta^2 + sum dDelta^2`` [rad^2 + m^2] of the
        document's stopping rule.
    """
    y = Ym[mask]
    x = cp.foot[mask]
    S = y.mean(axis=0)  # variable iteration centre S_k
    u = y - S
    b = x - y
    # theta x u + Delta = Q' - P  (linearised T_d), 3 rows per point
    p = solve_sym6(*_small_motion_system(u, b))
    theta, delta = p[:3], p[3:]
    Td = make_pose(_rot_xyz(theta), delta)
    Ak = make_pose(None, S)
    Td_prime = Ak @ Td @ inv_pose(Ak)  # maps model-frame points: T(k) = T'_d T(k-1)
    step = float(theta @ theta + delta @ delta)
    return T @ inv_pose(Td_prime), step

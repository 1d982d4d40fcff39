"""Small batched SE(3) helpers of the global search: B poses at once, as (B, 4, 4) arrays."""

from __future__ import annotations

import numpy as np

from algorithms.arraytypes import FloatArray

__all__ = ["apply_model_motion", "make_poses", "rotvec_to_matrix", "to_model"]


def rotvec_to_matrix(w: FloatArray) -> FloatArray:
    """(B, 3) rotation vectors -> (B, 3, 3) rotations (Rodrigues)."""
    th = np.linalg.norm(w, axis=1)
    small = th < 1e-12
    ths = np.where(small, 1.0, th)
    k = w / ths[:, None]
    K = np.zeros((len(w), 3, 3))
    K[:, 0, 1] = -k[:, 2]
    K[:, 0, 2] = k[:, 1]
    K[:, 1, 0] = k[:, 2]
    K[:, 1, 2] = -k[:, 0]
    K[:, 2, 0] = -k[:, 1]
    K[:, 2, 1] = k[:, 0]
    s = np.where(small, 0.0, np.sin(th))[:, None, None]
    c = np.where(small, 0.0, 1.0 - np.cos(th))[:, None, None]
    R = np.eye(3)[None] + s * K + c * (K @ K)
    if small.any():  # first order for tiny angles
        W = np.zeros((int(small.sum()), 3, 3))
        ws = w[small]
        W[:, 0, 1] = -ws[:, 2]
        W[:, 0, 2] = ws[:, 1]
        W[:, 1, 0] = ws[:, 2]
        W[:, 1, 2] = -ws[:, 0]
        W[:, 2, 0] = -ws[:, 1]
        W[:, 2, 1] = ws[:, 0]
        R[small] = np.eye(3)[None] + W
    return R


def to_model(T: FloatArray, y: FloatArray) -> FloatArray:
    """Points y (N, 3) [world] into the model frames of poses T (B, 4, 4) -> (B, N, 3)."""
    return (y[None, :, :] - T[:, None, :3, 3]) @ T[:, :3, :3]


def apply_model_motion(T: FloatArray, Rd: FloatArray, c: FloatArray, v: FloatArray) -> FloatArray:
    """New poses (B, 4, 4) when model-frame points move by ``x' = Rd (x - c) + c + v``
    (Rd (B, 3, 3), c and v (B, 3) [m]).

    ``x = T^-1 y``, so the new ``T^-1 = M T^-1`` and ``T_new = T M^-1``.
    """
    B = len(T)
    Minv = np.tile(np.eye(4), (B, 1, 1))
    RdT = Rd.transpose(0, 2, 1)
    t = c - np.einsum("bij,bj->bi", Rd, c) + v
    Minv[:, :3, :3] = RdT
    Minv[:, :3, 3] = -np.einsum("bij,bj->bi", RdT, t)
    return T @ Minv


def make_poses(R: FloatArray, p: FloatArray) -> FloatArray:
    """(B, 3, 3) rotations and (B, 3) translations -> (B, 4, 4) poses."""
    T = np.tile(np.eye(4), (len(R), 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = p
    return T


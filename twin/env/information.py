"""The pose information an active-localization episode gathers, and what it says.

Conventions are those of :mod:`algorithms.registration.uncertainty`: the pose error is the
twist ``[omega, v]`` in the workpiece frame; a measured point with foot ``p`` and normal
``n`` on the model adds ``g g^T / sigma^2`` with ``g = [p x n, n]`` to the Fisher
information. An episode starts from a Gaussian prior: the fixture places the part within
``placement_sigma`` of its nominal pose (per axis), so the prior information is
``diag(1 / sigma_rot^2, 1 / sigma_trans^2)`` and the posterior ``P + F`` is always invertible.
The information gain of a measurement is the increase of ``log det(P + F)`` [nats].

Directions the part's own shape cannot fix (the axis of a body of revolution) are taken out
of the stopping rule: they are the weak directions of the information of the whole model
surface, and the standard deviations are those of the other directions given them.
"""

from __future__ import annotations

import numpy as np

from algorithms.registration.uncertainty import fisher_information, observability
from twin.realize import Workpiece

#: Points sampled on the whole model to find the directions its shape cannot fix.
MODEL_SAMPLES = 4000


def prior_information(placement_sigma_m: float, placement_sigma_rad: float) -> np.ndarray:
    """(6, 6) information of the fixture's placement prior (rotation first)."""
    return np.diag([placement_sigma_rad**-2] * 3 + [placement_sigma_m**-2] * 3)


def point_information(feet_wp: np.ndarray, normals_wp: np.ndarray, sigma_m: float) -> np.ndarray:
    """(6, 6) Fisher information of points at ``feet_wp`` (M, 3) with unit normals (M, 3)."""
    if len(feet_wp) == 0:
        return np.zeros((6, 6))
    return fisher_information(feet_wp, normals_wp, sigma_m)


def segment_information(feet_wp: np.ndarray, normals_wp: np.ndarray, beam_wp: np.ndarray, readings_m: np.ndarray,
                        sigma_m: float, bias_sigma_m: float, incidence_noise: bool, bin_m: float) -> np.ndarray:
    """(6, 6) information one line's points would bring: rows ``[p x n, n]`` weighted by
    ``cos^2(incidence) / sigma^2`` (with ``incidence_noise``), one unknown linearity offset per
    bin of readings (``bin_m`` wide, prior ``bias_sigma_m``) marginalised out (the same model
    as :func:`algorithms.registration.bayes.localize_map`; the offsets of bins other lines
    already saw are taken as unknown, so the prediction errs low).

    Args:
        feet_wp, normals_wp: (M, 3) predicted points and unit normals, workpiece frame.
        beam_wp: (3,) the beam direction, workpiece frame; readings_m: (M,) distances [m].
    """
    if len(feet_wp) == 0:
        return np.zeros((6, 6))
    c = -(normals_wp @ beam_wp)
    sigma = sigma_m / np.maximum(np.abs(c), 1e-3) if incidence_noise else np.full(len(c), sigma_m)
    w = sigma**-2
    J = np.hstack([np.cross(feet_wp, normals_wp), normals_wp])
    F = (w[:, None] * J).T @ J
    if bias_sigma_m > 0:
        _, g = np.unique(np.floor(readings_m / bin_m), return_inverse=True)
        Hxb = np.zeros((6, g.max() + 1))
        np.add.at(Hxb.T, g, (w * c)[:, None] * J)
        Hbb = np.bincount(g, w * c * c) + bias_sigma_m**-2
        F = F - (Hxb / Hbb) @ Hxb.T
    return 0.5 * (F + F.T)


def log_det(F: np.ndarray) -> float:
    """log det of a symmetric positive-definite information matrix [nats]."""
    sign, value = np.linalg.slogdet(F)
    return float(value) if sign > 0 else -np.inf


def model_free_directions(workpiece: Workpiece, seed: int = 0) -> np.ndarray:
    """(k, 6) twists no measurement of the part's surface can fix (its symmetry), from the
    information of ``MODEL_SAMPLES`` points spread over the whole model (smooth normals)."""
    mesh = workpiece.mesh
    rng = np.random.default_rng(seed)
    face = rng.choice(len(mesh.faces), MODEL_SAMPLES, p=mesh.area_faces / mesh.area)
    r = rng.random((MODEL_SAMPLES, 2))
    flip = r.sum(axis=1) > 1
    r[flip] = 1 - r[flip]
    tri = mesh.triangles[face]
    feet = tri[:, 0] + r[:, :1] * (tri[:, 1] - tri[:, 0]) + r[:, 1:] * (tri[:, 2] - tri[:, 0])
    return observability(feet, workpiece.index.smooth_normals(face, feet)).weak_directions


def scaling(length_m: float) -> np.ndarray:
    """(6,) ``S`` that makes twists consistent displacements: ``[L omega, v]``."""
    return np.array([length_m] * 3 + [1.0] * 3)


def worst_std(F_posterior: np.ndarray, free: np.ndarray, length_m: float) -> tuple[float, float]:
    """(rotation [rad], translation [m]): the largest standard deviation of any rotation and of
    any translation of the pose, given the shape's free directions ``free`` (k, 6)."""
    s = scaling(length_m)
    Fs = F_posterior / np.outer(s, s)
    if len(free):
        W = free * s
        _, _, Vt = np.linalg.svd(W)
        B = Vt[len(free):]             # orthonormal complement of the free directions (scaled)
        Cs = B.T @ np.linalg.inv(B @ Fs @ B.T) @ B
    else:
        Cs = np.linalg.inv(Fs)
    C = Cs / np.outer(s, s)
    rot = float(np.sqrt(max(np.linalg.eigvalsh(0.5 * (C[:3, :3] + C[:3, :3].T))[-1], 0.0)))
    trans = float(np.sqrt(max(np.linalg.eigvalsh(0.5 * (C[3:, 3:] + C[3:, 3:].T))[-1], 0.0)))
    return rot, trans

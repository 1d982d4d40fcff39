"""What the inliers at a local fit (:mod:`algorithms.registration.local`) determine of the
pose: the observability of their feet and the covariance of the pose (workpiece frame)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from algorithms.arraytypes import FloatArray
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import inv_pose
from algorithms.registration.feet import apply_pose
from algorithms.registration.iteration_state import LocalFit
from algorithms.registration.pose_updates import gram
from algorithms.registration.uncertainty import (
    OBSERVABILITY_TOL,
    Observability,
    cross_into,
    observability,
    sym_inverse,
    unit_twists,
)

__all__ = ["OBSERVABILITY_MAX_POINTS", "FitUncertainty", "fit_uncertainty"]

#: A regular subsample of at most this many feet estimates the same normalised information
#: (exactly so for symmetric sets) at a fraction of the cost of the smooth normals.
OBSERVABILITY_MAX_POINTS = 4096


@dataclass(frozen=True)
class FitUncertainty:
    """What the inliers at a fit determine of the pose (workpiece frame).

    Attributes:
        Ym_in: (n, 3) [m] the inliers, workpiece frame.
        s: (n,) [m] their plane residuals ``<y_i - x_i, n_i>``.
        obs: the observability of the feet.
        sigma_m: the given noise sigma, or the one estimated from ``s`` [m].
        determined: (q, 6) the twists the covariance is over (the identity when observable).
        covariance: (q, q) of the pose along ``determined`` [rad, m], or None if singular.
        free: (6 - q, 6) unit twists the points leave free.
    """

    Ym_in: FloatArray
    s: FloatArray
    obs: Observability
    sigma_m: float
    determined: FloatArray
    covariance: FloatArray | None
    free: FloatArray


def fit_uncertainty(fit: LocalFit, Y: FloatArray, index: MeshIndex, sigma: float | None) -> FitUncertainty:
    """The observability and covariance at the fit's pose from its inliers' feet.

    Args:
        fit: the fit.
        Y: (N, 3) [m] the points, world frame.
        index: the model.
        sigma: the given noise sigma [m], or None (estimated from the plane residuals).
    """
    mask = fit.mask
    Ym = apply_pose(inv_pose(fit.T), Y)
    feet = fit.cp.foot[mask]
    normals = fit.cp.normal[mask]
    n_used = len(feet)
    s = np.einsum("ij,ij->i", Ym[mask] - feet, normals)
    stride = max(1, -(-n_used // OBSERVABILITY_MAX_POINTS))
    sub_feet = feet[::stride]
    sub_faces = fit.cp.face[mask][::stride]
    obs = observability(sub_feet, index.smooth_normals(sub_faces, sub_feet), OBSERVABILITY_TOL)
    sigma_used = float(np.sqrt(np.sum(s * s) / max(n_used - 6, 1))) if sigma is None else float(sigma)
    J = np.empty((n_used, 6))
    cross_into(feet, normals, J)
    J[:, 3:] = normals
    covariance: FloatArray | None
    if obs.observable:
        determined = np.eye(6)
        covariance = sym_inverse(gram(J)) * sigma_used**2
    else:
        # the covariance of the directions the points do fix (the others have none)
        determined = unit_twists(obs.determined_directions)
        covariance = _covariance_along(J @ determined.T, sigma_used)
    return FitUncertainty(Ym_in=Ym[mask], s=s, obs=obs, sigma_m=sigma_used, determined=determined,
                          covariance=covariance, free=unit_twists(obs.weak_directions))


def _covariance_along(A: FloatArray, sigma: float) -> FloatArray | None:
    """sigma^2 (A^T A)^-1 for the rows A (N, q) of the directions fixed, or None if singular."""
    if A.shape[1] == 0:
        return np.zeros((0, 0))
    try:
        C = sym_inverse(gram(A)) * sigma**2
    except np.linalg.LinAlgError:
        return None
    return C if np.all(np.isfinite(C)) else None

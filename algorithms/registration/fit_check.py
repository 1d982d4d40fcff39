"""Is the fit one the noise explains? The poor-fit check, with or without a given sigma.

A converged fit of points of *another* part, or a local minimum, leaves residuals that are
**structured in space**: neighbouring points have nearly the same signed distance to the
model, because the mismatch varies over millimetres while the noise changes from point to
point. The white part of the noise is therefore estimated from the differences between each
point's residual and its nearest neighbour's (:func:`white_noise_sigma_m`; a robust MAD
estimate, divided by sqrt(2)); a fit whose RMS residual is more than ``POOR_FIT_WHITE_SIGMAS``
times that noise (or ``POOR_FIT_SIGMAS`` times the given sigma) is a poor fit. A fit that keeps fewer than
``1 - MAX_OUTLIER_FRACTION`` of the points as inliers is also a poor fit: the model explains
only part of what was measured (a cube's points on a larger block with a hole fit its faces
exactly, but the points over the hole are lost).

The thresholds sit between what each part fitted to its own model and to the other parts'
models gives (``python -m benchmarks.bench_fit_check``, ``benchmarks/results_fit_check.md``;
the figures are in ``benchmarks/results_history_registration.md``).

Sparse points (tens of millimetres apart) carry less of this evidence: their neighbours'
residuals are no longer correlated, so without a sigma a wrong model can pass there; give
``sigma`` (the sensor's) when you know it.
"""

from __future__ import annotations

import math

import numpy as np

from algorithms.arraytypes import ArrayLike, FloatArray

__all__ = [
    "MAX_OUTLIER_FRACTION",
    "POOR_FIT_SIGMAS",
    "POOR_FIT_WHITE_SIGMAS",
    "RESIDUAL_FLOOR_REL",
    "poor_fit_reason",
    "white_noise_sigma_m",
]

#: With a given sigma, a fit is poor when its RMS residual exceeds this many sigmas.
POOR_FIT_SIGMAS = 3.0
#: Without one, a fit is poor when its RMS residual exceeds this many point-to-point noise
#: sigmas: above a correct model's ratio (2.5 at most: the inner sphere's scan, structured
#: sensor errors), below a wrong one's (9 or more).
POOR_FIT_WHITE_SIGMAS = 5.0
#: A fit is poor when more than this fraction of the points are outliers of the model.
MAX_OUTLIER_FRACTION = 0.2
#: RMS residuals below this fraction of the part's size pass whatever the noise estimate
#: (noise-free data: floating-point residuals have no meaningful scale).
RESIDUAL_FLOOR_REL = 1e-6
_MAD_TO_SIGMA = 1.4826


def white_noise_sigma_m(points_m: FloatArray, residuals_m: ArrayLike) -> float:
    """The point-to-point (white) part of the residual's spread [m].

    Args:
        points_m: (n, 3) the points (any frame; only their neighbours matter).
        residuals_m: (n,) their signed distances to the model, or (n, m) their signed
            components along m normals (a line feature has two).

    Returns:
        1.4826 MAD(r_i - r_nn(i)) / sqrt(2), nn(i) the nearest other point (components
        pooled); NaN for n < 2.
    """
    n = len(points_m)
    if n < 2:
        return math.nan
    r = np.asarray(residuals_m, dtype=np.float64).reshape(n, -1)
    from scipy.spatial import cKDTree  # here: a fit with a stated sigma never loads scipy.spatial

    _, j = cKDTree(points_m).query(points_m, k=2)
    diff = (r - r[j[:, 1]]).ravel()
    return float(_MAD_TO_SIGMA * np.median(np.abs(diff - np.median(diff))) / math.sqrt(2.0))


def poor_fit_reason(rmse_m: float, n_inliers: int, n_points: int, extent_m: float,
                    sigma_m: float | None, white_sigma_m: float) -> str | None:
    """Why the fit is poor (one phrase), or None if the noise explains it.

    Args:
        rmse_m: RMS residual of the inliers [m].
        n_inliers: inliers kept.
        n_points: finite points given.
        extent_m: the model's size (bounding-box diagonal) [m].
        sigma_m: the given noise sigma [m], or None.
        white_sigma_m: :func:`white_noise_sigma_m` of the inliers' residuals [m].
    """
    outlier_fraction = 1.0 - n_inliers / max(n_points, 1)
    if outlier_fraction > MAX_OUTLIER_FRACTION:
        return (f"{outlier_fraction:.0%} of the points lie off the model (more than "
                f"{MAX_OUTLIER_FRACTION:.0%}): points of another part, or a local minimum")
    if sigma_m is not None:
        if rmse_m > POOR_FIT_SIGMAS * sigma_m:
            return (f"RMS {rmse_m:.3g} m is {rmse_m / sigma_m:.0f} times the given sigma "
                    "(local minimum or wrong model?)")
        return None
    if rmse_m <= RESIDUAL_FLOOR_REL * extent_m or not math.isfinite(white_sigma_m):
        return None
    if rmse_m > POOR_FIT_WHITE_SIGMAS * white_sigma_m:
        ratio = rmse_m / white_sigma_m if white_sigma_m > 0 else math.inf
        return (f"RMS {rmse_m:.3g} m is {ratio:.0f} times the point-to-point noise {white_sigma_m:.3g} m "
                "(residuals structured in space: local minimum or wrong model?)")
    return None

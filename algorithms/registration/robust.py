"""Outlier rules shared by every registration method (local, symmetric, global search).

Spurious returns and fixture points are rejected at every iteration by their distance to the
model. The ``outlier`` option of the methods chooses the rule:

* ``"mad"`` (default): a point is an outlier when its distance exceeds
  ``max(5 * 1.4826 * median(distance), floor)``: a robust 5-sigma cut for Gaussian noise along
  the normals (the distances are ``|noise|``, whose median is 0.674 sigma), with a floor so
  exact data lose nothing. The rule has two stages. Until the iteration first converges the
  cut is looser, ``max(8 * 1.4826 * median(distance), coarse floor)``: only gross outliers
  go. Far from the minimum the residuals are systematic misfit, not noise, and the far points
  are the ones that carry the correction: cutting them early traps the iteration in wrong
  minima and slows the point-to-point methods. Once converged the cut is tightened to
  5 sigmas; if that changes the inlier set the iteration goes on.
* a number: a fixed maximum distance [m];
* ``None`` (or ``"none"``): every point is kept.

Whatever the rule, at least ``min_points`` points are kept: when fewer pass (a fixed distance
and a poor start, say) the closest half is kept to get going.
"""

from __future__ import annotations

import numpy as np

from algorithms.arraytypes import BoolArray, FloatArray
from algorithms.errors import AlgorithmError

__all__ = [
    "ALL",
    "MAD_TO_SIGMA",
    "OUTLIER_K",
    "OUTLIER_K_COARSE",
    "OUTLIER_FLOOR_REL",
    "OUTLIER_COARSE_FLOOR_REL",
    "OutlierStages",
    "count",
    "inlier_mask",
    "outlier_config",
    "same_mask",
    "upper_median",
]

#: Robust sigma from the median absolute value of Gaussian noise.
MAD_TO_SIGMA = 1.4826
#: The cut in robust sigmas once the fit has converged, and before.
OUTLIER_K = 5.0
OUTLIER_K_COARSE = 8.0
#: Floors of the ``"mad"`` cut, relative to the model's size: the final one keeps exact data
#: whole; until the first convergence no point within the coarse one is cut (systematic
#: misfit is not noise: cutting it slows or traps the iteration).
OUTLIER_FLOOR_REL = 1e-6
OUTLIER_COARSE_FLOOR_REL = 1e-2

#: A mask that selects every row (indexing with it gives views, not copies).
ALL = slice(None)

#: Inliers: a (N,) bool mask, or :data:`ALL`.
Mask = BoolArray | slice
#: The checked ``outlier`` option: ``None``, ``"mad"`` or a distance [m].
OutlierConfig = str | float | None


def outlier_config(outlier: OutlierConfig) -> OutlierConfig:
    """Check the ``outlier`` option: returns ``None``, ``"mad"`` or a distance [m].

    Raises:
        AlgorithmError: anything else (the message lists what is allowed).
    """
    if outlier is None or (isinstance(outlier, str) and outlier == "none"):
        return None
    if isinstance(outlier, str):
        if outlier != "mad":
            raise AlgorithmError(f"outlier must be 'mad', a distance [m] or None, got {outlier!r}")
        return "mad"
    try:
        value = float(outlier)
    except (TypeError, ValueError):
        raise AlgorithmError(f"outlier must be 'mad', a distance [m] or None, got {outlier!r}") from None
    if not (np.isfinite(value) and value > 0):
        raise AlgorithmError(f"outlier distance must be a positive length [m], got {outlier!r}")
    return value


def upper_median(d: FloatArray) -> float:
    """The median of d (the upper one of an even count), by partition."""
    k = len(d) // 2
    return float(np.partition(d, k)[k])


def inlier_mask(d: FloatArray, cfg: OutlierConfig, floor: float, k: float = OUTLIER_K,
                min_points: int = 6) -> Mask:
    """Inliers among distances ``d`` (N,) [m]: a bool mask, or :data:`ALL` when every point is.

    Args:
        d: (N,) distances of the points to the model [m].
        cfg: the checked option (:func:`outlier_config`).
        floor: the smallest cut of the ``"mad"`` rule [m].
        k: robust sigmas of the ``"mad"`` cut.
        min_points: at least this many points are kept (the closest half otherwise).
    """
    if cfg is None:
        return ALL
    if cfg == "mad":
        thr = max(k * MAD_TO_SIGMA * upper_median(d), floor)
    else:
        thr = float(cfg)
    mask = d <= thr
    if mask.all():
        return ALL
    if mask.sum() < min_points:
        mask = d <= upper_median(d)
    return mask


def same_mask(a: Mask, b: Mask) -> bool:
    """Whether two masks from :func:`inlier_mask` select the same rows."""
    if isinstance(a, slice) or isinstance(b, slice):
        return isinstance(a, slice) and isinstance(b, slice)
    return bool(np.array_equal(a, b))


def count(mask: Mask, n: int) -> int:
    """Rows a mask selects out of n."""
    return n if isinstance(mask, slice) else int(mask.sum())


class OutlierStages:
    """The staged rule of one fit: the coarse cut until the fit first converges, then the
    final one (for ``"mad"``; the other rules have one stage).

    Args:
        cfg: the checked option (:func:`outlier_config`).
        coarse_floor: floor of the coarse ``"mad"`` cut [m].
        floor: floor of the final ``"mad"`` cut [m].
        min_points: at least this many points are kept.
    """

    def __init__(self, cfg: OutlierConfig, coarse_floor: float, floor: float, min_points: int) -> None:
        self.cfg = cfg
        self.k = OUTLIER_K_COARSE
        self.floor = coarse_floor
        self._final_floor = floor
        self.min_points = min_points

    def mask(self, d: FloatArray) -> Mask:
        """Inliers of distances ``d`` under the current stage."""
        return inlier_mask(d, self.cfg, self.floor, self.k, self.min_points)

    def tighten(self) -> bool:
        """Move to the final stage; True when that changed the rule (``"mad"``, first call)."""
        if self.cfg != "mad" or self.k == OUTLIER_K:
            return False
        self.k = OUTLIER_K
        self.floor = self._final_floor
        return True

"""Checks of the inputs every registration method shares: points, model, units, sigma.

Rows with NaN or infinite coordinates are dropped and counted (a laser that saw nothing
reports NaN); fewer than ``MIN_POINTS`` finite rows is an error. Point sets spanning more than
``UNITS_MAX_RATIO`` times the model's bounding-box diagonal, or less than ``UNITS_MIN_RATIO``
of it, raise an error that the units look wrong.
"""

from __future__ import annotations

import numpy as np

from algorithms.arraytypes import ArrayLike, FloatArray, IntArray
from algorithms.errors import AlgorithmError
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.parametric import ParametricModel

__all__ = ["MIN_POINTS", "UNITS_MAX_RATIO", "UNITS_MIN_RATIO", "check_sigma", "check_units", "finite_rows",
           "mesh_index"]

MIN_POINTS = 6
#: Units check: point spread relative to the model's bounding-box diagonal.
UNITS_MAX_RATIO = 20.0
UNITS_MIN_RATIO = 1e-3


def finite_rows(points: ArrayLike, min_points: int = MIN_POINTS) -> tuple[FloatArray, IntArray]:
    """The points as float64 (N, 3) (frame and unit as given) and the indices (M,) of their
    finite rows.

    Raises:
        AlgorithmError: not (N, 3), or fewer than ``min_points`` finite rows.
    """
    P = np.asarray(points, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        raise AlgorithmError(f"points must be (N, 3) with N >= {min_points}, got {P.shape}")
    finite = np.all(np.isfinite(P), axis=1)
    if finite.sum() < min_points:
        raise AlgorithmError(
            f"points must be (N, 3) with at least {min_points} finite rows, got {int(finite.sum())} "
            f"finite of {len(P)}"
        )
    return P, np.nonzero(finite)[0]


def mesh_index(mesh: object, index: MeshIndex | None) -> MeshIndex:
    """A prebuilt index, or one built for ``mesh`` (a trimesh or what :class:`MeshIndex` takes).
    A :class:`~algorithms.geometry.parametric.ParametricModel` (exact surfaces, Newton foot
    points) passes too: Algorithm 1 as printed runs on it."""
    if index is None:
        if mesh is None:
            raise AlgorithmError("give a mesh (or a prebuilt index)")
        return MeshIndex(mesh)
    if not isinstance(index, (MeshIndex, ParametricModel)):
        raise AlgorithmError(f"index must be a MeshIndex or a ParametricModel, got {type(index).__name__}")
    return index


def check_sigma(sigma: float | None, name: str = "sigma") -> float | None:
    """A positive finite noise sigma [m], or None."""
    if sigma is None:
        return None
    if not (np.isfinite(sigma) and sigma > 0):
        raise AlgorithmError(f"{name} must be a positive length [m] or None, got {sigma}")
    return float(sigma)


def check_units(Y: FloatArray, index: MeshIndex) -> None:
    """Refuse point sets whose size no rigid pose of the model can explain.

    Args:
        Y: (N, 3) finite points [m], any frame (only their spread matters).
        index: the model's index, in the same unit.
    """
    size = index.extent
    if not size > 0:
        raise AlgorithmError("the model has zero size (all vertices coincide)")
    spread = 2.0 * _radius_90(Y)
    if spread > UNITS_MAX_RATIO * size:
        raise AlgorithmError(
            f"the points span {spread:.4g} but the model is only {size:.4g} across "
            f"({spread / size:.0f}x): units look wrong (points in mm and model in m?); "
            "mesh and points must be in the same units (metres)"
        )
    if spread < UNITS_MIN_RATIO * size:
        raise AlgorithmError(
            f"the points span {spread:.4g} but the model is {size:.4g} across "
            f"(1/{size / max(spread, 1e-300):.0f}): units look wrong (points in m and model in mm?) "
            "or the points cover too little of the part"
        )


def _radius_90(Y: FloatArray) -> float:
    """The 90th percentile (linear interpolation) of the points' distances from their
    coordinate-wise median [m], by partition: np.median's and np.percentile's result without
    their sorting cost (the check runs on every call of localize and global_localize)."""
    n = len(Y)
    k = n // 2
    if n % 2:
        center = np.partition(Y, k, axis=0)[k]
    else:
        P = np.partition(Y, [k - 1, k], axis=0)
        center = 0.5 * (P[k - 1] + P[k])
    d = Y - center
    r = np.sqrt(np.einsum("ij,ij->i", d, d))
    h = 0.9 * (n - 1)
    lo = int(h)
    hi = min(lo + 1, n - 1)
    q = np.partition(r, [lo, hi])
    return float(q[lo] + (h - lo) * (q[hi] - q[lo]))

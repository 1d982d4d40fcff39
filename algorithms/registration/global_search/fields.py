"""Nearest-surface oracles of the global search: the coarse field and the exact closest points.

The coarse phases of every global method (Algorithm 5's starts, the genetic algorithm's
population, the swarm when asked) evaluate thousands of poses. They read the nearest surface
from a coarse nearest-surface field: a voxel grid storing the nearest surface sample of every
node, built once per mesh (one Euclidean distance transform), about a millimetre resolution.
The best distinct minima are then refined with the exact closest points
(:class:`algorithms.geometry.mesh_index.MeshIndex`, :class:`ExactOracle`). Both answer
``closest(x, hint) -> (foot, normal, face or None)`` and carry ``tangent_tol``, the
tangential tolerance of their feet (zero for exact feet), which :func:`sq_dist` uses.
"""

from __future__ import annotations

import weakref
from typing import Any, Protocol

import numpy as np

from algorithms.arraytypes import FloatArray, IntArray
from algorithms.errors import AlgorithmError

__all__ = ["CoarseField", "ExactOracle", "NearestSurface", "coarse_field", "sq_dist"]


class NearestSurface(Protocol):
    """What the searches ask of a model: the nearest surface to model-frame points."""

    #: Tangential tolerance of the feet [m] (0: exact feet).
    tangent_tol: float

    def closest(self, x: FloatArray, hint: IntArray | None = None) -> tuple[FloatArray, FloatArray, IntArray | None]:
        """(N, 3) [m] model-frame points -> (feet (N, 3) [m], unit normals (N, 3), faces (N,) or None)."""
        ...


class CoarseField:
    """Nearest surface sample of every node of a voxel grid around the model.

    Built with one Euclidean distance transform (scipy.ndimage) of the voxels that contain
    surface samples; a query rounds to the nearest node and returns that node's nearest
    sample and its face normal. Accuracy: a few voxels (``cell`` = extent / 64 by default);
    it is only used for the coarse phases, never for a reported pose.
    """

    def __init__(self, mesh: Any, cells_per_extent: int = 64, pad_frac: float = 0.6) -> None:
        # imported here: only a search's first call on a mesh builds a field
        import trimesh
        from scipy import ndimage

        V = np.asarray(mesh.vertices, dtype=np.float64)
        lo, hi = V.min(axis=0), V.max(axis=0)
        extent = float(np.linalg.norm(hi - lo))
        if not extent > 0:
            raise AlgorithmError("mesh has zero extent")
        cell = extent / cells_per_extent
        pad = pad_frac * extent
        self.origin = lo - pad
        self.cell = cell
        self.shape = tuple(int(s) for s in np.ceil((hi - lo + 2 * pad) / cell).astype(int) + 1)
        face_normals = np.asarray(mesh.face_normals, dtype=np.float64)
        n = int(min(2_000_000, max(20_000, 6.0 * float(mesh.area) / cell**2)))
        s, fi = trimesh.sample.sample_surface(mesh, n, seed=0)
        tri = np.asarray(mesh.triangles, dtype=np.float64)
        s = np.vstack([s, tri.mean(axis=1)])
        fi = np.concatenate([fi, np.arange(len(tri))])
        self.samples = s
        self.normals = face_normals[fi]
        # samples and normals in one array: one np.take per query
        self._sample_normal = np.hstack([self.samples, self.normals])
        ijk = np.rint((s - self.origin) / cell).astype(np.int64)
        table = np.full(self.shape, -1, dtype=np.int32)
        table[ijk[:, 0], ijk[:, 1], ijk[:, 2]] = np.arange(len(s), dtype=np.int32)
        ind = ndimage.distance_transform_edt(table < 0, return_distances=False, return_indices=True)
        self.nearest = table[ind[0], ind[1], ind[2]]
        self._flat = self.nearest.reshape(-1)
        self._hi = np.asarray(self.shape, dtype=np.float64) - 1.0
        self._strides = np.array([self.shape[1] * self.shape[2], self.shape[2], 1], dtype=np.int64)
        # tangential tolerance: a node's sample is within about one cell of the true foot
        self.tangent_tol = cell
        # the field's own residual for points exactly on the surface (its floor)
        chk, cfi = trimesh.sample.sample_surface(mesh, 2000, seed=1)
        foot, normal, _ = self.closest(chk)
        d2, _ = sq_dist(chk, foot, normal, self.tangent_tol)
        self.floor_rms = float(np.sqrt(np.mean(d2)))

    def closest(self, x: FloatArray, hint: IntArray | None = None) -> tuple[FloatArray, FloatArray, None]:
        """The nearest node's sample and its face normal; ``hint`` is ignored."""
        f = np.rint((x - self.origin) * (1.0 / self.cell))
        np.clip(f, 0.0, self._hi, out=f)
        k = self._flat[f.astype(np.int64) @ self._strides]
        sn = np.take(self._sample_normal, k, axis=0)
        return sn[:, :3], sn[:, 3:], None


class ExactOracle:
    """Exact closest points of a :class:`~algorithms.geometry.mesh_index.MeshIndex`."""

    tangent_tol = 0.0

    def __init__(self, index: Any) -> None:
        self.index = index

    def closest(self, x: FloatArray, hint: IntArray | None = None) -> tuple[FloatArray, FloatArray, IntArray]:
        """Exact feet, normals and faces; ``hint``: the faces of the previous query's feet."""
        try:
            cp = self.index.query(x, hint=hint)
        except TypeError:  # an index without hints
            cp = self.index.query(x)
        return cp.foot, cp.normal, cp.face


_FIELD_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def coarse_field(mesh: Any) -> CoarseField:
    """The mesh's :class:`CoarseField`, built once per mesh (cached while the mesh lives)."""
    try:
        f = _FIELD_CACHE.get(mesh)
    except TypeError:
        f = None
    if f is None:
        f = CoarseField(mesh)
        try:
            _FIELD_CACHE[mesh] = f
        except TypeError:
            pass
    return f


def sq_dist(x: FloatArray, foot: FloatArray, normal: FloatArray,
            tangent_tol: float) -> tuple[FloatArray, FloatArray]:
    """Squared distance estimate: exact for exact feet (tangent_tol = 0); for a field sample,
    the normal offset plus the tangential offset beyond the sample's patch.

    Returns:
        (squared distances [m^2], signed normal offsets [m]), the shape of ``x`` less its last axis.
    """
    d = x - foot
    rn = np.einsum("...i,...i->...", d, normal)
    dd = np.einsum("...i,...i->...", d, d)
    if tangent_tol <= 0:
        return dd, rn
    tang = np.sqrt(np.maximum(dd - rn * rn, 0.0))
    ex = np.maximum(tang - tangent_tol, 0.0)
    return rn * rn + ex * ex, rn


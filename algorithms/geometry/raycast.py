"""Exact ray casts on triangle meshes (first hits of many parallel rays).

MuJoCo's ray-triangle test can let a ray slip through a shared edge or vertex of a mesh;
the cast below cannot (barycentric test with a tolerance). Generated meshes sit on regular
grids, so planning rasters are also shifted off round numbers by ``GRID_SHIFT_M``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from algorithms.arraytypes import ArrayLike, BoolArray, FloatArray, IntArray
from algorithms.errors import AlgorithmError

# The planning raster is shifted off round numbers so that rays do not run exactly along the
# shared edges of grid-tessellated meshes.
GRID_SHIFT_M = 1.2345e-4
#: Up to this many rays, each ray culls the triangles by their bounding boxes (no trees built).
FEW_RAYS = 16
#: The boxes' margin [m]: every triangle the barycentric test's tolerance admits is inside.
BOX_MARGIN_M = 1e-9


def _unit_vector(v: ArrayLike, name: str) -> FloatArray:
    a = np.asarray(v, dtype=np.float64)
    if a.shape != (3,) or not np.all(np.isfinite(a)) or np.linalg.norm(a) < 1e-12:
        raise AlgorithmError(f"{name} must be a finite non-zero (3,) vector, got {v!r}")
    return a / np.linalg.norm(a)


def raycast_parallel(
    vertices: ArrayLike, faces: ArrayLike, origins: ArrayLike, direction: ArrayLike, chunk: int = 20000
) -> tuple[BoolArray, FloatArray, IntArray]:
    """First hits of parallel rays on a triangle mesh (exact, vectorised).

    The triangles are projected onto the plane orthogonal to ``direction`` and grouped by
    size (powers of two of their circumradius); each group has a KD-tree of centroids that
    is searched within its largest radius, so small and large triangles mix without every
    ray testing every large-radius neighbourhood. Point-in-triangle uses barycentric
    coordinates with a 1e-12 tolerance: a ray along a shared edge or through a shared
    vertex hits one of the triangles (it cannot slip through).

    Args:
        vertices: (V, 3), faces: (F, 3) the mesh.
        origins: (N, 3) ray origins.
        direction: (3,) common ray direction.

    Returns:
        hit (N,) bool, points (N, 3) (NaN where no hit), face (N,) int (-1 where no hit).
    """
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    Orig = np.asarray(origins, dtype=np.float64)
    if Orig.ndim != 2 or Orig.shape[1] != 3:
        raise AlgorithmError(f"origins must be (N, 3), got {Orig.shape}")
    d = _unit_vector(direction, "direction")
    e1 = np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)
    B = np.column_stack([e1, e2])
    o2 = Orig @ B
    hits = _Hits(len(Orig))
    if len(Orig) <= FEW_RAYS:
        _few_rays(hits, V, F, B, Orig, o2, d)
        return hits.hit, hits.pts, hits.face
    tri = V[F]
    t2 = tri @ B
    cen = t2.mean(axis=1)
    rad = np.max(np.linalg.norm(t2 - cen[:, None, :], axis=2), axis=1)
    level = np.floor(np.log2(np.maximum(rad, 1e-12))).astype(np.int64)
    groups = []
    for lv in np.unique(level):
        ids = np.flatnonzero(level == lv)
        groups.append((ids, cKDTree(cen[ids]), float(rad[ids].max()) * (1 + 1e-9) + 1e-12))
    for c0 in range(0, len(Orig), chunk):
        sl = slice(c0, min(len(Orig), c0 + chunk))
        for ids, tree, r in groups:
            cand = tree.query_ball_point(o2[sl], r=r)
            counts = np.fromiter((len(c) for c in cand), dtype=np.int64, count=len(cand))
            if counts.sum() == 0:
                continue
            qi = np.repeat(np.arange(sl.start, sl.stop), counts)
            fi = ids[np.concatenate([np.asarray(c, dtype=np.int64) for c in cand if len(c)])]
            hits.keep_first(qi, fi, t2, o2, tri, Orig, d)
    return hits.hit, hits.pts, hits.face


def _few_rays(hits: _Hits, V: FloatArray, F: IntArray, B: FloatArray, Orig: FloatArray, o2: FloatArray,
              d: FloatArray) -> None:
    """A handful of rays (a line of sight, a probe's aim): each culls the triangles by their
    projected bounding boxes, which costs less than building the centroid trees."""
    vb = V @ B
    boxes = []
    for k in range(2):
        c = vb[F, k]
        boxes.append((np.minimum(np.minimum(c[:, 0], c[:, 1]), c[:, 2]) - BOX_MARGIN_M,
                      np.maximum(np.maximum(c[:, 0], c[:, 1]), c[:, 2]) + BOX_MARGIN_M))
    (lo0, hi0), (lo1, hi1) = boxes
    for i, o in enumerate(o2):
        fi = np.flatnonzero((lo0 <= o[0]) & (o[0] <= hi0) & (lo1 <= o[1]) & (o[1] <= hi1))
        tri = V[F[fi]]
        hits.keep_first(np.full(len(fi), i), np.arange(len(fi)), tri @ B, o2, tri, Orig, d, face_ids=fi)


class _Hits:
    """The nearest hit so far of each ray."""

    def __init__(self, n: int):
        self.hit = np.zeros(n, dtype=bool)
        self.pts = np.full((n, 3), np.nan)
        self.face = np.full(n, -1, dtype=np.int64)
        self.best_t = np.full(n, np.inf)

    def keep_first(self, qi: IntArray, fi: IntArray, t2: FloatArray, o2: FloatArray, tri: FloatArray,
                   Orig: FloatArray, d: FloatArray, face_ids: IntArray | None = None) -> None:
        """Test rays ``qi`` against candidate triangles ``fi`` (pairs; rows of ``tri``, the
        triangles, and ``t2``, their projections) and keep each ray's nearest hit in front of
        its origin, where nearer than the one kept. ``face_ids`` maps those rows to the mesh's
        faces (default: they are its faces)."""
        a, b, c = t2[fi, 0], t2[fi, 1], t2[fi, 2]
        v0, v1, v2 = b - a, c - a, o2[qi] - a
        den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = (v2[:, 0] * v1[:, 1] - v1[:, 0] * v2[:, 1]) / den
            v = (v0[:, 0] * v2[:, 1] - v2[:, 0] * v0[:, 1]) / den
        eps = 1e-12
        with np.errstate(invalid="ignore"):
            inside = (np.abs(den) > 0) & (u >= -eps) & (v >= -eps) & (u + v <= 1 + eps)
        qi, fi, u, v = qi[inside], fi[inside], u[inside], v[inside]
        T3 = tri[fi]
        X = T3[:, 0] + u[:, None] * (T3[:, 1] - T3[:, 0]) + v[:, None] * (T3[:, 2] - T3[:, 0])
        t = (X - Orig[qi]) @ d
        front = t >= 0
        qi, fi, X, t = qi[front], fi[front], X[front], t[front]
        order = np.lexsort((t, qi))
        qi, fi, X, t = qi[order], fi[order], X[order], t[order]
        first = np.concatenate([[True], qi[1:] != qi[:-1]]) if len(qi) else np.zeros(0, dtype=bool)
        qi, fi, X, t = qi[first], fi[first], X[first], t[first]
        better = t < self.best_t[qi]
        qi, fi, X, t = qi[better], fi[better], X[better], t[better]
        self.best_t[qi] = t
        self.hit[qi] = True
        self.pts[qi] = X
        self.face[qi] = fi if face_ids is None else face_ids[fi]

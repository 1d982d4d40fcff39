"""Exact closest points on a triangle mesh, for many points at once.

This is the inner loop of every localization algorithm: given query points in the mesh's
frame, find for each the nearest point on the surface (the *foot*), the face it lies on,
the distance and the outward face normal there.

Why not ``trimesh.proximity.closest_point``: trimesh 5.2 decides the Voronoi region of the
triangle with absolute tolerances (an absolute 1e-13 on products of squared edge lengths),
which puts points in the wrong region on metre-scale meshes with millimetre triangles: of
2,000 points sampled on a 19k-face, 150 mm part, 21 % got a "closest point" up to 0.17 mm
away (``tests/test_closest_point.py`` checks exactness on points sampled on the mesh). Here the point-triangle test is
Ericson's (Real-Time Collision Detection, 5.1.5): only sign tests on dot products, no
tolerance, so it is invariant to the scale of the mesh.

Two backends give the same answers (exact; only the face chosen between faces at exactly
equal distance may differ):

``numba`` (used when numba is installed): a bounding-volume hierarchy over the triangles
(median splits, 4 triangles a leaf) searched per point with best-first pruning by box
distance, on one thread per core above a few thousand points. With a ``hint`` (the previous iteration's
face of each point) the search starts at the hint's leaf with the hint's distance as bound
and walks up, visiting the sibling of each node on the way only where its box is closer than
the best so far: exact, and about twice as fast as a search from the root.

``numpy`` (fallback): a KD-tree over sample points, as follows.

* At build time every face gets one or more *sample points* on it (the centroids of an
  ``m x m`` subdivision of the face, ``m`` chosen so that every point of the face lies within
  ``radius`` of one of its samples). The samples go into a ``scipy.spatial.cKDTree``.
* A query asks the tree for the ``k`` nearest samples and computes the exact distance to
  their faces; call the best ``d_best``. Any face ``f`` not among them has all its samples
  at least ``d_k`` (the k-th neighbour distance) away, so its distance is at least
  ``d_k - radius``. If ``d_k - radius >= d_best`` the answer is proven; otherwise the point is
  re-asked with more neighbours and, at the last resort, with every sample within
  ``d_best + radius`` (a ball query). The answer is exact in every case, not approximate.

Units follow the mesh (metres in this project).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import ModuleType

import numpy as np
from scipy.spatial import cKDTree

from algorithms.errors import AlgorithmError

_nb: ModuleType | None
try:  # optional: compiled kernels (about 10-50x faster); results are identical
    import numba as _nb
except ImportError:  # pragma: no cover - depends on the environment
    _nb = None
HAVE_NUMBA = _nb is not None

__all__ = ["ClosestPoints", "MeshIndex", "NearFaces", "PARALLEL_MIN_POINTS", "closest_points_on_triangles",
           "compile_kernels", "query_kernels", "kernels_cached"]

# Neighbour counts tried before the ball query (points near the surface need few).
_K_STAGES = (8, 48)
#: Faces each point keeps in its :class:`NearFaces` list (the foot's face and its neighbours).
NEAR_K = 4
#: From this many points on, a query uses every core (threads cost more than they save
# for a few hundred points).
PARALLEL_MIN_POINTS = 4000


@dataclass(frozen=True)
class ClosestPoints:
    """Closest points on a mesh for N query points (all in the mesh's frame).

    Attributes:
        foot: (N, 3) [m] nearest point on the surface.
        distance: (N,) [m] unsigned distance from the query to ``foot``.
        face: (N,) int index of the face ``foot`` lies on (one of them when it is on an edge).
        normal: (N, 3) unit outward normal of ``face`` (by the winding of the mesh).
        rel_error: 0 for exact closest points; else each ``distance`` is within
            ``(1 + rel_error)`` of the exact one (its foot on a face that near; see
            :meth:`MeshIndex.query`).
    """

    foot: np.ndarray
    distance: np.ndarray
    face: np.ndarray
    normal: np.ndarray
    rel_error: float = 0.0

    def plane_residual(self, points: np.ndarray) -> np.ndarray:
        """(N,) [m] ``<points - foot, normal>``: signed point-to-tangent-plane residual."""
        return np.einsum("ij,ij->i", np.asarray(points, dtype=np.float64) - self.foot, self.normal)


@dataclass
class NearFaces:
    """Each point's nearest faces, kept between queries: a certificate that lets a point that
    moved a little be answered from its own short list, exactly.

    For a point ``p`` that has moved ``delta = |p - anchor|`` since its list was found, every
    face outside the first ``j + 1`` of its list is at least ``reach[j] - delta`` from ``p``
    (triangle inequality). So once the nearest of the first ``j + 1`` faces is within
    ``reach[j] - delta`` it is the nearest face of the mesh: usually after one or two
    point-triangle tests. When no ``j`` certifies, the point's list is found again by the
    tree. Mutable: updated in place by :meth:`MeshIndex.query_near`.

    Attributes:
        anchor: (N, 3) [m] where each point's list was found (mesh frame).
        faces: (N, K) int64 the K faces nearest to ``anchor``, nearest first (-1 pads a mesh
            with fewer faces).
        reach: (N, K) [m] every face not among ``faces[:, :j + 1]`` is at least ``reach[:, j]``
            from ``anchor`` (inf when the list holds every face; -inf: no list yet).
        n_rebuilt: how many points the last query had to look up in the tree.
    """

    anchor: np.ndarray
    faces: np.ndarray
    reach: np.ndarray
    n_rebuilt: int = 0


def closest_points_on_triangles(points: np.ndarray, triangles: np.ndarray):
    """Exact closest point on each triangle to each point (pairwise, Ericson 5.1.5).

    Args:
        points: (P, 3) query points.
        triangles: (P, 3, 3) triangle vertices ``a, b, c`` paired with ``points``.

    Returns:
        (foot (P, 3), squared distance (P,)).
    """
    points = np.asarray(points, dtype=np.float64)
    tri = np.asarray(triangles, dtype=np.float64)
    a = tri[:, 0]
    ab = tri[:, 1] - a
    ac = tri[:, 2] - a
    abab = np.einsum("ij,ij->i", ab, ab)
    acac = np.einsum("ij,ij->i", ac, ac)
    abac = np.einsum("ij,ij->i", ab, ac)
    ap = points - a
    v, w = _barycentric(
        np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap), abab, acac, abac
    )
    diff = ap - v[:, None] * ab - w[:, None] * ac
    return points - diff, np.einsum("ij,ij->i", diff, diff)


def _barycentric(d1, d2, abab, acac, abac):
    """Barycentric (v, w) of the closest point ``a + v ab + w ac`` (Ericson's regions).

    ``d1 = ab.ap``, ``d2 = ac.ap``; the other dot products follow from the face constants:
    ``d3 = ab.bp = d1 - abab``, ``d4 = ac.bp = d2 - abac``, ``d5 = ab.cp = d1 - abac``,
    ``d6 = ac.cp = d2 - acac``. Region tests are pure sign tests (scale invariant); the
    order of the ``np.where`` calls reproduces Ericson's early returns (later = higher
    priority).
    """
    d3 = d1 - abab
    d4 = d2 - abac
    d5 = d1 - abac
    d6 = d2 - acac
    vc = d1 * d4 - d3 * d2
    vb = d5 * d2 - d1 * d6
    va = d3 * d6 - d5 * d4
    with np.errstate(divide="ignore", invalid="ignore"):
        # interior (face region)
        den = va + vb + vc
        v = vb / den
        w = vc / den
        # edge BC
        e43 = d4 - d3
        e56 = d5 - d6
        m = (va <= 0) & (e43 >= 0) & (e56 >= 0)
        t = e43 / (e43 + e56)
        v = np.where(m, 1.0 - t, v)
        w = np.where(m, t, w)
        # vertex C
        m = (d6 >= 0) & (d5 <= d6)
        v = np.where(m, 0.0, v)
        w = np.where(m, 1.0, w)
        # edge AC
        m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        v = np.where(m, 0.0, v)
        w = np.where(m, d2 / (d2 - d6), w)
        # edge AB
        m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        v = np.where(m, d1 / (d1 - d3), v)
        w = np.where(m, 0.0, w)
        # vertex B
        m = (d3 >= 0) & (d4 <= d3)
        v = np.where(m, 1.0, v)
        w = np.where(m, 0.0, w)
        # vertex A
        m = (d1 <= 0) & (d2 <= 0)
        v = np.where(m, 0.0, v)
        w = np.where(m, 0.0, w)
    # Degenerate (zero-area) faces can leave 0/0 in a region no test claimed; any point of
    # the face is then as good as its edges, which other tests cover: fall back to vertex A.
    bad = ~(np.isfinite(v) & np.isfinite(w))
    if bad.any():
        v = np.where(bad, 0.0, v)
        w = np.where(bad, 0.0, w)
    return v, w


_compiled = False


def query_kernels():
    """The compiled query kernels, for other compiled functions (None without numba):
    ``tree(q, hints, *arrays, out_face, out_foot, out_dist, out_normal, shrink)`` answers
    :meth:`MeshIndex.query` (``hints`` -1 for none, ``shrink = 1 / (1 + rel_error)^2``) and
    ``near(q, anchor, faces, reach, *arrays, out_face, out_foot, out_dist, out_normal, rebuilt)``
    :meth:`MeshIndex.query_near` (the lists updated in place), ``arrays`` those of
    :meth:`MeshIndex.kernel_arrays`."""
    if _nb is None:
        return None
    return _nb_query_serial, _nb_near_serial


def kernels_cached(kernels=None) -> bool | None:
    """Whether numba's on-disk cache holds the given compiled functions (default: every
    closest-point kernel) for their current source (None: cannot tell, numba's cache layout
    being private)."""
    try:
        return all(bool(k._cache._cache_file._load_index()) for k in (kernels or _KERNELS))
    except Exception:  # pragma: no cover - depends on numba's internals
        return None


def compile_kernels(announce=True) -> float:
    """Compile (or load from numba's cache) every closest-point kernel now, and return the
    seconds it took.

    Numba compiles the kernels on their first call and caches them on disk (``cache=True``),
    so only the first run of an installation pays the compilation (see
    ``benchmarks/results_speed.md`` for the time measured; loading the cache takes well under
    a second). :class:`MeshIndex` calls this on the
    first index a process builds; with ``announce`` it says on stderr that it is compiling
    when the cache does not hold the kernels (``twin warmup`` calls it at install time).
    """
    global _compiled
    if _nb is None or _compiled:
        return 0.0
    import sys
    import time

    t0 = time.perf_counter()
    if announce and kernels_cached() is False:
        print("compiling closest-point kernels, first run only ...", file=sys.stderr, flush=True)
    _compiled = True
    # one tetrahedron and one point: every kernel in the argument types of real calls
    vertices = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    faces = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])

    class _Tet:
        pass

    tet = _Tet()
    tet.vertices, tet.faces = vertices, faces  # type: ignore[attr-defined]
    index = MeshIndex(tet, backend="numba")
    q = np.array([[0.2, 0.2, 0.2], [2.0, 2.0, 2.0]])
    index._query_numba(q, None)
    index._query_near_numba(q, None)
    return time.perf_counter() - t0


def _in_chunks(run, n: int) -> None:
    """run(a, b) over [0, n): in one call below PARALLEL_MIN_POINTS, else in one chunk per core on
    threads (the compiled kernels release the GIL). Threads over a serial kernel instead of
    numba's parallel=True: the same speed here, and half the first-run compilation time."""
    workers = min(_pool_size(), -(-n // PARALLEL_MIN_POINTS))
    if workers <= 1:
        run(0, n)
        return
    bounds = np.linspace(0, n, workers + 1).astype(int)
    list(_pool().map(lambda k: run(bounds[k], bounds[k + 1]), range(workers)))


def _pool_size() -> int:
    import os

    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not on Linux
        return max(1, os.cpu_count() or 1)


_POOL = None


def _pool():
    global _POOL
    if _POOL is None:
        from concurrent.futures import ThreadPoolExecutor

        _POOL = ThreadPoolExecutor(max_workers=_pool_size(), thread_name_prefix="mesh_index")
    return _POOL


class MeshIndex:
    """A spatial index over a triangle mesh for exact closest-point queries.

    Build it once per mesh and reuse it: building costs about as much as a few thousand
    queries. Queries are thread-safe (the index is read-only after construction).

    Args:
        mesh: a ``trimesh.Trimesh`` (or anything with ``vertices`` (V, 3) and ``faces``
            (F, 3)), in the frame the queries will be given in.
        backend: ``"auto"`` (compiled BVH search when numba is installed, else numpy),
            ``"numba"`` or ``"numpy"``. Both are exact and give the same feet and
            distances; numba is 10-50x faster.

    Raises:
        AlgorithmError: no faces, non-finite vertices, face indices out of range, or an
            unknown/unavailable backend.
    """

    def __init__(self, mesh, backend: str = "auto"):
        if backend not in ("auto", "numba", "numpy"):
            raise AlgorithmError(f"backend must be 'auto', 'numba' or 'numpy', got {backend!r}")
        if backend == "numba" and _nb is None:
            raise AlgorithmError("backend 'numba' requested but numba is not installed (pip install numba)")
        if backend == "auto":
            backend = "numba" if _nb is not None else "numpy"
        self.backend = backend
        try:
            vertices = np.asarray(mesh.vertices, dtype=np.float64)
            faces = np.asarray(mesh.faces, dtype=np.int64)
        except AttributeError as exc:  # pragma: no cover - message only
            raise AlgorithmError(f"mesh must have vertices and faces, got {type(mesh).__name__}") from exc
        if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
            raise AlgorithmError(f"mesh must have at least one triangle face, got faces of shape {faces.shape}")
        if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) < 3:
            raise AlgorithmError(f"mesh vertices must be (V, 3) with V >= 3, got {vertices.shape}")
        if not np.all(np.isfinite(vertices)):
            raise AlgorithmError("mesh vertices contain NaN or infinite coordinates")
        if faces.min() < 0 or faces.max() >= len(vertices):
            raise AlgorithmError("mesh faces index vertices that do not exist")
        self.mesh = mesh
        self.vertices = vertices
        self.faces = faces
        tri = vertices[faces]
        a = tri[:, 0]
        ab = tri[:, 1] - a
        ac = tri[:, 2] - a
        cross = np.cross(ab, ac)
        area2 = np.linalg.norm(cross, axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            normals = cross / area2[:, None]
        normals[~np.isfinite(normals).all(axis=1)] = 0.0
        self.face_normals = normals
        self.n_faces = len(faces)
        # Per-face constants, packed so that one row gather fetches all a pair needs:
        # columns a(3) ab(3) ac(3) |ab|^2 |ac|^2 ab.ac
        self._data = np.empty((len(faces), 12))
        self._data[:, 0:3] = a
        self._data[:, 3:6] = ab
        self._data[:, 6:9] = ac
        self._data[:, 9] = np.einsum("ij,ij->i", ab, ab)
        self._data[:, 10] = np.einsum("ij,ij->i", ac, ac)
        self._data[:, 11] = np.einsum("ij,ij->i", ab, ac)

        # Sample points: centroids of an m x m subdivision of each face. Every point of a
        # sub-triangle is within (its largest centroid-vertex distance) of its centroid, and
        # all m^2 sub-triangles of a face are congruent (up to a point reflection), so the
        # covering radius of face f is r_f / m_f with r_f that of the whole face.
        centroid = tri.mean(axis=1)
        r_face = np.linalg.norm(tri - centroid[:, None, :], axis=2).max(axis=1)
        positive = r_face[r_face > 0]
        target = np.percentile(positive, 90) if len(positive) else 1.0
        m = np.maximum(1, np.ceil(r_face / target - 1e-12)).astype(np.int64)
        m = np.minimum(m, 64)  # a huge face among tiny ones: cap the sample count
        if self.backend == "numpy":
            samples, sample_face = _subdivision_centroids(tri, m)
            self.radius = float(np.max(r_face / m)) * (1.0 + 1e-9) + 1e-300
            self._sample_face = sample_face
            self._tree = cKDTree(samples, leafsize=16)
            self.n_samples = len(samples)
        else:
            compile_kernels()
            lo, hi, left, right, start, count, perm, up, leaf_of = _nb_build(
                tri.min(axis=1), tri.max(axis=1), centroid, _BVH_LEAF)
            inner = left >= 0
            assert np.array_equal(right[inner], left[inner] + 1)  # siblings are adjacent
            # The face constants in leaf order, so that a leaf's triangles are one contiguous
            # block (``perm`` maps a leaf slot back to its face), and the nodes packed
            # (see _pack_nodes).
            self._bvh = (np.ascontiguousarray(self._data[perm]),
                         *_pack_nodes(lo, hi, left, start, count, up, leaf_of, perm))
        scale = np.ptp(vertices, axis=0)
        self.extent = float(np.linalg.norm(scale))  # bounding-box diagonal [m]
        # median edge length [m]: the scale below which a point's nearest faces stay its
        # nearest faces (see query_near)
        self.face_size = float(np.median(np.linalg.norm(ab, axis=1))) if len(ab) else 0.0
        self._smooth: np.ndarray | None = None
        self._pseudo: tuple | None = None

    def __setstate__(self, state):
        """Unpickled (a worker process): the node records back in one aligned block (pickle
        copies the two views of it apart)."""
        self.__dict__.update(state)
        if getattr(self, "_bvh", None) is not None:
            leaf_data, _nodes_f, nodes_i, hint_map, perm = self._bvh
            nodes_f, packed = _node_records(len(nodes_i))
            packed[:] = nodes_i  # the whole records, boxes' bits included
            self._bvh = (leaf_data, nodes_f, packed, hint_map, perm)

    # ------------------------------------------------------------------ queries
    def query(self, points, hint=None, rel_error: float = 0.0) -> ClosestPoints:
        """Exact (or, with ``rel_error``, nearly exact) closest points on the mesh.

        Args:
            points: (N, 3) [m] query points, in the mesh's frame, finite.
            hint: optional (N,) face indices (e.g. the previous iteration's ``face``); a good
                hint makes the compiled search faster, and never changes the answer.
            rel_error: 0 (default): exact. > 0: each point's answer is a face within
                ``(1 + rel_error)`` times the exact distance (the search skips every box not
                nearer than ``best / (1 + rel_error)``); for points far from the mesh this
                visits a fraction of the leaves. The numpy backend answers exactly.

        Returns:
            ClosestPoints with foot (N, 3), distance (N,), face (N,), normal (N, 3) and the
            ``rel_error`` the answer honours.
        """
        q = np.asarray(points, dtype=np.float64)
        if q.ndim != 2 or q.shape[1] != 3:
            raise AlgorithmError(f"points must be (N, 3), got {q.shape}")
        n = len(q)
        if n == 0:
            return ClosestPoints(np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=np.int64), np.zeros((0, 3)))
        if not np.all(np.isfinite(q)):
            raise AlgorithmError("query points contain NaN or infinite coordinates")
        if not (math.isfinite(rel_error) and rel_error >= 0.0):
            raise AlgorithmError(f"rel_error must be a finite number >= 0, got {rel_error}")
        if self.backend == "numba":
            return self._query_numba(q, hint, rel_error)
        workers = -1 if n >= PARALLEL_MIN_POINTS else 1
        best_d2 = np.full(n, np.inf)
        best_face = np.zeros(n, dtype=np.int64)
        pending = np.arange(n)
        k_prev = 0
        for k in _K_STAGES:
            k = min(k, self.n_samples)
            qp = q[pending]
            dk, ik = self._tree.query(qp, k=k, workers=workers)
            if k == 1:
                dk = dk[:, None]
                ik = ik[:, None]
            faces = self._sample_face[ik[:, k_prev:]]
            d2, f = self._best_of(qp, faces)
            better = d2 < best_d2[pending]
            best_d2[pending[better]] = d2[better]
            best_face[pending[better]] = f[better]
            if k >= self.n_samples:
                pending = pending[:0]
                break
            # Proven when no sample beyond the k-th can belong to a closer face.
            bound = dk[:, -1] - self.radius
            cur = best_d2[pending]
            done = (cur == 0.0) | ((bound > 0) & (bound * bound >= cur))
            pending = pending[~done]
            k_prev = k
            if len(pending) == 0:
                break
        if len(pending):
            self._ball_stage(q, pending, best_d2, best_face, workers)
        return self._finish(q, best_face)

    def _query_numba(self, q, hint, rel_error=0.0):
        n = len(q)
        if hint is None:
            hints = np.full(n, -1, dtype=np.int64)
        else:
            hints = np.asarray(hint, dtype=np.int64).reshape(-1)
            if hints.shape != (n,):
                raise AlgorithmError(f"hint must be ({n},) face indices, got {hints.shape}")
            hints = np.where((hints >= 0) & (hints < self.n_faces), hints, -1)
        face = np.empty(n, dtype=np.int64)
        foot = np.empty((n, 3))
        dist = np.empty(n)
        normal = np.empty((n, 3))
        # writeable C arrays: the types the kernel was compiled (and cached) for
        q = np.require(q, requirements=("C", "W"))
        bvh = self._bvh
        normals = self.face_normals

        def run(a, b):
            _nb_query_serial(q[a:b], hints[a:b], self._data, *bvh, normals, face[a:b], foot[a:b],
                             dist[a:b], normal[a:b], 1.0 / (1.0 + rel_error) ** 2)

        _in_chunks(run, n)
        return ClosestPoints(foot=foot, distance=dist, face=face, normal=normal, rel_error=rel_error)

    def kernel_arrays(self) -> tuple:
        """``(data, leaf_data, nodes_f, nodes_i, hint_map, perm, normals)``: the
        arrays the compiled kernels of :func:`query_kernels` search, for compiled callers that
        run their own loop of queries (numba backend only)."""
        if self.backend != "numba":
            raise AlgorithmError("kernel_arrays needs the numba backend")
        return (self._data, *self._bvh, self.face_normals)

    def query_near(self, points, near: NearFaces | None = None) -> tuple[ClosestPoints, NearFaces]:
        """Exact closest points, answered from each point's list of nearest faces where the
        list's certificate holds (see :class:`NearFaces`), from the tree elsewhere.

        Meant for a sequence of queries of the same points as they move by small steps (the
        iterations of a registration): a point that stays within its certificate costs a
        handful of point-triangle tests instead of a tree search. The answers are those of
        :meth:`query` (exact; only the face chosen between faces at exactly equal distance
        may differ).

        Args:
            points: (N, 3) [m] query points, mesh frame, finite.
            near: the lists returned by the previous call for the same N points (updated in
                place), or None to find them for every point.

        Returns:
            (ClosestPoints, NearFaces).
        """
        q = np.require(np.asarray(points, dtype=np.float64), requirements=("C", "W"))
        if q.ndim != 2 or q.shape[1] != 3:
            raise AlgorithmError(f"points must be (N, 3), got {q.shape}")
        if not np.all(np.isfinite(q)):
            raise AlgorithmError("query points contain NaN or infinite coordinates")
        if self.backend != "numba" or len(q) == 0:
            return self._query_near_numpy(q, near)
        return self._query_near_numba(q, near)

    def _query_near_numpy(self, q, near):
        """The numpy backend keeps no lists: every query is a tree query."""
        n = len(q)
        cp = self.query(q)
        near = NearFaces(anchor=q.copy(), faces=np.full((n, NEAR_K), -1, np.int64),
                         reach=np.repeat(cp.distance[:, None], NEAR_K, axis=1))
        near.faces[:, 0] = cp.face
        near.n_rebuilt = n
        return cp, near

    def _query_near_numba(self, q, near):
        n = len(q)
        if near is None:
            near = NearFaces(anchor=np.zeros((n, 3)), faces=np.full((n, NEAR_K), -1, np.int64),
                             reach=np.full((n, NEAR_K), -np.inf))
        elif near.faces.shape[0] != n:
            raise AlgorithmError(f"near lists were made for {near.faces.shape[0]} points, got {n}")
        face = np.empty(n, dtype=np.int64)
        foot = np.empty((n, 3))
        dist = np.empty(n)
        normal = np.empty((n, 3))
        rebuilt = np.zeros(n, dtype=np.uint8)
        bvh = self._bvh
        normals = self.face_normals

        def run(a, b):
            _nb_near_serial(q[a:b], near.anchor[a:b], near.faces[a:b], near.reach[a:b], self._data,
                            *bvh, normals, face[a:b], foot[a:b], dist[a:b], normal[a:b], rebuilt[a:b])

        _in_chunks(run, n)
        near.n_rebuilt = int(rebuilt.sum())
        return ClosestPoints(foot=foot, distance=dist, face=face, normal=normal), near

    def _best_of(self, q, faces):
        """Exact nearest among candidate faces (n, c) for points q (n, 3)."""
        n, c = faces.shape
        flat = faces.reshape(-1)
        qq = np.repeat(q, c, axis=0)
        d2 = self._pair_d2(qq, flat).reshape(n, c)
        j = np.argmin(d2, axis=1)
        rows = np.arange(n)
        return d2[rows, j], faces[rows, j]

    def _pair_d2(self, q, flat):
        """Squared distance of each q[i] to face flat[i] (P,)."""
        g = self._data[flat]  # (P, 12) one row gather
        ax, ay, az = g[:, 0], g[:, 1], g[:, 2]
        bx, by, bz = g[:, 3], g[:, 4], g[:, 5]
        cx, cy, cz = g[:, 6], g[:, 7], g[:, 8]
        px = q[:, 0] - ax
        py = q[:, 1] - ay
        pz = q[:, 2] - az
        d1 = bx * px + by * py + bz * pz
        d2 = cx * px + cy * py + cz * pz
        v, w = _barycentric(d1, d2, g[:, 9], g[:, 10], g[:, 11])
        ex = px - v * bx - w * cx
        ey = py - v * by - w * cy
        ez = pz - v * bz - w * cz
        return ex * ex + ey * ey + ez * ez

    def _ball_stage(self, q, pending, best_d2, best_face, workers):
        """Last resort: every sample within d_best + radius of the point."""
        qp = q[pending]
        r = np.sqrt(best_d2[pending]) + self.radius
        lists = self._tree.query_ball_point(qp, r * (1.0 + 1e-12), workers=workers, return_sorted=False)
        counts = np.fromiter((len(x) for x in lists), dtype=np.int64, count=len(lists))
        if counts.sum() == 0:
            return
        idx = np.concatenate([np.asarray(x, dtype=np.int64) for x in lists if len(x)])
        owner = np.repeat(np.arange(len(pending)), counts)
        faces = self._sample_face[idx]
        d2 = self._pair_d2(qp[owner], faces)
        # minimum per owner: sort by (owner, d2) and take each owner's first
        order = np.lexsort((d2, owner))
        first = np.ones(len(order), dtype=bool)
        first[1:] = owner[order][1:] != owner[order][:-1]
        sel = order[first]
        o = owner[sel]
        better = d2[sel] < best_d2[pending[o]]
        best_d2[pending[o[better]]] = d2[sel][better]
        best_face[pending[o[better]]] = faces[sel][better]

    def _finish(self, q, face):
        g = self._data[face]
        a, ab, ac = g[:, 0:3], g[:, 3:6], g[:, 6:9]
        ap = q - a
        v, w = _barycentric(
            np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap), g[:, 9], g[:, 10], g[:, 11]
        )
        diff = ap - v[:, None] * ab - w[:, None] * ac
        foot = q - diff
        dist = np.sqrt(np.einsum("ij,ij->i", diff, diff))
        return ClosestPoints(foot=foot, distance=dist, face=face, normal=self.face_normals[face])

    # ------------------------------------------------------------ smooth normals
    def smooth_normals(self, face: np.ndarray, foot: np.ndarray) -> np.ndarray:
        """Unit normals of the underlying smooth surface at feet on given faces.

        Per-corner normals are angle-weighted means of the normals of the faces around the
        vertex that are within 30 degrees of the face's own normal (a crease angle, so sharp
        CAD edges stay sharp), interpolated barycentrically over the face. On a tessellated
        cylinder or sphere they are radial, so the observability test sees the true surface,
        not the facets.

        Args:
            face: (N,) face indices.
            foot: (N, 3) points on those faces.
        """
        if self._smooth is None:
            self._smooth = _corner_normals(self.vertices, self.faces, self.face_normals)
        face = np.asarray(face, dtype=np.int64)
        v, w = self._barycentric(face, foot)
        v, w = np.clip(v, 0.0, 1.0), np.clip(w, 0.0, 1.0)
        cn = self._smooth[face]  # (N, 3 corners, 3)
        n = (1.0 - v - w)[:, None] * cn[:, 0] + v[:, None] * cn[:, 1] + w[:, None] * cn[:, 2]
        norm = np.sqrt(np.einsum("ij,ij->i", n, n))
        good = norm > 1e-12
        out = np.where(good[:, None], n / np.where(good, norm, 1.0)[:, None], self.face_normals[face])
        return out

    def _barycentric(self, face: np.ndarray, foot) -> tuple[np.ndarray, np.ndarray]:
        """Barycentric (v, w) of feet on their faces (the 2x2 Gram system; 0 on a degenerate face)."""
        g = self._data[face]
        ap = np.asarray(foot, dtype=np.float64) - g[:, 0:3]
        d1 = np.einsum("ij,ij->i", g[:, 3:6], ap)
        d2 = np.einsum("ij,ij->i", g[:, 6:9], ap)
        abab, acac, abac = g[:, 9], g[:, 10], g[:, 11]
        det = abab * acac - abac * abac
        with np.errstate(divide="ignore", invalid="ignore"):
            v = (acac * d1 - abac * d2) / det
            w = (abab * d2 - abac * d1) / det
        ok = np.isfinite(v) & np.isfinite(w)
        return np.where(ok, v, 0.0), np.where(ok, w, 0.0)

    def signed_distance(self, points) -> np.ndarray:
        """(N,) distance to the surface [m], negative inside the (closed) model.

        The sign is that of ``(point - foot) . pseudonormal`` with the angle-weighted
        pseudonormal of the feature the foot lies on (Baerentzen and Aanaes, 2005): the face
        normal inside a face, the sum of the two face normals on an edge, the angle-weighted
        vertex normal at a vertex. Unlike the normal of whichever face the foot was found on,
        this is correct near edges and corners.
        """
        q = np.asarray(points, dtype=np.float64)
        cp = self.query(q)
        if self._pseudo is None:
            self._pseudo = _pseudonormals(self.vertices, self.faces, self.face_normals)
        corner_pn, edge_pn = self._pseudo
        v, w = self._barycentric(cp.face, cp.foot)
        bary = np.column_stack([1.0 - v - w, v, w])
        on_zero = bary <= _FEATURE_TOL
        n = self.face_normals[cp.face].copy()
        zeros = on_zero.sum(axis=1)
        edge = zeros == 1               # the foot is on the edge opposite the zero corner
        n[edge] = edge_pn[cp.face[edge], np.argmax(on_zero[edge], axis=1)]
        vert = zeros >= 2               # at the corner whose coordinate is not zero
        n[vert] = corner_pn[cp.face[vert], np.argmin(on_zero[vert], axis=1)]
        sign = np.einsum("ij,ij->i", q - cp.foot, n)
        return np.where(sign < 0.0, -cp.distance, cp.distance)


_FEATURE_TOL = 1e-9   # a barycentric coordinate this small puts the foot on an edge or corner


def _pseudonormals(vertices, faces, face_normals):
    """Angle-weighted vertex pseudonormals per (face, corner) and edge pseudonormals per
    (face, edge opposite the corner): (F, 3, 3) each, unnormalised directions."""
    corner = _corner_normals(vertices, faces, face_normals, crease_deg=180.0)
    F = len(faces)
    # the edge opposite corner c of face f joins corners c+1 and c+2
    a = np.concatenate([faces[:, 1], faces[:, 2], faces[:, 0]])
    b = np.concatenate([faces[:, 2], faces[:, 0], faces[:, 1]])
    key = np.minimum(a, b).astype(np.int64) * (len(vertices) + 1) + np.maximum(a, b)
    owner = np.tile(np.arange(F), 3)
    slot = np.repeat(np.arange(3), F)
    order = np.argsort(key, kind="stable")
    ks = key[order]
    edge = face_normals[owner].copy()
    same_next = np.flatnonzero(ks[1:] == ks[:-1])
    i, j = order[same_next], order[same_next + 1]
    edge[i] += face_normals[owner[j]]
    edge[j] += face_normals[owner[i]]
    edge_pn = np.empty((F, 3, 3))
    edge_pn[owner, slot] = edge
    return corner, edge_pn


def _subdivision_centroids(tri: np.ndarray, m: np.ndarray):
    """Centroids of the m^2 sub-triangles of each face (barycentric grid of level m)."""
    samples = []
    owners = []
    for level in np.unique(m):
        sel = np.nonzero(m == level)[0]
        # barycentric coordinates (u, v) of the sub-triangle centroids
        uv = []
        for i in range(level):
            for j in range(level - i):
                # upright sub-triangle (i, j), (i+1, j), (i, j+1)
                uv.append(((3 * i + 1) / (3 * level), (3 * j + 1) / (3 * level)))
                if i + j < level - 1:
                    # inverted sub-triangle (i+1, j), (i, j+1), (i+1, j+1)
                    uv.append(((3 * i + 2) / (3 * level), (3 * j + 2) / (3 * level)))
        bary = np.asarray(uv)
        t = tri[sel]
        a = t[:, 0]
        pts = (
            a[:, None, :]
            + bary[None, :, 0, None] * (t[:, 1] - a)[:, None, :]
            + bary[None, :, 1, None] * (t[:, 2] - a)[:, None, :]
        )
        samples.append(pts.reshape(-1, 3))
        owners.append(np.repeat(sel, len(bary)))
    return np.concatenate(samples), np.concatenate(owners)


def _corner_normals(vertices, faces, face_normals, crease_deg: float = 30.0):
    """(F, 3, 3) per-corner normals: angle-weighted, crease-limited vertex normals."""
    tri = vertices[faces]
    # interior angle at each corner
    ang = np.empty((len(faces), 3))
    for c in range(3):
        e1 = tri[:, (c + 1) % 3] - tri[:, c]
        e2 = tri[:, (c + 2) % 3] - tri[:, c]
        cosang = np.einsum("ij,ij->i", e1, e2) / np.maximum(
            np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1), 1e-300
        )
        ang[:, c] = np.arccos(np.clip(cosang, -1.0, 1.0))
    # incidence: (vertex, face, corner) sorted by vertex
    vert = faces.reshape(-1)
    fidx = np.repeat(np.arange(len(faces)), 3)
    order = np.argsort(vert, kind="stable")
    vert_s = vert[order]
    f_s = fidx[order]
    starts = np.searchsorted(vert_s, np.arange(len(vertices)))
    ends = np.searchsorted(vert_s, np.arange(len(vertices)), side="right")
    deg = ends - starts
    # all pairs (corner owner face f, neighbour face g) sharing the vertex
    pair_vert = np.repeat(vert_s, deg[vert_s])
    pair_f = np.repeat(f_s, deg[vert_s])
    run_start = np.cumsum(deg[vert_s]) - deg[vert_s]   # each (vertex, f)'s first pair
    offs = np.arange(len(pair_vert)) - np.repeat(run_start, deg[vert_s])
    incidence = starts[pair_vert] + offs          # position of (vertex, g) in the sorted list
    pair_g = f_s[incidence]
    cos_crease = np.cos(np.radians(crease_deg))
    keep = np.einsum("ij,ij->i", face_normals[pair_f], face_normals[pair_g]) >= cos_crease
    # angle of face g at this vertex (element i of faces.reshape(-1) is corner i % 3)
    wgt = ang.reshape(-1)[order[incidence]] * keep
    # the pairs of one (vertex, f) are contiguous: sum each run
    acc = np.add.reduceat(wgt[:, None] * face_normals[pair_g], run_start, axis=0)
    # back to (face, corner) order
    corner_of_f = order % 3
    out = np.zeros((len(faces), 3, 3))
    out[f_s, corner_of_f] = acc
    norm = np.linalg.norm(out, axis=2, keepdims=True)
    fallback = np.broadcast_to(face_normals[:, None, :], out.shape)
    return np.where(norm > 1e-300, out / np.maximum(norm, 1e-300), fallback)


# ---------------------------------------------------------------------------------------
# Compiled path (numba): a bounding-volume hierarchy over the triangles, searched per point
# with best-first pruning. Same Ericson test, same regions, so the same answers as the
# numpy path (ties between faces at equal distance may pick a different face).
# ---------------------------------------------------------------------------------------
_BVH_LEAF = 4
_STACK = 128


def _node_records(n: int):
    """(float32, int32) views of n new 32-byte records, 64-byte aligned: records 2k and
    2k + 1 share a cache line."""
    raw = np.zeros(n * 32 + 64, np.uint8)
    off = (-raw.ctypes.data) % 64
    buf = raw[off : off + n * 32]
    return buf.view(np.float32).reshape(n, 8), buf.view(np.int32).reshape(n, 8)


def _pack_nodes(lo, hi, left, start, count, up, leaf_of, perm):
    """The tree's nodes in 32-byte records, two to a 64-byte cache line: a node and its
    sibling share a line, so the hinted queries' walk from a leaf to the root (one sibling box
    a level) reads one line a level instead of four rows of four arrays.

    Record ``r`` (node ``r - 1`` of :func:`_nb_build`; record 0 unused, so that siblings are
    the pairs ``(2k, 2k + 1)`` and a node's sibling is ``r ^ 1``; the root is record 1):
    ``nodes_f[r, 0:6]`` the box (lower, upper corner) in float32, rounded outwards so that
    the distance to it stays a lower bound; ``nodes_i[r, 6]`` the first child's record, or
    for a leaf ``-(8 start + count) - 1`` (its slots in the leaf order); ``nodes_i[r, 7]`` the
    parent's record (0 at the root). ``nodes_f`` and ``nodes_i`` are two views of the same
    memory. ``hint_map[f]``: face f's slot in the leaf order and its leaf's record.

    Returns (nodes_f, nodes_i, hint_map, perm)."""
    n = len(lo)
    if 8 * len(perm) + 8 >= 2**31:
        raise AlgorithmError(f"meshes of up to {2**28 - 1} faces are supported, got {len(perm)}")
    nodes_f, nodes_i = _node_records(n + 1)
    lo32 = lo.astype(np.float32)
    hi32 = hi.astype(np.float32)
    lo32 = np.where(lo32.astype(np.float64) > lo, np.nextafter(lo32, np.float32(-np.inf)), lo32)
    hi32 = np.where(hi32.astype(np.float64) < hi, np.nextafter(hi32, np.float32(np.inf)), hi32)
    nodes_f[0, 0:3] = np.inf
    nodes_f[0, 3:6] = -np.inf
    nodes_f[1:, 0:3] = lo32
    nodes_f[1:, 3:6] = hi32
    nodes_i[1:, 6] = np.where(left >= 0, left + 1, -(8 * start + count) - 1)
    nodes_i[1:, 7] = up + 1  # the root's -1 becomes 0
    slot = np.empty(len(perm), np.int64)
    slot[perm] = np.arange(len(perm))
    hint_map = np.empty((len(perm), 2), np.int32)
    hint_map[:, 0] = slot
    hint_map[:, 1] = leaf_of + 1
    return nodes_f, nodes_i, hint_map, perm

if _nb is not None:

    @_nb.njit(cache=True, nogil=True, inline="always")
    def _nb_tri(px, py, pz, data, f):  # pragma: no cover - compiled
        ax = data[f, 0]
        ay = data[f, 1]
        az = data[f, 2]
        bx = data[f, 3]
        by = data[f, 4]
        bz = data[f, 5]
        cx = data[f, 6]
        cy = data[f, 7]
        cz = data[f, 8]
        apx = px - ax
        apy = py - ay
        apz = pz - az
        d1 = bx * apx + by * apy + bz * apz
        d2 = cx * apx + cy * apy + cz * apz
        v = 0.0
        w = 0.0
        if d1 <= 0.0 and d2 <= 0.0:
            pass
        else:
            d3 = d1 - data[f, 9]
            d4 = d2 - data[f, 11]
            if d3 >= 0.0 and d4 <= d3:
                v = 1.0
            else:
                vc = d1 * d4 - d3 * d2
                if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
                    v = d1 / (d1 - d3)
                else:
                    d5 = d1 - data[f, 11]
                    d6 = d2 - data[f, 10]
                    if d6 >= 0.0 and d5 <= d6:
                        w = 1.0
                    else:
                        vb = d5 * d2 - d1 * d6
                        if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
                            w = d2 / (d2 - d6)
                        else:
                            va = d3 * d6 - d5 * d4
                            e43 = d4 - d3
                            e56 = d5 - d6
                            if va <= 0.0 and e43 >= 0.0 and e56 >= 0.0:
                                t = e43 / (e43 + e56)
                                v = 1.0 - t
                                w = t
                            else:
                                den = va + vb + vc
                                if den != 0.0:
                                    v = vb / den
                                    w = vc / den
        ex = apx - v * bx - w * cx
        ey = apy - v * by - w * cy
        ez = apz - v * bz - w * cz
        return ex * ex + ey * ey + ez * ez, v, w

    @_nb.njit(cache=True, nogil=True, inline="always")
    def _nb_box_d2(px, py, pz, nodes_f, r):  # pragma: no cover - compiled
        dx = max(np.float64(nodes_f[r, 0]) - px, 0.0, px - np.float64(nodes_f[r, 3]))
        dy = max(np.float64(nodes_f[r, 1]) - py, 0.0, py - np.float64(nodes_f[r, 4]))
        dz = max(np.float64(nodes_f[r, 2]) - pz, 0.0, pz - np.float64(nodes_f[r, 5]))
        return dx * dx + dy * dy + dz * dz

    @_nb.njit(cache=True, nogil=True)
    def _nb_build(tri_lo, tri_hi, cen, leaf):  # pragma: no cover - compiled
        nf = cen.shape[0]
        perm = np.arange(nf)
        maxn = 2 * nf + 1
        lo = np.empty((maxn, 3))
        hi = np.empty((maxn, 3))
        left = np.full(maxn, -1, np.int64)
        right = np.full(maxn, -1, np.int64)
        start = np.zeros(maxn, np.int64)
        count = np.zeros(maxn, np.int64)
        stack = np.empty(maxn, np.int64)
        count[0] = nf
        n_nodes = 1
        sp = 1
        stack[0] = 0
        while sp > 0:
            sp -= 1
            node = stack[sp]
            s = start[node]
            c = count[node]
            for k in range(3):
                lo[node, k] = np.inf
                hi[node, k] = -np.inf
            clo = np.full(3, np.inf)
            chi = np.full(3, -np.inf)
            for j in range(s, s + c):
                f = perm[j]
                for k in range(3):
                    lo[node, k] = min(lo[node, k], tri_lo[f, k])
                    hi[node, k] = max(hi[node, k], tri_hi[f, k])
                    clo[k] = min(clo[k], cen[f, k])
                    chi[k] = max(chi[k], cen[f, k])
            if c <= leaf:
                continue
            axis = 0
            if chi[1] - clo[1] > chi[axis] - clo[axis]:
                axis = 1
            if chi[2] - clo[2] > chi[axis] - clo[axis]:
                axis = 2
            seg = perm[s : s + c].copy()
            keys = np.empty(c)
            for j in range(c):
                keys[j] = cen[seg[j], axis]
            order = np.argsort(keys)
            for j in range(c):
                perm[s + j] = seg[order[j]]
            mid = c // 2
            lft = n_nodes
            rgt = n_nodes + 1
            n_nodes += 2
            start[lft] = s
            count[lft] = mid
            start[rgt] = s + mid
            count[rgt] = c - mid
            left[node] = lft
            right[node] = rgt
            stack[sp] = lft
            stack[sp + 1] = rgt
            sp += 2
        up = np.full(n_nodes, -1, np.int64)
        leaf_of = np.empty(nf, np.int64)
        for node in range(n_nodes):
            if left[node] >= 0:
                up[left[node]] = node
                up[right[node]] = node
            else:
                for j in range(start[node], start[node] + count[node]):
                    leaf_of[perm[j]] = node
        return (lo[:n_nodes].copy(), hi[:n_nodes].copy(), left[:n_nodes].copy(), right[:n_nodes].copy(),
                start[:n_nodes].copy(), count[:n_nodes].copy(), perm, up, leaf_of)

    @_nb.njit(cache=True, nogil=True, inline="always")
    def _nb_descend(px, py, pz, root, best, bestj, leaf_data, nodes_f, nodes_i, stack, stack_lb,
                    shrink):  # pragma: no cover - compiled
        """Best-first search of the subtree at record ``root``; returns the improved (best,
        slot)."""
        stack[0] = root
        stack_lb[0] = _nb_box_d2(px, py, pz, nodes_f, root)
        sp = 1
        while sp > 0:
            sp -= 1
            if stack_lb[sp] >= best * shrink:
                continue
            r = stack[sp]
            c = nodes_i[r, 6]
            if c < 0:
                code = -c - 1
                s = code >> 3
                for j in range(s, s + (code & 7)):
                    d2, _v, _w = _nb_tri(px, py, pz, leaf_data, j)
                    if d2 < best:
                        best = d2
                        bestj = j
            else:
                dl = _nb_box_d2(px, py, pz, nodes_f, c)
                dr = _nb_box_d2(px, py, pz, nodes_f, c + 1)
                # push the farther child first so the nearer is searched first
                if dl <= dr:
                    if dr < best * shrink:
                        stack[sp] = c + 1
                        stack_lb[sp] = dr
                        sp += 1
                    if dl < best * shrink:
                        stack[sp] = c
                        stack_lb[sp] = dl
                        sp += 1
                else:
                    if dl < best * shrink:
                        stack[sp] = c
                        stack_lb[sp] = dl
                        sp += 1
                    if dr < best * shrink:
                        stack[sp] = c + 1
                        stack_lb[sp] = dr
                        sp += 1
        return best, bestj

    @_nb.njit(cache=True, nogil=True, inline="always")
    def _nb_out(i, px, py, pz, tri, j, f, normals, out_face, out_foot, out_dist,
                out_normal):  # pragma: no cover - compiled
        """Write point i's answer: face f, whose constants are row j of tri (the face-order
        or the leaf-order table)."""
        d2, v, w = _nb_tri(px, py, pz, tri, j)
        out_face[i] = f
        out_dist[i] = np.sqrt(d2)
        for k in range(3):
            out_foot[i, k] = tri[j, k] + v * tri[j, 3 + k] + w * tri[j, 6 + k]
            out_normal[i, k] = normals[f, k]

    @_nb.njit(cache=True, nogil=True, inline="always")
    def _nb_one(i, q, hints, leaf_data, nodes_f, nodes_i, hint_map, perm, normals, out_face, out_foot,
                out_dist, out_normal, stack, stack_lb, shrink):  # pragma: no cover - compiled
        px = q[i, 0]
        py = q[i, 1]
        pz = q[i, 2]
        h = hints[i]
        # Bottom-up from the hint's leaf: every subtree off the leaf-to-root path is the
        # sibling of a node on it, so visiting each sibling (pruned by its box) is exact, and
        # with the hint's distance as the bound most siblings cost one box test. Without a
        # hint: the whole tree from the root. (One call site of _nb_descend: it is inlined.)
        best = np.inf
        bestj = -1
        r = 1
        if h >= 0:
            bestj = hint_map[h, 0]
            best, _v, _w = _nb_tri(px, py, pz, leaf_data, bestj)
            r = hint_map[h, 1]
        sub = r
        while True:
            if sub > 0:
                best, bestj = _nb_descend(px, py, pz, sub, best, bestj, leaf_data, nodes_f, nodes_i,
                                          stack, stack_lb, shrink)
            if r == 1:
                break
            sib = r ^ 1
            sub = sib if _nb_box_d2(px, py, pz, nodes_f, sib) < best * shrink else 0
            r = nodes_i[r, 7]
        _nb_out(i, px, py, pz, leaf_data, bestj, perm[bestj], normals, out_face, out_foot, out_dist,
                out_normal)

    @_nb.njit(cache=True, nogil=True)
    def _nb_query_serial(q, hints, data, leaf_data, nodes_f, nodes_i, hint_map, perm, normals,
                         out_face, out_foot, out_dist, out_normal, shrink):  # pragma: no cover
        stack = np.empty(_STACK, np.int64)
        stack_lb = np.empty(_STACK)
        for i in range(q.shape[0]):
            _nb_one(i, q, hints, leaf_data, nodes_f, nodes_i, hint_map, perm, normals, out_face, out_foot,
                    out_dist, out_normal, stack, stack_lb, shrink)

    @_nb.njit(cache=True, nogil=True, inline="always")
    def _nb_descend_k(px, py, pz, root, kd2, kj, m, leaf_data, nodes_f, nodes_i, stack,
                      stack_lb):  # pragma: no cover - compiled
        """Best-first search of the subtree at record ``root`` for the K nearest faces:
        ``kd2``/``kj`` (K,) hold the ``m`` nearest found so far (leaf slots), ascending; returns
        the new ``m``."""
        kk = kd2.shape[0]
        stack[0] = root
        stack_lb[0] = _nb_box_d2(px, py, pz, nodes_f, root)
        sp = 1
        while sp > 0:
            sp -= 1
            bnd = kd2[kk - 1] if m == kk else np.inf
            if stack_lb[sp] >= bnd:
                continue
            r = stack[sp]
            c = nodes_i[r, 6]
            if c < 0:
                code = -c - 1
                s = code >> 3
                for j in range(s, s + (code & 7)):
                    d2, _v, _w = _nb_tri(px, py, pz, leaf_data, j)
                    if m == kk and d2 >= kd2[kk - 1]:
                        continue
                    pos = m if m < kk else kk - 1
                    while pos > 0 and kd2[pos - 1] > d2:
                        kd2[pos] = kd2[pos - 1]
                        kj[pos] = kj[pos - 1]
                        pos -= 1
                    kd2[pos] = d2
                    kj[pos] = j
                    if m < kk:
                        m += 1
            else:
                dl = _nb_box_d2(px, py, pz, nodes_f, c)
                dr = _nb_box_d2(px, py, pz, nodes_f, c + 1)
                if dl <= dr:
                    if dr < bnd:
                        stack[sp] = c + 1
                        stack_lb[sp] = dr
                        sp += 1
                    if dl < bnd:
                        stack[sp] = c
                        stack_lb[sp] = dl
                        sp += 1
                else:
                    if dl < bnd:
                        stack[sp] = c
                        stack_lb[sp] = dl
                        sp += 1
                    if dr < bnd:
                        stack[sp] = c + 1
                        stack_lb[sp] = dr
                        sp += 1
        return m

    @_nb.njit(cache=True, nogil=True, inline="always")
    def _nb_near_one(i, q, anchor, faces, reach, data, leaf_data, nodes_f, nodes_i, hint_map, perm,
                     normals, out_face, out_foot, out_dist, out_normal, rebuilt, kd2, kj,
                     stack, stack_lb):  # pragma: no cover - compiled
        px = q[i, 0]
        py = q[i, 1]
        pz = q[i, 2]
        kk = faces.shape[1]
        dx = px - anchor[i, 0]
        dy = py - anchor[i, 1]
        dz = pz - anchor[i, 2]
        moved = np.sqrt(dx * dx + dy * dy + dz * dz)
        best = np.inf
        bestf = -1
        certified = False
        for j in range(kk):
            f = faces[i, j]
            if f < 0:
                certified = bestf >= 0  # the list holds every face of the mesh
                break
            d2, _v, _w = _nb_tri(px, py, pz, data, f)
            if d2 < best:
                best = d2
                bestf = f
            slack = reach[i, j] - moved
            if slack >= 0.0 and best <= slack * slack:
                certified = True
                break
        tri = data  # certified: the list's face, from the face-order table
        row = bestf
        if not certified:
            # the certificate fails: the K nearest faces here, from the tree (walking up from
            # the list's best face when there is one, as in _nb_one; from the root otherwise)
            m = 0
            r = hint_map[bestf, 1] if bestf >= 0 else 1
            sub = r
            while True:  # as in _nb_one, with one call site
                if sub > 0:
                    m = _nb_descend_k(px, py, pz, sub, kd2, kj, m, leaf_data, nodes_f, nodes_i, stack,
                                      stack_lb)
                if r == 1:
                    break
                sib = r ^ 1
                bnd = kd2[kk - 1] if m == kk else np.inf
                sub = sib if _nb_box_d2(px, py, pz, nodes_f, sib) < bnd else 0
                r = nodes_i[r, 7]
            for j in range(kk):
                if j >= m:
                    faces[i, j] = -1
                    reach[i, j] = np.inf
                else:
                    faces[i, j] = perm[kj[j]]
                    if j + 1 < m:
                        reach[i, j] = np.sqrt(kd2[j + 1])
                    else:  # the last face of the list: the others are at least as far as it
                        reach[i, j] = np.sqrt(kd2[j]) if m == kk else np.inf
            anchor[i, 0] = px
            anchor[i, 1] = py
            anchor[i, 2] = pz
            rebuilt[i] = 1
            tri = leaf_data
            row = kj[0]
            bestf = faces[i, 0]
        _nb_out(i, px, py, pz, tri, row, bestf, normals, out_face, out_foot, out_dist, out_normal)

    @_nb.njit(cache=True, nogil=True)
    def _nb_near_serial(q, anchor, faces, reach, data, leaf_data, nodes_f, nodes_i, hint_map, perm,
                        normals, out_face, out_foot, out_dist, out_normal,
                        rebuilt):  # pragma: no cover - compiled
        stack = np.empty(_STACK, np.int64)
        stack_lb = np.empty(_STACK)
        kd2 = np.empty(faces.shape[1])
        kj = np.empty(faces.shape[1], np.int64)
        for i in range(q.shape[0]):
            _nb_near_one(i, q, anchor, faces, reach, data, leaf_data, nodes_f, nodes_i, hint_map, perm,
                         normals, out_face, out_foot, out_dist, out_normal, rebuilt, kd2, kj, stack,
                         stack_lb)

    _KERNELS = (_nb_build, _nb_query_serial, _nb_near_serial)

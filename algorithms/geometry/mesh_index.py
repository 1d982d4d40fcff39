"""Exact closest points on a triangle mesh, for many points at once (:class:`MeshIndex`).

The inner loop of every localization algorithm: for each query point in the mesh's frame, the
nearest point on the surface (the *foot*), the face it lies on, the distance and the outward
face normal there. The point-triangle test is Ericson's (Real-Time Collision Detection, 5.1.5):
sign tests on dot products, no tolerance, so it is invariant to the scale of the mesh (unlike
``trimesh.proximity.closest_point``, whose absolute tolerances put feet in the wrong Voronoi
region on metre-scale meshes with millimetre triangles; ``tests/test_closest_point.py`` checks
exactness on points sampled on the mesh).

Two backends give the same answers (exact; only the face chosen between faces at exactly equal
distance may differ): ``numba``, a bounding-volume hierarchy searched by compiled kernels
(:mod:`algorithms.geometry.bvh_kernels`), and ``numpy``, a KD-tree over sample points on the
faces (:meth:`MeshIndex._nearest_faces_numpy`). Units follow the mesh (metres in this project).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from algorithms.arraytypes import ArrayLike, FloatArray, IntArray
from algorithms.errors import AlgorithmError
from algorithms.geometry.bvh_kernels import (
    HAVE_NUMBA,
    Bvh,
    build_bvh,
    closest_on_tree,
    compile_kernels,
    face_table,
    near_on_tree,
    realign_nodes,
)
from algorithms.geometry.query_pool import PARALLEL_MIN_POINTS

__all__ = ["NEAR_K", "ClosestPoints", "MeshIndex", "NearFaces", "closest_points_on_triangles"]

# Neighbour counts tried before the ball query (points near the surface need few).
_K_STAGES = (8, 48)
#: Faces each point keeps in its :class:`NearFaces` list (the foot's face and its neighbours).
NEAR_K = 4


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

    foot: FloatArray
    distance: FloatArray
    face: IntArray
    normal: FloatArray
    rel_error: float = 0.0

    def plane_residual(self, points: ArrayLike) -> FloatArray:
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

    anchor: FloatArray
    faces: IntArray
    reach: FloatArray
    n_rebuilt: int = 0


def closest_points_on_triangles(points: ArrayLike, triangles: ArrayLike) -> tuple[FloatArray, FloatArray]:
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


class MeshIndex:
    """A spatial index over a triangle mesh for exact closest-point queries.

    Build it once per mesh and reuse it: building costs about as much as a few thousand
    queries. Queries are thread-safe (the index is read-only after construction).

    Args:
        mesh: a ``trimesh.Trimesh`` (or anything with ``vertices`` (V, 3) and ``faces``
            (F, 3)), in the frame the queries will be given in.
        backend: ``"auto"`` (compiled BVH search when numba is installed, else numpy),
            ``"numba"`` or ``"numpy"``. Both are exact and give the same feet and
            distances; numba is much faster.

    Raises:
        AlgorithmError: no faces, non-finite vertices, face indices out of range, or an
            unknown/unavailable backend.
    """

    def __init__(self, mesh: Any, backend: str = "auto") -> None:
        self.backend = _backend_name(backend)
        vertices, faces = _mesh_arrays(mesh)
        self.mesh = mesh
        self.vertices = vertices
        self.faces = faces
        tri = vertices[faces]
        self._data, self.face_normals = face_table(tri)
        self.n_faces = len(faces)
        if self.backend == "numpy":
            self._build_sample_tree(tri)
        else:
            compile_kernels()
            self._bvh: Bvh = build_bvh(tri, self._data)
        self.extent = float(np.linalg.norm(np.ptp(vertices, axis=0)))  # bounding-box diagonal [m]
        # median edge length [m]: the scale below which a point's nearest faces stay its
        # nearest faces (see query_near)
        self.face_size = float(np.median(np.linalg.norm(self._data[:, 3:6], axis=1)))
        self._smooth: FloatArray | None = None
        self._pseudo: tuple[FloatArray, FloatArray] | None = None

    def _build_sample_tree(self, tri: FloatArray) -> None:
        """The numpy backend's KD-tree over sample points on the faces.

        Every face gets the centroids of an ``m x m`` subdivision of it as samples, ``m`` chosen
        so that every point of the face lies within ``radius`` of one of its samples. Every
        point of a sub-triangle is within (its largest centroid-vertex distance) of its
        centroid, and all m^2 sub-triangles of a face are congruent (up to a point reflection),
        so the covering radius of face f is r_f / m_f with r_f that of the whole face.
        """
        centroid = tri.mean(axis=1)
        r_face = np.linalg.norm(tri - centroid[:, None, :], axis=2).max(axis=1)
        positive = r_face[r_face > 0]
        target = np.percentile(positive, 90) if len(positive) else 1.0
        m = np.maximum(1, np.ceil(r_face / target - 1e-12)).astype(np.int64)
        m = np.minimum(m, 64)  # a huge face among tiny ones: cap the sample count
        samples, sample_face = _subdivision_centroids(tri, m)
        from scipy.spatial import cKDTree  # here: the numba backend never loads scipy.spatial

        self.radius = float(np.max(r_face / m)) * (1.0 + 1e-9) + 1e-300
        self._sample_face = sample_face
        self._tree = cKDTree(samples, leafsize=16)
        self.n_samples = len(samples)

    def __setstate__(self, state: dict[str, Any]) -> None:
        """Unpickled (a worker process): the node records back in one aligned block."""
        self.__dict__.update(state)
        if getattr(self, "_bvh", None) is not None:
            self._bvh = realign_nodes(self._bvh)

    # ------------------------------------------------------------------ queries
    def query(self, points: ArrayLike, hint: ArrayLike | None = None, rel_error: float = 0.0) -> ClosestPoints:
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
        return self._finish(q, self._nearest_faces_numpy(q))

    def _nearest_faces_numpy(self, q: FloatArray) -> IntArray:
        """(N,) the nearest face of each point, by the KD-tree over the face samples.

        The tree gives the ``k`` nearest samples; the exact distance to their faces gives
        ``d_best``. Any face not among them has all its samples at least ``d_k`` (the k-th
        neighbour distance) away, so its distance is at least ``d_k - radius``: where
        ``d_k - radius >= d_best`` the answer is proven; the other points are asked again with
        more neighbours and, at the last resort, with every sample within ``d_best + radius``
        (a ball query). Exact in every case, not approximate.
        """
        n = len(q)
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
        return best_face

    def _face_hints(self, hint: ArrayLike | None, n: int) -> IntArray:
        """(n,) the hint faces as the compiled search takes them: -1 for none or out of range."""
        if hint is None:
            return np.full(n, -1, dtype=np.int64)
        hints = np.asarray(hint, dtype=np.int64).reshape(-1)
        if hints.shape != (n,):
            raise AlgorithmError(f"hint must be ({n},) face indices, got {hints.shape}")
        return np.where((hints >= 0) & (hints < self.n_faces), hints, -1)

    def _query_numba(self, q: FloatArray, hint: ArrayLike | None, rel_error: float) -> ClosestPoints:
        face, foot, dist, normal = closest_on_tree(q, self._face_hints(hint, len(q)), self._data, self._bvh,
                                                   self.face_normals, rel_error)
        return ClosestPoints(foot=foot, distance=dist, face=face, normal=normal, rel_error=rel_error)

    def kernel_arrays(self) -> tuple[FloatArray, FloatArray, NDArray[np.float32], NDArray[np.int32],
                                     NDArray[np.int32], IntArray, FloatArray]:
        """``(data, leaf_data, nodes_f, nodes_i, hint_map, perm, normals)``: the
        arrays the compiled kernels of :func:`~algorithms.geometry.bvh_kernels.query_kernels` search, for
        compiled callers that run their own loop of queries (numba backend only)."""
        if self.backend != "numba":
            raise AlgorithmError("kernel_arrays needs the numba backend")
        return (self._data, *self._bvh, self.face_normals)

    def query_near(self, points: ArrayLike, near: NearFaces | None = None) -> tuple[ClosestPoints, NearFaces]:
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

    def _query_near_numpy(self, q: FloatArray, near: NearFaces | None) -> tuple[ClosestPoints, NearFaces]:
        """The numpy backend keeps no lists: every query is a tree query."""
        n = len(q)
        cp = self.query(q)
        near = NearFaces(anchor=q.copy(), faces=np.full((n, NEAR_K), -1, np.int64),
                         reach=np.repeat(cp.distance[:, None], NEAR_K, axis=1))
        near.faces[:, 0] = cp.face
        near.n_rebuilt = n
        return cp, near

    def _query_near_numba(self, q: FloatArray, near: NearFaces | None) -> tuple[ClosestPoints, NearFaces]:
        n = len(q)
        if near is None:
            near = NearFaces(anchor=np.zeros((n, 3)), faces=np.full((n, NEAR_K), -1, np.int64),
                             reach=np.full((n, NEAR_K), -np.inf))
        elif near.faces.shape[0] != n:
            raise AlgorithmError(f"near lists were made for {near.faces.shape[0]} points, got {n}")
        face, foot, dist, normal, near.n_rebuilt = near_on_tree(
            q, near.anchor, near.faces, near.reach, self._data, self._bvh, self.face_normals)
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
    def smooth_normals(self, face: ArrayLike, foot: ArrayLike) -> FloatArray:
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
        face = np.asarray(face, dtype=np.int64)
        if self._smooth is None:  # filled face by face: a fit touches few of a dense mesh's faces
            self._incidence = _vertex_incidence(self.faces, len(self.vertices))
            self._smooth_done = np.zeros(self.n_faces, dtype=bool)
            self._smooth = np.zeros((self.n_faces, 3, 3))  # last: another thread may be reading
        todo = np.unique(face[~self._smooth_done[face]])
        if len(todo):
            self._smooth[todo] = _corner_normals(self.vertices, self.faces, self.face_normals, which=todo,
                                                 incidence=self._incidence)
            self._smooth_done[todo] = True
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

    def signed_distance(self, points: ArrayLike) -> FloatArray:
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


def _vertex_incidence(faces: IntArray, n_vertices: int) -> tuple[IntArray, IntArray, IntArray]:
    """The corners around each vertex: ``order`` (the flat corner indices ``3 f + c`` sorted by
    vertex, stable), and vertex v's corners ``order[starts[v] : starts[v] + degree[v]]``."""
    flat = faces.reshape(-1)
    order = np.argsort(flat, kind="stable")
    sorted_vertex = flat[order]
    starts = np.searchsorted(sorted_vertex, np.arange(n_vertices))
    degree = np.searchsorted(sorted_vertex, np.arange(n_vertices), side="right") - starts
    return order, starts, degree


def _corner_angles(vertices, faces, corner: IntArray) -> FloatArray:
    """Interior angles [rad] at flat corners ``3 f + c``."""
    f, c = corner // 3, corner % 3
    p0 = vertices[faces[f, c]]
    e1 = vertices[faces[f, (c + 1) % 3]] - p0
    e2 = vertices[faces[f, (c + 2) % 3]] - p0
    cosang = np.einsum("ij,ij->i", e1, e2) / np.maximum(np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1),
                                                          1e-300)
    return np.arccos(np.clip(cosang, -1.0, 1.0))


def _corner_normals(vertices, faces, face_normals, crease_deg: float = 30.0, which=None, incidence=None):
    """(len(which), 3, 3) per-corner normals of the faces ``which`` (default: all): at each
    corner, the angle-weighted mean of the normals of the faces around its vertex within
    ``crease_deg`` of the face's own normal. ``incidence``: :func:`_vertex_incidence`, if known."""
    which = np.arange(len(faces)) if which is None else np.asarray(which, dtype=np.int64)
    order, starts, degree = _vertex_incidence(faces, len(vertices)) if incidence is None else incidence
    corner_vertex = faces[which].reshape(-1)        # the vertex of each wanted corner
    n_around = degree[corner_vertex]
    # all pairs (the corner's face f, a face g around its vertex), one run per corner
    run_start = np.cumsum(n_around) - n_around
    pair_f = np.repeat(np.repeat(which, 3), n_around)
    offs = np.arange(int(n_around.sum())) - np.repeat(run_start, n_around)
    corner_g = order[np.repeat(starts[corner_vertex], n_around) + offs]   # g's corner at the vertex
    pair_g = corner_g // 3
    keep = np.einsum("ij,ij->i", face_normals[pair_f], face_normals[pair_g]) >= np.cos(np.radians(crease_deg))
    if len(corner_g) > faces.size:   # many pairs: each corner's angle once, then gathered
        angle = _corner_angles(vertices, faces, np.arange(faces.size))[corner_g]
    else:
        angle = _corner_angles(vertices, faces, corner_g)
    wgt = angle * keep
    out = np.add.reduceat(wgt[:, None] * face_normals[pair_g], run_start, axis=0).reshape(len(which), 3, 3)
    norm = np.linalg.norm(out, axis=2, keepdims=True)
    fallback = np.broadcast_to(face_normals[which][:, None, :], out.shape)
    return np.where(norm > 1e-300, out / np.maximum(norm, 1e-300), fallback)


def _backend_name(backend: str) -> str:
    """The backend an index uses: ``backend``, or for ``"auto"`` numba where installed."""
    if backend not in ("auto", "numba", "numpy"):
        raise AlgorithmError(f"backend must be 'auto', 'numba' or 'numpy', got {backend!r}")
    if backend == "numba" and not HAVE_NUMBA:
        raise AlgorithmError("backend 'numba' requested but numba is not installed (pip install numba)")
    if backend == "auto":
        return "numba" if HAVE_NUMBA else "numpy"
    return backend


def _mesh_arrays(mesh: Any) -> tuple[FloatArray, IntArray]:
    """The mesh's (V, 3) float64 vertices and (F, 3) int64 faces, checked."""
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
    return vertices, faces

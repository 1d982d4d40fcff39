"""Compiled (numba) exact closest points on a triangle mesh: a bounding-volume hierarchy over
the triangles, searched per point best-first by box distance.

The tree: median splits, ``_BVH_LEAF`` triangles a leaf, boxes in float32 rounded outwards,
nodes packed two to a cache line (:func:`build_bvh`). With a hint (a face near the answer, e.g.
the previous iteration's) the search starts at the hint's leaf with the hint's distance as
bound and walks up, visiting the sibling of each node on the way only where its box is nearer
than the best so far: exact, and faster than a search from the root, as most siblings cost one
box test. The point-triangle test is the one of
:func:`algorithms.geometry.mesh_index.closest_points_on_triangles` (Ericson's sign tests).

Module-level functions with ``cache=True``, so that numba's disk cache finds them again in the
next process. Without numba the kernels are missing and
:class:`~algorithms.geometry.mesh_index.MeshIndex` uses its numpy backend. Units follow the
mesh (metres in this project).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from types import ModuleType
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from algorithms.arraytypes import FloatArray, IntArray
from algorithms.errors import AlgorithmError
from algorithms.geometry.query_pool import in_chunks

_nb: ModuleType | None
try:  # optional: compiled kernels (much faster than numpy); results are identical
    import numba as _nb
except ImportError:  # pragma: no cover - depends on the environment
    _nb = None
HAVE_NUMBA = _nb is not None

__all__ = ["HAVE_NUMBA", "Bvh", "build_bvh", "closest_on_tree", "compile_kernels", "face_table",
           "kernels_cached", "near_on_tree", "query_kernels", "realign_nodes"]

_BVH_LEAF = 4   # triangles a leaf (at most 7: a leaf's count is packed in 3 bits)
_STACK = 128    # search stack: about one pending node a level of a median-split tree (~log2(F / 4))
# Faces a near list holds in :func:`compile_kernels` (the kernels are compiled per array type,
# so any length serves).
_WARMUP_NEAR_K = 4

_compiled = False


class Bvh(NamedTuple):
    """The compiled search's tree over F faces (see :func:`_pack_nodes` for the records).

    Attributes:
        leaf_data: (F, 12) the face table of :func:`face_table` in leaf order (a leaf's
            triangles one contiguous block).
        nodes_f: (R, 8) float32 node records: the box (lower, upper corner) in columns 0:6.
        nodes_i: (R, 8) int32 view of the same records: child (6) and parent (7) records.
        hint_map: (F, 2) int32 face f's slot in the leaf order and its leaf's record.
        perm: (F,) int64 the face of each leaf slot.
    """

    leaf_data: FloatArray
    nodes_f: NDArray[np.float32]
    nodes_i: NDArray[np.int32]
    hint_map: NDArray[np.int32]
    perm: IntArray


def face_table(tri: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Per-face constants of the point-triangle test, and the unit face normals.

    Args:
        tri: (F, 3, 3) [m] the vertices ``a, b, c`` of each face.

    Returns:
        (data (F, 12): columns ``a`` (3), ``ab`` (3), ``ac`` (3), ``|ab|^2``, ``|ac|^2``,
        ``ab.ac``, packed so that one row gather fetches all a point-face pair needs;
        normals (F, 3): unit ``ab x ac`` (outward by the winding), 0 on a degenerate face).
    """
    a = tri[:, 0]
    ab = tri[:, 1] - a
    ac = tri[:, 2] - a
    cross = np.cross(ab, ac)
    area2 = np.linalg.norm(cross, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        normals = cross / area2[:, None]
    normals[~np.isfinite(normals).all(axis=1)] = 0.0
    data = np.empty((len(tri), 12))
    data[:, 0:3] = a
    data[:, 3:6] = ab
    data[:, 6:9] = ac
    data[:, 9] = np.einsum("ij,ij->i", ab, ab)
    data[:, 10] = np.einsum("ij,ij->i", ac, ac)
    data[:, 11] = np.einsum("ij,ij->i", ab, ac)
    return data, normals


def build_bvh(tri: FloatArray, data: FloatArray) -> Bvh:
    """The tree over the faces (compiled: call :func:`compile_kernels` first to announce it).

    Args:
        tri: (F, 3, 3) [m] face vertices.
        data: (F, 12) their :func:`face_table`.
    """
    lo, hi, left, right, start, count, perm, up, leaf_of = _nb_build(
        tri.min(axis=1), tri.max(axis=1), tri.mean(axis=1), _BVH_LEAF)
    inner = left >= 0
    assert np.array_equal(right[inner], left[inner] + 1)  # siblings are adjacent
    return Bvh(np.ascontiguousarray(data[perm]), *_pack_nodes(lo, hi, left, start, count, up, leaf_of, perm))


def realign_nodes(bvh: Bvh) -> Bvh:
    """The node records back in one aligned block, after unpickling (pickle copies the two
    views of it apart)."""
    nodes_f, packed = _node_records(len(bvh.nodes_i))
    packed[:] = bvh.nodes_i  # the whole records, boxes' bits included
    return bvh._replace(nodes_f=nodes_f, nodes_i=packed)


def closest_on_tree(q: FloatArray, hints: IntArray, data: FloatArray, bvh: Bvh, normals: FloatArray,
                    rel_error: float) -> tuple[IntArray, FloatArray, FloatArray, FloatArray]:
    """Closest points of N points, on every core from ``PARALLEL_MIN_POINTS`` points on.

    Args:
        q: (N, 3) [m] query points, mesh frame, finite.
        hints: (N,) int64 a face near each point's answer, or -1 for none.
        data: (F, 12) the :func:`face_table`; bvh: its tree; normals: (F, 3) the face normals.
        rel_error: 0: exact; else each distance is within ``(1 + rel_error)`` of the exact one.

    Returns:
        (face (N,), foot (N, 3) [m], distance (N,) [m], normal (N, 3)).
    """
    n = len(q)
    face = np.empty(n, dtype=np.int64)
    foot = np.empty((n, 3))
    dist = np.empty(n)
    normal = np.empty((n, 3))
    # writeable C arrays: the types the kernel was compiled (and cached) for
    q = np.require(q, requirements=("C", "W"))

    def run(a: int, b: int) -> None:
        _nb_query_serial(q[a:b], hints[a:b], data, *bvh, normals, face[a:b], foot[a:b],
                         dist[a:b], normal[a:b], 1.0 / (1.0 + rel_error) ** 2)

    in_chunks(run, n)
    return face, foot, dist, normal


def near_on_tree(q: FloatArray, anchor: FloatArray, faces: IntArray, reach: FloatArray, data: FloatArray,
                 bvh: Bvh, normals: FloatArray) -> tuple[IntArray, FloatArray, FloatArray, FloatArray, int]:
    """Closest points of N points from their near lists where the lists' certificate holds, from
    the tree elsewhere (the lists of those found again, in place); see
    :class:`algorithms.geometry.mesh_index.NearFaces` for ``anchor``, ``faces``, ``reach``.

    Returns:
        (face (N,), foot (N, 3) [m], distance (N,) [m], normal (N, 3), the number of points
        whose list was found again).
    """
    n = len(q)
    face = np.empty(n, dtype=np.int64)
    foot = np.empty((n, 3))
    dist = np.empty(n)
    normal = np.empty((n, 3))
    rebuilt = np.zeros(n, dtype=np.uint8)

    def run(a: int, b: int) -> None:
        _nb_near_serial(q[a:b], anchor[a:b], faces[a:b], reach[a:b], data, *bvh, normals, face[a:b],
                        foot[a:b], dist[a:b], normal[a:b], rebuilt[a:b])

    in_chunks(run, n)
    return face, foot, dist, normal, int(rebuilt.sum())


def query_kernels() -> Any:  # the (tree, near) pair of numba dispatchers, or None
    """The compiled query kernels, for other compiled functions (None without numba):
    ``tree(q, hints, *arrays, out_face, out_foot, out_dist, out_normal, shrink)`` answers
    :meth:`MeshIndex.query` (``hints`` -1 for none, ``shrink = 1 / (1 + rel_error)^2``) and
    ``near(q, anchor, faces, reach, *arrays, out_face, out_foot, out_dist, out_normal, rebuilt)``
    :meth:`MeshIndex.query_near` (the lists updated in place), ``arrays`` those of
    :meth:`MeshIndex.kernel_arrays`."""
    if _nb is None:
        return None
    return _nb_query_serial, _nb_near_serial


def kernels_cached(kernels: Sequence[Any] | None = None) -> bool | None:
    """Whether numba's on-disk cache holds the given compiled functions (default: every
    closest-point kernel) for their current source (None: cannot tell, numba's cache layout
    being private)."""
    try:
        return all(bool(k._cache._cache_file._load_index()) for k in (kernels or _KERNELS))
    except Exception:  # pragma: no cover - depends on numba's internals
        return None


def compile_kernels(announce: bool = True) -> float:
    """Compile (or load from numba's cache) every closest-point kernel now, and return the
    seconds it took (0 when done before in this process, or without numba).

    Numba compiles the kernels on their first call and caches them on disk (``cache=True``),
    so only the first run of an installation pays the compilation (the times measured:
    ``benchmarks/results_speed.md``). :class:`MeshIndex` calls this on the first index a
    process builds; with ``announce`` it says on stderr that it is compiling when the cache
    does not hold the kernels (``twin warmup`` calls it at install time).
    """
    global _compiled
    if _nb is None or _compiled:
        return 0.0
    t0 = time.perf_counter()
    if announce and kernels_cached() is False:
        print("compiling closest-point kernels, first run only ...", file=sys.stderr, flush=True)
    _compiled = True
    _run_on_a_tetrahedron()
    return time.perf_counter() - t0


def _run_on_a_tetrahedron() -> None:
    """One tetrahedron and two points through every kernel, in the argument types of real calls."""
    vertices = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    faces = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], dtype=np.int64)
    tri = vertices[faces]
    data, normals = face_table(tri)
    bvh = build_bvh(tri, data)
    q = np.array([[0.2, 0.2, 0.2], [2.0, 2.0, 2.0]])
    n = len(q)
    closest_on_tree(q, np.full(n, -1, dtype=np.int64), data, bvh, normals, 0.0)
    near_on_tree(q, np.zeros((n, 3)), np.full((n, _WARMUP_NEAR_K), -1, np.int64),
                 np.full((n, _WARMUP_NEAR_K), -np.inf), data, bvh, normals)

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

"""Planar faces of the generated workpieces: conforming Delaunay meshes with graded interior points.

:func:`planar_patch` meshes a planar face given by its 3-D boundary loops; the 2-D work is
:func:`_mesh_planar_region`, whose steps are:

1. the boundary loops as segments, and dense samples of them that give the distance to the
   boundary and the boundary spacing nearby (:class:`_Region`);
2. interior points from triangular lattices of spacing ``max_edge / 2^k``, each level kept
   where the target edge length lies in its band (:func:`_interior_points`);
3. a Delaunay triangulation with ghost points around the region (:func:`_ghost_points`,
   :meth:`_Region.triangulate`);
4. a few damped Laplacian smoothing steps of the interior points (:func:`_smooth_interior`);
5. the conformity check: every boundary segment is a triangle edge (:func:`_check_conforms`).

The loop points are the only boundary vertices, so a neighbouring surface that shares a loop
is stitched exactly by :func:`twin.parts.kernel.assemble`. Triangles stay well shaped (MuJoCo's
ray casts are slow on long slivers) and face counts moderate.

Units: metres throughout.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.spatial import Delaunay, cKDTree

from algorithms.arraytypes import BoolArray, FloatArray, IntArray

__all__ = ["PLANAR_GRADING", "PLANAR_MAX_EDGE_M", "planar_patch"]

PLANAR_MAX_EDGE_M = 0.005
"""Largest edge [m] of the graded planar faces, far from curved features."""

PLANAR_GRADING = 0.3
"""Growth of the planar edge length per unit distance from the nearest boundary (dimensionless).

0.3 lets the edge grow from 0.5 mm to 5 mm over 15 mm while neighbouring triangles differ by
less than 1.5x.
"""

# Smallest distance of an interior point from the boundary, relative to the local edge length.
_CLEARANCE = 0.55
# Damped Laplacian smoothing steps applied to the interior points of planar faces.
_SMOOTHING_STEPS = 4
# An interior point must lie outside the circle of this radius (relative to the segment's
# length) about every segment's midpoint: just over the diametral circle (0.5).
_DIAMETRAL = 0.56
# Boundary segments are sampled at a quarter of the shortest segment, at most this many
# samples per segment.
_MAX_DENSE_PER_SEGMENT = 64


def _hex_lattice(lo: FloatArray, hi: FloatArray, spacing: float) -> FloatArray:
    """Points of a triangular lattice covering the box [lo, hi] (2-D)."""
    row = spacing * math.sqrt(3.0) / 2.0
    ys = np.arange(lo[1], hi[1] + row, row)
    xs = np.arange(lo[0] - spacing, hi[0] + spacing, spacing)
    gx, gy = np.meshgrid(xs, ys)
    gx = gx + (np.arange(len(ys)) % 2)[:, None] * (spacing / 2.0)
    return np.column_stack([gx.ravel(), gy.ravel()])


def _hex_lattice_near(
    lo: FloatArray, hi: FloatArray, spacing: float, centers: FloatArray, reach: float
) -> FloatArray:
    """The points of ``_hex_lattice(lo, hi, spacing)`` in tiles within ``reach`` of centers."""
    tile = 32.0 * spacing
    nx = max(1, int(math.ceil((hi[0] - lo[0]) / tile)))
    ny = max(1, int(math.ceil((hi[1] - lo[1]) / tile)))
    tx, ty = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    tile_lo = lo + np.column_stack([tx.ravel(), ty.ravel()]) * tile
    mid = tile_lo + 0.5 * tile
    dist, _ = cKDTree(centers).query(mid)
    keep = dist <= reach + tile / math.sqrt(2.0)
    if not np.any(keep):
        return np.zeros((0, 2))
    lattice = _hex_lattice(lo, hi, spacing)
    cell = np.floor((lattice - lo) / tile).astype(np.int64)
    cell = np.clip(cell, 0, [nx - 1, ny - 1])
    kept = np.zeros((nx, ny), dtype=bool)
    kept[tx.ravel()[keep], ty.ravel()[keep]] = True
    return lattice[kept[cell[:, 0], cell[:, 1]]]


def _inside(points: FloatArray, seg_a: FloatArray, seg_b: FloatArray) -> BoolArray:
    """Even-odd point-in-region test against all boundary segments, (N,) bool."""
    out = np.zeros(len(points), dtype=bool)
    ya, yb = seg_a[:, 1], seg_b[:, 1]
    xa, xb = seg_a[:, 0], seg_b[:, 0]
    for start in range(0, len(points), 2048):
        p = points[start : start + 2048]
        px, py = p[:, 0:1], p[:, 1:2]
        straddle = (ya[None, :] > py) != (yb[None, :] > py)
        with np.errstate(divide="ignore", invalid="ignore"):
            x_cross = xa + (py - ya) * (xb - xa) / (yb - ya)
        hits = straddle & (px < x_cross)
        out[start : start + 2048] = (np.count_nonzero(hits, axis=1) % 2) == 1
    return out


def _loop_segments(loops: Sequence[FloatArray]) -> tuple[FloatArray, FloatArray, IntArray]:
    """Start points (S, 2), end points (S, 2) and loop-point indices (S, 2) of every boundary
    segment, loop after loop, each loop closed."""
    seg_a_list, seg_b_list, seg_index_list = [], [], []
    offset = 0
    for lp in loops:
        n = len(lp)
        idx = np.arange(n) + offset
        seg_a_list.append(lp)
        seg_b_list.append(np.roll(lp, -1, axis=0))
        seg_index_list.append(np.column_stack([idx, np.roll(idx, -1)]))
        offset += n
    return np.concatenate(seg_a_list), np.concatenate(seg_b_list), np.concatenate(seg_index_list)


def _dense_samples(seg_a: FloatArray, seg_b: FloatArray, seg_len: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Samples (D, 2) of the boundary segments at about a quarter of the shortest segment,
    and the length of the segment each lies on (D,) [m]: the boundary spacing there."""
    min_len = float(seg_len.min())
    pieces = np.maximum(1, np.ceil(seg_len / (0.25 * min_len + 1e-300)).astype(int))
    pieces = np.minimum(pieces, _MAX_DENSE_PER_SEGMENT)
    dense_parts, dense_spacing_parts = [], []
    for k in np.unique(pieces):
        sel = np.nonzero(pieces == k)[0]
        t = (np.arange(k) / k)[None, :, None]
        pts = seg_a[sel, None, :] + t * (seg_b[sel] - seg_a[sel])[:, None, :]
        dense_parts.append(pts.reshape(-1, 2))
        dense_spacing_parts.append(np.repeat(seg_len[sel], k))
    return np.concatenate(dense_parts), np.concatenate(dense_spacing_parts)


@dataclass(frozen=True)
class _Region:
    """A planar region to mesh: its boundary segments, dense boundary samples and size rule.

    Attributes:
        boundary: (n_b, 2) [m] the loop points, loop after loop.
        seg_a, seg_b: (S, 2) [m] start and end of each boundary segment.
        seg_index: (S, 2) indices of the segments' ends into ``boundary``.
        seg_len: (S,) [m]; seg_mid: (S, 2) [m] segment midpoints.
        dense: (D, 2) [m] boundary samples; dense_spacing: (D,) [m] the boundary spacing there.
        max_edge: largest interior edge [m]; grading: growth of the edge per unit distance.
    """

    boundary: FloatArray
    seg_a: FloatArray
    seg_b: FloatArray
    seg_index: IntArray
    seg_len: FloatArray
    seg_mid: FloatArray
    dense: FloatArray
    dense_spacing: FloatArray
    dense_tree: cKDTree
    mid_tree: cKDTree
    max_edge: float
    grading: float

    @classmethod
    def from_loops(cls, loops: Sequence[FloatArray], max_edge: float, grading: float) -> _Region:
        boundary = np.concatenate(loops)
        seg_a, seg_b, seg_index = _loop_segments(loops)
        seg_len = np.linalg.norm(seg_b - seg_a, axis=1)
        seg_mid = 0.5 * (seg_a + seg_b)
        dense, dense_spacing = _dense_samples(seg_a, seg_b, seg_len)
        return cls(boundary, seg_a, seg_b, seg_index, seg_len, seg_mid, dense, dense_spacing, cKDTree(dense),
                   cKDTree(seg_mid), max_edge, grading)

    @property
    def lo(self) -> FloatArray:
        return self.boundary.min(axis=0)

    @property
    def hi(self) -> FloatArray:
        return self.boundary.max(axis=0)

    @property
    def min_len(self) -> float:
        return float(self.seg_len.min())

    @property
    def max_seg(self) -> float:
        return float(self.seg_len.max())

    def target_size(self, pts: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Target edge length ``min(max_edge, s + grading * d)`` at pts (N, 2), and d (N,) [m]."""
        dist, nearest = self.dense_tree.query(pts)
        return np.minimum(self.max_edge, self.dense_spacing[nearest] + self.grading * dist), dist

    def admissible(self, pts: FloatArray) -> BoolArray:
        """Inside, clear of the boundary, and outside every segment's diametral circle."""
        size, dist = self.target_size(pts)
        ok = dist >= _CLEARANCE * size
        ok[ok] = _inside(pts[ok], self.seg_a, self.seg_b)
        rows = np.nonzero(ok)[0]
        if len(rows):
            near = self.mid_tree.query_ball_point(pts[rows], r=_DIAMETRAL * self.max_seg)
            counts = np.fromiter((len(js) for js in near), dtype=np.int64, count=len(near))
            if counts.sum():
                which = np.repeat(rows, counts)
                js = np.concatenate([np.asarray(j, dtype=np.int64) for j in near if j])
                inside_circle = np.linalg.norm(self.seg_mid[js] - pts[which], axis=1) < (
                    _DIAMETRAL * self.seg_len[js]
                )
                ok[which[inside_circle]] = False
        return ok

    def triangulate(self, pts: FloatArray, ghosts: FloatArray) -> tuple[IntArray, FloatArray]:
        """Delaunay triangles of pts (M, 3) inside the region, counter-clockwise, and twice
        their areas (M,) [m^2]; triangles touching the ghost points are dropped."""
        tri = Delaunay(np.concatenate([pts, ghosts])).simplices
        tri = tri[np.all(tri < len(pts), axis=1)]
        tri = tri[_inside(pts[tri].mean(axis=1), self.seg_a, self.seg_b)]
        p0, p1, p2 = pts[tri[:, 0]], pts[tri[:, 1]], pts[tri[:, 2]]
        cross = (p1[:, 0] - p0[:, 0]) * (p2[:, 1] - p0[:, 1]) - (p1[:, 1] - p0[:, 1]) * (
            p2[:, 0] - p0[:, 0]
        )
        return np.where((cross < 0.0)[:, None], tri[:, [0, 2, 1]], tri), np.abs(cross)


def _level_lattice(region: _Region, h: float, coarsest: bool) -> FloatArray:
    """Lattice points (K, 2) of spacing h inside the region's bounding box (open).

    The coarsest level covers the box; a finer level only the tiles where the target size can
    fall below 2 h: within (2 h - s) / grading of boundary samples spaced s < 2 h.
    """
    lo, hi = region.lo, region.hi
    if coarsest:
        cand = _hex_lattice(lo, hi, h)
    else:
        fine = region.dense_spacing < 2.0 * h
        if not np.any(fine):
            return np.zeros((0, 2))
        reach = float(np.max(2.0 * h - region.dense_spacing[fine])) / region.grading
        cand = _hex_lattice_near(lo, hi, h, region.dense[fine], reach)
    cand = cand[(cand[:, 0] > lo[0]) & (cand[:, 0] < hi[0])]
    return cand[(cand[:, 1] > lo[1]) & (cand[:, 1] < hi[1])]


def _level_points(region: _Region, cand: FloatArray, h: float, lower: float, upper: float,
                  accepted_tree: cKDTree) -> FloatArray:
    """The candidates (K, 2) whose target size lies in [lower, upper), at least 0.7 h from every
    accepted point, and admissible (:meth:`_Region.admissible`)."""
    size, _ = region.target_size(cand)
    cand = cand[(size >= lower) & (size < upper)]
    if len(cand) == 0:
        return cand
    d_acc, _ = accepted_tree.query(cand)
    cand = cand[d_acc >= 0.7 * h]
    return cand[region.admissible(cand)]


def _interior_points(region: _Region) -> FloatArray:
    """The loop points followed by graded interior points (N, 2) [m], coarse levels first.

    Level k has spacing ``max_edge / 2^k`` down to the finest boundary spacing and keeps the
    lattice points whose target size lies in [h, 2 h) (the coarsest level: >= h, the finest:
    < 2 h).
    """
    levels = [region.max_edge]
    while levels[-1] > region.min_len:
        levels.append(levels[-1] / 2.0)
    accepted = [region.boundary]
    accepted_tree = cKDTree(region.boundary)
    for k in range(len(levels) - 1, -1, -1):
        h = levels[k]
        cand = _level_lattice(region, h, coarsest=k == 0)
        if len(cand) == 0:
            continue
        upper = np.inf if k == 0 else 2.0 * h
        lower = 0.0 if k == len(levels) - 1 else h
        cand = _level_points(region, cand, h, lower, upper, accepted_tree)
        if len(cand) == 0:
            continue
        accepted.append(cand)
        accepted_tree = cKDTree(np.concatenate(accepted))
    return np.concatenate(accepted)


def _ghost_points(region: _Region) -> FloatArray:
    """Points (G, 2) on a rectangle well outside the region.

    They keep the boundary points off the convex hull (Qhull would drop collinear hull points);
    triangles touching them are outside the region and discarded.
    """
    max_edge = region.max_edge
    margin = 2.0 * max(max_edge, region.max_seg)
    glo, ghi = region.lo - margin, region.hi + margin
    nx = max(2, int(math.ceil((ghi[0] - glo[0]) / max_edge)))
    ny = max(2, int(math.ceil((ghi[1] - glo[1]) / max_edge)))
    gx = np.linspace(glo[0], ghi[0], nx + 1)
    gy = np.linspace(glo[1], ghi[1], ny + 1)
    return np.concatenate(
        [
            np.column_stack([gx, np.full_like(gx, glo[1])]),
            np.column_stack([gx, np.full_like(gx, ghi[1])]),
            np.column_stack([np.full_like(gy[1:-1], glo[0]), gy[1:-1]]),
            np.column_stack([np.full_like(gy[1:-1], ghi[0]), gy[1:-1]]),
        ]
    )


def _neighbour_mean(tri: IntArray, points: FloatArray) -> FloatArray:
    """Mean (N, 2) of each point's neighbours along the triangles' edges."""
    n_pts = len(points)
    edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    adj = coo_matrix(
        (np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n_pts, n_pts)
    ).tocsr()
    adj = ((adj + adj.T) > 0).astype(np.float64)
    degree = np.asarray(adj.sum(axis=1)).ravel()
    return (adj @ points) / np.maximum(degree, 1.0)[:, None]


def _smooth_interior(region: _Region, points: FloatArray, ghosts: FloatArray) -> None:
    """Smooth the lattice seams in place: move each interior point toward the mean of its
    neighbours (a few damped Laplacian steps), refusing moves that are not admissible."""
    n_boundary = len(region.boundary)
    for _ in range(_SMOOTHING_STEPS):
        if len(points) == n_boundary:
            break
        tri, _ = region.triangulate(points, ghosts)
        mean = _neighbour_mean(tri, points)
        moved = points[n_boundary:] + 0.6 * (mean[n_boundary:] - points[n_boundary:])
        ok = region.admissible(moved)
        points[n_boundary:][ok] = moved[ok]


def _check_conforms(region: _Region, points: FloatArray, tri: IntArray, cross: FloatArray) -> None:
    """Every loop segment is the edge of exactly one triangle, every other edge of two, every
    point is used and no triangle is degenerate.

    Raises:
        RuntimeError: anything else (a bug, or parameters the generators should have refused).
    """
    edges = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
    uniq, counts = np.unique(edges, axis=0, return_counts=True)
    seg_sorted = np.unique(np.sort(region.seg_index, axis=1), axis=0)
    boundary_edges = uniq[counts == 1]
    if (
        np.any(counts > 2)
        or len(boundary_edges) != len(seg_sorted)
        or not np.array_equal(boundary_edges, seg_sorted)
        or len(np.unique(tri)) != len(points)
        or np.any(np.abs(cross) <= 1e-18 * region.max_edge**2)
    ):
        raise RuntimeError("internal error: planar face triangulation does not conform")


def _mesh_planar_region(
    loops: Sequence[FloatArray], max_edge: float, grading: float = PLANAR_GRADING
) -> tuple[FloatArray, IntArray]:
    """Triangulate a planar region bounded by closed polygons, keeping the loop points.

    The loop points are the only boundary vertices, so a neighbouring surface that shares a
    loop is stitched exactly. Interior points come from triangular lattices whose spacing
    follows ``min(max_edge, s + grading * d)`` (``s`` the boundary spacing nearby, ``d`` the
    distance to the boundary) and keep every boundary segment's diametral circle empty, so
    each segment is a Delaunay edge and the triangulation conforms to the boundary.

    Args:
        loops: closed polygons, each (n_i, 2) [m] without the closing point repeated; any
            orientation. The region is what the even-odd rule calls inside.
        max_edge: largest interior edge length [m].
        grading: growth of the edge length per unit distance from the boundary.

    Returns:
        points: (N, 2) [m]; the first sum(n_i) rows are the loop points in the given order.
        triangles: (M, 3) int, counter-clockwise.

    Raises:
        RuntimeError: the triangulation does not conform to the loops (:func:`_check_conforms`).
    """
    region = _Region.from_loops([np.asarray(lp, dtype=np.float64) for lp in loops], max_edge, grading)
    points = _interior_points(region)
    ghosts = _ghost_points(region)
    _smooth_interior(region, points, ghosts)
    tri, cross = region.triangulate(points, ghosts)
    _check_conforms(region, points, tri, cross)
    return points, tri


def planar_patch(
    loops3d: Sequence[FloatArray],
    origin: FloatArray,
    u: FloatArray,
    v: FloatArray,
    outward: FloatArray,
    max_edge: float,
) -> tuple[FloatArray, IntArray]:
    """Mesh a planar face given by 3-D boundary loops lying in the plane (origin, u, v).

    The loop points are kept as the patch's boundary vertices, unchanged and in order, so a
    neighbouring patch built on the same loop is stitched exactly by
    :func:`twin.parts.kernel.assemble`.

    Args:
        loops3d: closed polygons, each (n_i, 3) [m] without the closing point repeated, in
            the plane; the face is what the even-odd rule calls inside (an outer loop and the
            holes in it, any orientation).
        origin: (3,) [m] a point of the plane.
        u, v: (3,) orthonormal in-plane axes.
        outward: (3,) the face's outward normal (only its side of the plane matters).
        max_edge: largest interior edge [m]; edges grade from the loops' spacing up to it.

    Returns:
        vertices (N, 3) [m], the first sum(n_i) being the loop points; triangles (M, 3) int,
        wound counter-clockwise seen from ``outward``.
    """
    loops2d = [(lp - origin) @ np.column_stack([u, v]) for lp in loops3d]
    pts2d, tri = _mesh_planar_region(loops2d, max_edge)
    n_b = sum(len(lp) for lp in loops3d)
    interior = origin + pts2d[n_b:, 0:1] * u + pts2d[n_b:, 1:2] * v
    vertices = np.concatenate([np.concatenate(loops3d), interior])
    if float(np.dot(np.cross(u, v), outward)) < 0.0:
        tri = tri[:, [0, 2, 1]]
    return vertices, tri

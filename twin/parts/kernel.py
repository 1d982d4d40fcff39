"""Meshing kernel of the generated workpieces: watertight solids built surface by surface.

The generators of :mod:`twin.parts` build every part from the pieces here, so that the solid
is closed by construction (no boolean engine is needed):

* curved surfaces are surfaces of revolution: a profile of :func:`line_segment` and
  :func:`cubic_bezier` curves in (r, a) coordinates, sampled by :func:`sample_profile`
  against a chord tolerance and revolved by :func:`revolve`;
* planar faces are meshed by :func:`planar_patch`, a conforming Delaunay triangulation of
  their boundary loops with graded interior points, so that triangles stay well shaped
  (MuJoCo's ray casts are slow on long slivers) and face counts moderate; :func:`box_patches`
  gives the six faces of a block with holes cut where curved surfaces meet it;
* :func:`assemble` stitches the patches by merging coincident vertices and checks that the
  result is a closed, consistently wound solid of positive volume.

A patch is a pair ``(vertices, triangles)``: vertices (N, 3) [m], triangles (M, 3) int64
indices into them. Patches that share a boundary share its vertices exactly (the same float
values), which is what lets :func:`assemble` merge them with a nanometre tolerance.

The parameter checks (:func:`check_positive` ...) raise :class:`~twin.errors.TwinError` with
one-line messages naming the parameter; generators use them on every keyword argument.

Units: metres throughout.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import Delaunay, cKDTree

from twin.errors import TwinError

__all__ = [
    "CHORD_TOL_M",
    "PLANAR_GRADING",
    "PLANAR_MAX_EDGE_M",
    "assemble",
    "box_patches",
    "check_finite",
    "check_nonnegative",
    "check_positive",
    "check_resolution",
    "cubic_bezier",
    "edge_points",
    "format_mm",
    "line_segment",
    "planar_patch",
    "require",
    "revolve",
    "sample_profile",
]

PLANAR_MAX_EDGE_M = 0.005
"""Largest edge [m] of the graded planar faces, far from curved features."""

PLANAR_GRADING = 0.3
"""Growth of the planar edge length per unit distance from the nearest boundary (dimensionless).

0.3 lets the edge grow from 0.5 mm to 5 mm over 15 mm while neighbouring triangles differ by
less than 1.5x.
"""

CHORD_TOL_M = 1e-5
"""Default chord tolerance [m] of the curved surfaces: the mesh deviates from them by less."""

# MuJoCo's mesh loader refuses meshes with more faces than this.
_MAX_FACES = 200_000
# Two points closer than this [m] are the same vertex when the surfaces are stitched; every
# generated edge is micrometres long at least, so this cannot merge distinct vertices.
_MERGE_TOL_M = 1e-9
# Smallest distance of an interior point from the boundary, relative to the local edge length.
_CLEARANCE = 0.55
# Damped Laplacian smoothing steps applied to the interior points of planar faces.
_SMOOTHING_STEPS = 4


# --------------------------------------------------------------------------------------------
# Parameter checks
# --------------------------------------------------------------------------------------------


def check_positive(name: str, value: object) -> float:
    """``value`` as a float, refused unless it is a finite number > 0.

    Args:
        name: parameter name, quoted in the error message.
        value: the caller's value (any type; strings that parse as numbers are accepted).

    Raises:
        TwinError: not a number, not finite, or not positive.
    """
    try:
        out = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise TwinError(f"{name} must be a positive number, got {value!r}") from None
    if not (math.isfinite(out) and out > 0.0):
        raise TwinError(f"{name} must be a positive finite number, got {value!r}")
    return out


def check_finite(name: str, value: object) -> float:
    """``value`` as a float, refused unless it is a finite number (see :func:`check_positive`)."""
    try:
        out = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise TwinError(f"{name} must be a finite number, got {value!r}") from None
    if not math.isfinite(out):
        raise TwinError(f"{name} must be a finite number, got {value!r}")
    return out


def check_nonnegative(name: str, value: object) -> float:
    """``value`` as a float, refused unless it is a finite number >= 0 (see :func:`check_positive`)."""
    out = check_finite(name, value)
    if out < 0.0:
        raise TwinError(f"{name} must be >= 0, got {value!r}")
    return out


def require(condition: bool, message: str) -> None:
    """Raise :class:`TwinError` with ``message`` (one line) unless ``condition`` holds."""
    if not condition:
        raise TwinError(message)


def format_mm(value: float) -> str:
    """A length [m] for error messages, in millimetres to 3 significant digits: ``"12.5 mm"``."""
    return f"{value * 1e3:.3g} mm"


def check_resolution(resolution_m: object, chord_tolerance_m: object | None = None) -> tuple[float, ...]:
    """Check the tessellation parameters every generator takes.

    Args:
        resolution_m: largest edge [m] on the curved surfaces, 0.1 mm to 10 mm.
        chord_tolerance_m: largest chord deviation [m], 0.1 um to 1 mm; None when the
            generator has none.

    Returns:
        ``(resolution,)`` when ``chord_tolerance_m`` is None, else ``(resolution, tolerance)``,
        floats [m].

    Raises:
        TwinError: a value is not a number or is out of its range.
    """
    res = check_positive("resolution_m", resolution_m)
    require(
        1e-4 <= res <= 0.01,
        f"resolution_m must be between 0.1 mm and 10 mm, got {format_mm(res)}",
    )
    if chord_tolerance_m is None:
        return (res,)
    tol = check_positive("chord_tolerance_m", chord_tolerance_m)
    require(
        1e-7 <= tol <= 1e-3,
        f"chord_tolerance_m must be between 0.1 um and 1 mm, got {tol * 1e6:.3g} um",
    )
    return res, tol


# --------------------------------------------------------------------------------------------
# Planar regions: conforming Delaunay with graded interior points
# --------------------------------------------------------------------------------------------


def _hex_lattice(lo: np.ndarray, hi: np.ndarray, spacing: float) -> np.ndarray:
    """Points of a triangular lattice covering the box [lo, hi] (2-D)."""
    row = spacing * math.sqrt(3.0) / 2.0
    ys = np.arange(lo[1], hi[1] + row, row)
    xs = np.arange(lo[0] - spacing, hi[0] + spacing, spacing)
    gx, gy = np.meshgrid(xs, ys)
    gx = gx + (np.arange(len(ys)) % 2)[:, None] * (spacing / 2.0)
    return np.column_stack([gx.ravel(), gy.ravel()])


def _hex_lattice_near(
    lo: np.ndarray, hi: np.ndarray, spacing: float, centers: np.ndarray, reach: float
) -> np.ndarray:
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


def _inside(points: np.ndarray, seg_a: np.ndarray, seg_b: np.ndarray) -> np.ndarray:
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


def _mesh_planar_region(
    loops: Sequence[np.ndarray], max_edge: float, grading: float = PLANAR_GRADING
) -> tuple[np.ndarray, np.ndarray]:
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
    """
    loops = [np.asarray(lp, dtype=np.float64) for lp in loops]
    boundary = np.concatenate(loops)
    n_boundary = len(boundary)
    seg_a_list, seg_b_list, seg_index_list = [], [], []
    offset = 0
    for lp in loops:
        n = len(lp)
        idx = np.arange(n) + offset
        seg_a_list.append(lp)
        seg_b_list.append(np.roll(lp, -1, axis=0))
        seg_index_list.append(np.column_stack([idx, np.roll(idx, -1)]))
        offset += n
    seg_a = np.concatenate(seg_a_list)
    seg_b = np.concatenate(seg_b_list)
    seg_len = np.linalg.norm(seg_b - seg_a, axis=1)
    seg_mid = 0.5 * (seg_a + seg_b)
    seg_index = np.concatenate(seg_index_list)

    # Dense samples of the boundary give the distance to it and the local spacing there.
    min_len = float(seg_len.min())
    pieces = np.maximum(1, np.ceil(seg_len / (0.25 * min_len + 1e-300)).astype(int))
    pieces = np.minimum(pieces, 64)
    dense_parts, dense_spacing_parts = [], []
    for k in np.unique(pieces):
        sel = np.nonzero(pieces == k)[0]
        t = (np.arange(k) / k)[None, :, None]
        pts = seg_a[sel, None, :] + t * (seg_b[sel] - seg_a[sel])[:, None, :]
        dense_parts.append(pts.reshape(-1, 2))
        dense_spacing_parts.append(np.repeat(seg_len[sel], k))
    dense = np.concatenate(dense_parts)
    dense_spacing = np.concatenate(dense_spacing_parts)
    dense_tree = cKDTree(dense)
    mid_tree = cKDTree(seg_mid)
    max_seg = float(seg_len.max())

    lo, hi = boundary.min(axis=0), boundary.max(axis=0)

    def target_size(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        dist, nearest = dense_tree.query(pts)
        return np.minimum(max_edge, dense_spacing[nearest] + grading * dist), dist

    def admissible(pts: np.ndarray) -> np.ndarray:
        """Inside, clear of the boundary, and outside every segment's diametral circle."""
        size, dist = target_size(pts)
        ok = dist >= _CLEARANCE * size
        ok[ok] = _inside(pts[ok], seg_a, seg_b)
        rows = np.nonzero(ok)[0]
        if len(rows):
            near = mid_tree.query_ball_point(pts[rows], r=0.56 * max_seg)
            counts = np.fromiter((len(js) for js in near), dtype=np.int64, count=len(near))
            if counts.sum():
                which = np.repeat(rows, counts)
                js = np.concatenate([np.asarray(j, dtype=np.int64) for j in near if j])
                inside_circle = np.linalg.norm(seg_mid[js] - pts[which], axis=1) < (
                    0.56 * seg_len[js]
                )
                ok[which[inside_circle]] = False
        return ok

    # Level spacings max_edge / 2^k down to the finest boundary spacing.
    levels = [max_edge]
    while levels[-1] > min_len:
        levels.append(levels[-1] / 2.0)
    accepted = [boundary]
    accepted_tree = cKDTree(boundary)
    for k in range(len(levels) - 1, -1, -1):
        h = levels[k]
        if k == 0:
            cand = _hex_lattice(lo, hi, h)
        else:
            # Sizes below 2 h occur only within (2 h - s) / grading of boundary samples
            # spaced s < 2 h: build this level's lattice only in tiles that reach them.
            fine = dense_spacing < 2.0 * h
            if not np.any(fine):
                continue
            reach = float(np.max(2.0 * h - dense_spacing[fine])) / grading
            cand = _hex_lattice_near(lo, hi, h, dense[fine], reach)
        cand = cand[(cand[:, 0] > lo[0]) & (cand[:, 0] < hi[0])]
        cand = cand[(cand[:, 1] > lo[1]) & (cand[:, 1] < hi[1])]
        if len(cand) == 0:
            continue
        size, _ = target_size(cand)
        upper = np.inf if k == 0 else 2.0 * h
        lower = 0.0 if k == len(levels) - 1 else h
        cand = cand[(size >= lower) & (size < upper)]
        if len(cand) == 0:
            continue
        d_acc, _ = accepted_tree.query(cand)
        cand = cand[d_acc >= 0.7 * h]
        cand = cand[admissible(cand)]
        if len(cand) == 0:
            continue
        accepted.append(cand)
        accepted_tree = cKDTree(np.concatenate(accepted))
    points = np.concatenate(accepted)

    # Ghost points keep the boundary points off the convex hull (Qhull would drop collinear
    # hull points); triangles touching them are outside the region and discarded.
    margin = 2.0 * max(max_edge, max_seg)
    glo, ghi = lo - margin, hi + margin
    nx = max(2, int(math.ceil((ghi[0] - glo[0]) / max_edge)))
    ny = max(2, int(math.ceil((ghi[1] - glo[1]) / max_edge)))
    gx = np.linspace(glo[0], ghi[0], nx + 1)
    gy = np.linspace(glo[1], ghi[1], ny + 1)
    ghosts = np.concatenate(
        [
            np.column_stack([gx, np.full_like(gx, glo[1])]),
            np.column_stack([gx, np.full_like(gx, ghi[1])]),
            np.column_stack([np.full_like(gy[1:-1], glo[0]), gy[1:-1]]),
            np.column_stack([np.full_like(gy[1:-1], ghi[0]), gy[1:-1]]),
        ]
    )

    def triangulate(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        tri = Delaunay(np.concatenate([pts, ghosts])).simplices
        tri = tri[np.all(tri < len(pts), axis=1)]
        tri = tri[_inside(pts[tri].mean(axis=1), seg_a, seg_b)]
        p0, p1, p2 = pts[tri[:, 0]], pts[tri[:, 1]], pts[tri[:, 2]]
        cross = (p1[:, 0] - p0[:, 0]) * (p2[:, 1] - p0[:, 1]) - (p1[:, 1] - p0[:, 1]) * (
            p2[:, 0] - p0[:, 0]
        )
        return np.where((cross < 0.0)[:, None], tri[:, [0, 2, 1]], tri), np.abs(cross)

    # Smooth the lattice seams: move each interior point toward the mean of its neighbours
    # (a few damped Laplacian steps), refusing moves that break the conditions above.
    n_pts = len(points)
    for _ in range(_SMOOTHING_STEPS):
        if n_pts == n_boundary:
            break
        tri, _ = triangulate(points)
        edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
        adj = coo_matrix(
            (np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n_pts, n_pts)
        ).tocsr()
        adj = ((adj + adj.T) > 0).astype(np.float64)
        degree = np.asarray(adj.sum(axis=1)).ravel()
        mean = (adj @ points) / np.maximum(degree, 1.0)[:, None]
        moved = points[n_boundary:] + 0.6 * (mean[n_boundary:] - points[n_boundary:])
        ok = admissible(moved)
        points[n_boundary:][ok] = moved[ok]
    tri, cross = triangulate(points)

    # Conformity: every loop segment is the edge of exactly one triangle, every other edge of
    # two. Anything else is a bug (or parameters the generators should have refused).
    edges = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
    uniq, counts = np.unique(edges, axis=0, return_counts=True)
    seg_sorted = np.unique(np.sort(seg_index, axis=1), axis=0)
    boundary_edges = uniq[counts == 1]
    if (
        np.any(counts > 2)
        or len(boundary_edges) != len(seg_sorted)
        or not np.array_equal(boundary_edges, seg_sorted)
        or len(np.unique(tri)) != len(points)
        or np.any(np.abs(cross) <= 1e-18 * max_edge**2)
    ):
        raise RuntimeError("internal error: planar face triangulation does not conform")
    return points, tri


def planar_patch(
    loops3d: Sequence[np.ndarray],
    origin: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    outward: np.ndarray,
    max_edge: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Mesh a planar face given by 3-D boundary loops lying in the plane (origin, u, v).

    The loop points are kept as the patch's boundary vertices, unchanged and in order, so a
    neighbouring patch built on the same loop is stitched exactly by :func:`assemble`.

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


# --------------------------------------------------------------------------------------------
# Surfaces of revolution
# --------------------------------------------------------------------------------------------


def _graded(values: np.ndarray, arc: np.ndarray, grading: float) -> np.ndarray:
    """Smallest ``values[j] + grading * |arc[i] - arc[j]|`` over j, for samples along a curve."""
    out = values.copy()
    for i in range(1, len(out)):
        out[i] = min(out[i], out[i - 1] + grading * (arc[i] - arc[i - 1]))
    for i in range(len(out) - 2, -1, -1):
        out[i] = min(out[i], out[i + 1] + grading * (arc[i + 1] - arc[i]))
    return out


def sample_profile(
    segments: Sequence[Callable[[np.ndarray], np.ndarray]], resolution: float, chord_tol: float
) -> tuple[np.ndarray, np.ndarray]:
    """Stations along a profile to be revolved, and the ring edge length at each.

    The segments map t in [0, 1] to (K, 2) points (r, a): radius and axial coordinate; they
    join end to start. A chord of length c deviates from a curve of curvature k by about
    ``c^2 k / 8``; so that chords and the diagonals of the cells they span (up to sqrt(2)
    longer) stay within ``chord_tol``:

    * ring edges are at most ``min(resolution, sqrt(4 chord_tol r / n_r))`` (the ring's
      curvature seen along the surface normal is n_r / r, n_r the normal's radial part:
      1 on a cylinder, 0 on a flat disk);
    * profile steps are at most ``min(resolution, sqrt(4 chord_tol / k), 2 ring edge)``.

    Both are graded along the profile (they grow by at most half the distance travelled)
    so that a fine ring at a sharp edge does not meet a coarse one. Segment ends are kept.

    Args:
        segments: profile curves (e.g. :func:`line_segment`, :func:`cubic_bezier`), each
            mapping t (K,) in [0, 1] to (K, 2) points (r, a) [m].
        resolution: largest ring edge and profile step [m].
        chord_tol: largest chord deviation from the curves [m].

    Returns:
        profile: (K, 2) stations (r, a) [m].
        ring_edge: (K,) ring edge length at each station [m].
    """
    dense, arc_parts, step_parts, edge_parts, ends = [], [], [], [], []
    arc0 = 0.0
    for seg in segments:
        t = np.linspace(0.0, 1.0, 2001)
        p = seg(t)
        d1 = np.gradient(p, t, axis=0)
        d2 = np.gradient(d1, t, axis=0)
        speed = np.linalg.norm(d1, axis=1)
        curv = np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / np.maximum(speed, 1e-300) ** 3
        arc = arc0 + np.concatenate(
            [[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(t))]
        )
        radial_normal = np.abs(d1[:, 1]) / np.maximum(speed, 1e-300)
        # On the axis (a pole) or where the normal is axial, rings do not leave the surface.
        curved_ring = (radial_normal > 1e-9) & (p[:, 0] > 1e-12)
        ring_edge = np.full(len(t), resolution)
        ring_edge[curved_ring] = np.minimum(
            resolution,
            np.sqrt(4.0 * chord_tol * p[curved_ring, 0] / radial_normal[curved_ring]),
        )
        step = np.minimum(resolution, np.sqrt(4.0 * chord_tol / np.maximum(curv, 1e-12)))
        dense.append((seg, t, arc))
        arc_parts.append(arc)
        edge_parts.append(ring_edge)
        step_parts.append(step)
        ends.append(arc[-1])
        arc0 = arc[-1]
    arc_all = np.concatenate(arc_parts)
    floor = 0.05 * resolution  # near a pole the ring edge tends to 0; the ring count is >= 3
    edge_all = _graded(np.maximum(np.concatenate(edge_parts), floor), arc_all, 0.5)
    step_all = _graded(np.minimum(np.concatenate(step_parts), 2.0 * edge_all), arc_all, 0.5)

    out, offset = [], 0
    for seg, t, arc in dense:
        n_t = len(t)
        step = step_all[offset : offset + n_t]
        offset += n_t
        density = 1.0 / step
        cum = np.concatenate([[0.0], np.cumsum(0.5 * (density[1:] + density[:-1]) * np.diff(arc))])
        n = max(1, int(math.ceil(cum[-1] - 1e-9)))
        t_s = np.interp(np.linspace(0.0, cum[-1], n + 1), cum, t)
        t_s[0], t_s[-1] = 0.0, 1.0
        samples = seg(t_s)
        arc_s = np.interp(t_s, t, arc)
        out.append((samples, arc_s) if not out else (samples[1:], arc_s[1:]))
    profile = np.concatenate([o[0] for o in out])
    arc_stations = np.concatenate([o[1] for o in out])
    # At a station shared by two segments (a sharp edge) the finer ring edge wins, which the
    # graded field already holds there: the dense samples of both segments share its arc.
    ring_edge = np.interp(arc_stations, arc_all, edge_all)
    at_joint = np.isin(arc_stations, np.asarray(ends[:-1]))
    for i in np.nonzero(at_joint)[0]:
        ring_edge[i] = float(edge_all[arc_all == arc_stations[i]].min())
    return profile, ring_edge


def line_segment(p: Sequence[float], q: Sequence[float]) -> Callable[[np.ndarray], np.ndarray]:
    """Straight profile segment from p to q, for :func:`sample_profile`.

    Args:
        p, q: (2,) end points (r, a) [m].

    Returns:
        f(t) for t (K,) in [0, 1]: (K, 2) points; f(1) is exactly q.
    """
    p_arr, q_arr = np.asarray(p, dtype=np.float64), np.asarray(q, dtype=np.float64)

    def f(t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)[:, None]
        out = p_arr + t * (q_arr - p_arr)
        out[t[:, 0] == 1.0] = q_arr
        return out

    return f


def cubic_bezier(control: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """Cubic Bezier profile segment, for :func:`sample_profile`.

    Args:
        control: (4, 2) control points (r, a) [m].

    Returns:
        f(t) for t (K,) in [0, 1]: (K, 2) points of the curve.
    """
    c = np.asarray(control, dtype=np.float64)

    def f(t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)[:, None]
        s = 1.0 - t
        return s**3 * c[0] + 3 * s**2 * t * c[1] + 3 * s * t**2 * c[2] + t**3 * c[3]

    return f


def _zip_rings(a: np.ndarray, b: np.ndarray, pa: np.ndarray, pb: np.ndarray, closed: bool):
    """Triangulate the strip between two rings of vertex indices (a earlier on the profile).

    Triangles are oriented along d(angle) x d(profile). Advancing along the shorter diagonal
    keeps the triangles well shaped.
    """
    tris = []
    na, nb = len(a), len(b)
    if na == 1 or nb == 1:
        if na == 1 and nb == 1:
            return np.zeros((0, 3), dtype=np.int64)
        ring, is_a = (b, False) if na == 1 else (a, True)
        pole = a[0] if na == 1 else b[0]
        n = len(ring)
        pairs = [(ring[i], ring[(i + 1) % n]) for i in range(n if closed else n - 1)]
        for r0, r1 in pairs:
            tris.append((r0, r1, pole) if is_a else (pole, r1, r0))
        return np.asarray(tris, dtype=np.int64)
    if closed:
        k0 = int(np.argmin(np.linalg.norm(pb - pa[0], axis=1)))
        order_b = np.roll(np.arange(nb), -k0)
        seq_a = np.concatenate([np.arange(na), [0]])
        seq_b = np.concatenate([order_b, [order_b[0]]])
        last_i, last_k = na, nb
    else:
        seq_a, seq_b = np.arange(na), np.arange(nb)
        last_i, last_k = na - 1, nb - 1
    i = k = 0
    while i < last_i or k < last_k:
        ai, bk = seq_a[i], seq_b[k]
        if i == last_i:
            advance_a = False
        elif k == last_k:
            advance_a = True
        else:
            diag_a = np.linalg.norm(pa[seq_a[i + 1]] - pb[bk])
            diag_b = np.linalg.norm(pb[seq_b[k + 1]] - pa[ai])
            advance_a = diag_a <= diag_b
        if advance_a:
            tris.append((a[ai], a[seq_a[i + 1]], b[bk]))
            i += 1
        else:
            tris.append((a[ai], b[seq_b[k + 1]], b[bk]))
            k += 1
    return np.asarray(tris, dtype=np.int64)


def revolve(
    profile: np.ndarray,
    ring_edge: np.ndarray,
    half: bool = False,
    rotation: np.ndarray | None = None,
    origin: Sequence[float] = (0.0, 0.0, 0.0),
) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """Revolve a sampled profile about the local z axis.

    Local point = (r cos(phi), r sin(phi), a); world = origin + rotation @ local. A full
    revolution has closed rings; ``half`` sweeps phi over [0, pi] with both ends kept.
    Stations with r = 0 become a single pole vertex. Triangles are oriented along
    d(phi) x d(profile), i.e. outward for a profile that runs up the axis with the material
    toward the axis.

    Args:
        profile: (K, 2) stations (r, a) [m], r >= 0 (from :func:`sample_profile`).
        ring_edge: (K,) largest ring edge at each station [m].
        half: sweep phi over [0, pi] only (open rings) instead of a full turn.
        rotation: (3, 3) local-to-world rotation; identity when None.
        origin: (3,) [m] world position of the local origin.

    Returns:
        vertices (N, 3) [m], triangles (M, 3) int, and the vertex indices of each ring
        (K arrays, ring k at profile station k; a pole is a ring of one vertex).
    """
    rot = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
    org = np.asarray(origin, dtype=np.float64)
    span = math.pi if half else 2.0 * math.pi
    verts, rings, tris = [], [], []
    count = 0
    for k, (r, a) in enumerate(profile):
        if r <= 1e-12:
            local = np.array([[0.0, 0.0, a]])
        else:
            edge = float(ring_edge[k])
            if half:
                m = max(2, int(math.ceil(span * r / edge)))
                phi = np.linspace(0.0, math.pi, m + 1)
                phi[-1] = math.pi
            else:
                m = max(3, int(math.ceil(span * r / edge)))
                phi = (np.arange(m) + 0.5 * (k % 2)) * (span / m)
            c, s = np.cos(phi), np.sin(phi)
            if half:
                c[0], s[0], c[-1], s[-1] = 1.0, 0.0, -1.0, 0.0
            local = np.column_stack([r * c, r * s, np.full(len(phi), a)])
        world = org + local @ rot.T
        rings.append(np.arange(count, count + len(world)))
        verts.append(world)
        count += len(world)
    vertices = np.concatenate(verts)
    for k in range(len(rings) - 1):
        a_idx, b_idx = rings[k], rings[k + 1]
        tris.append(
            _zip_rings(a_idx, b_idx, vertices[a_idx], vertices[b_idx], closed=not half)
        )
    return vertices, np.concatenate(tris), rings


# --------------------------------------------------------------------------------------------
# Boxes and assembly
# --------------------------------------------------------------------------------------------


class _SizeField:
    """Target edge length near curved features: ``min(max_edge, s + grading * distance)``.

    Args:
        points: (N, 3) [m] feature vertices (e.g. the rings where curved surfaces meet a
            planar face), or empty.
        spacing: (N,) [m] edge length at each of them.
        max_edge: cap [m].
    """

    def __init__(self, points: np.ndarray, spacing: np.ndarray, max_edge: float) -> None:
        self.max_edge = max_edge
        self.points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        self.spacing = np.asarray(spacing, dtype=np.float64).reshape(-1)
        self.tree = cKDTree(self.points) if len(self.points) else None

    def __call__(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64).reshape(-1, 3)
        if self.tree is None:
            return np.full(len(x), self.max_edge)
        # The smallest target over the nearest few features, not just the nearest one.
        k = min(16, len(self.points))
        dist, idx = self.tree.query(x, k=k)
        dist, idx = dist.reshape(len(x), k), idx.reshape(len(x), k)
        size = self.spacing[idx] + PLANAR_GRADING * dist
        return np.minimum(self.max_edge, size.min(axis=1))


def _loop_spacing(loop: np.ndarray) -> np.ndarray:
    """(n,) mean length of the two edges at each vertex of a closed loop (n, 3)."""
    lengths = np.linalg.norm(np.roll(loop, -1, axis=0) - loop, axis=1)
    return 0.5 * (lengths + np.roll(lengths, 1))


def edge_points(p: np.ndarray, q: np.ndarray, size: Callable[[np.ndarray], np.ndarray] | float
                 ) -> np.ndarray:
    """Points from p to q (both included) spaced by a size field, identical either way.

    Sampling p -> q and q -> p gives the same points (reversed), so two patches that share
    the edge share its vertices exactly.

    Args:
        p, q: (3,) end points [m].
        size: target spacing [m], constant or a function of (K, 3) points returning (K,).

    Returns:
        (n, 3) [m] points, p first and q last (exactly).
    """
    p, q = np.asarray(p, dtype=np.float64), np.asarray(q, dtype=np.float64)
    flip = tuple(q) < tuple(p)
    a, b = (q, p) if flip else (p, q)
    length = float(np.linalg.norm(b - a))
    t = np.linspace(0.0, 1.0, 1001)
    if callable(size):
        h = size(a + t[:, None] * (b - a))
    else:
        h = np.full_like(t, float(size))
    density = length / h
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (density[1:] + density[:-1]) * np.diff(t))])
    n = max(1, int(math.ceil(cum[-1] - 1e-9)))
    t_s = np.interp(np.linspace(0.0, cum[-1], n + 1), cum, t)
    pts = a + t_s[:, None] * (b - a)
    pts[0], pts[-1] = a, b
    return pts[::-1] if flip else pts


def _polygon_loop(
    corners: Sequence[np.ndarray], size: Callable[[np.ndarray], np.ndarray] | float
) -> np.ndarray:
    """Closed loop through the corners, each side sampled by :func:`edge_points`."""
    parts = []
    n = len(corners)
    for i in range(n):
        parts.append(edge_points(corners[i], corners[(i + 1) % n], size)[:-1])
    return np.concatenate(parts)


def box_patches(
    lo: Sequence[float],
    hi: Sequence[float],
    max_edge: float,
    top_holes: Sequence[np.ndarray] = (),
    end_holes: dict[int, Sequence[np.ndarray]] | None = None,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """The six faces of an axis-aligned box, with optional holes in the top and x-end faces.

    The box edges are graded toward the holes so that the faces meet them with short edges
    where the holes come near.

    Args:
        lo, hi: (3,) lowest and highest corners [m].
        max_edge: largest edge [m].
        top_holes: loops (n, 3) [m] in the plane z = hi[2] cut out of the top face (e.g. a
            ring of :func:`revolve`, so the curved surface and the face share it).
        end_holes: {-1: loops in x = lo[0], +1: loops in x = hi[0]}.

    Returns:
        Six patches (vertices (N_i, 3) [m], triangles (M_i, 3) int), wound outward: top,
        bottom, -y, +y, -x, +x faces.
    """
    x0, y0, z0 = (float(c) for c in lo)
    x1, y1, z1 = (float(c) for c in hi)
    end_holes = end_holes or {}
    all_holes = list(top_holes) + [h for hs in end_holes.values() for h in hs]
    if all_holes:
        size = _SizeField(
            np.concatenate(all_holes),
            np.concatenate([_loop_spacing(h) for h in all_holes]),
            max_edge,
        )
    else:
        size = _SizeField(np.zeros((0, 3)), np.zeros(0), max_edge)

    def corner(x: float, y: float, z: float) -> np.ndarray:
        return np.array([x, y, z])

    ex, ey, ez = np.eye(3)
    faces = [
        # (corners, u, v, outward, holes)
        ([corner(x0, y0, z1), corner(x1, y0, z1), corner(x1, y1, z1), corner(x0, y1, z1)],
         ex, ey, ez, list(top_holes)),
        ([corner(x0, y0, z0), corner(x1, y0, z0), corner(x1, y1, z0), corner(x0, y1, z0)],
         ex, ey, -ez, []),
        ([corner(x0, y0, z0), corner(x1, y0, z0), corner(x1, y0, z1), corner(x0, y0, z1)],
         ex, ez, -ey, []),
        ([corner(x0, y1, z0), corner(x1, y1, z0), corner(x1, y1, z1), corner(x0, y1, z1)],
         ex, ez, ey, []),
        ([corner(x0, y0, z0), corner(x0, y1, z0), corner(x0, y1, z1), corner(x0, y0, z1)],
         ey, ez, -ex, list(end_holes.get(-1, []))),
        ([corner(x1, y0, z0), corner(x1, y1, z0), corner(x1, y1, z1), corner(x1, y0, z1)],
         ey, ez, ex, list(end_holes.get(1, []))),
    ]
    patches = []
    for corners, u, v, outward, holes in faces:
        loop = _polygon_loop(corners, size)
        patches.append(planar_patch([loop, *holes], corners[0], u, v, outward, max_edge))
    return patches


BOX_FACES = ("top", "bottom", "front", "back", "left", "right")
"""Names of :func:`box_patches`' six faces, in its order (+z, -z, -y, +y, -x, +x)."""


def box_features(prefix: str) -> list[str]:
    """Feature names of :func:`box_patches`' faces: ``PREFIX_top``, ``PREFIX_bottom``, ..."""
    return [f"{prefix}_{face}" for face in BOX_FACES]


def assemble(patches: Sequence[tuple[np.ndarray, np.ndarray]], name: str,
             features: Sequence[str] | None = None) -> trimesh.Trimesh:
    """Stitch patches into one mesh by merging coincident vertices, and check the solid.

    Args:
        patches: (vertices (N_i, 3) [m], triangles (M_i, 3) int) pairs, each wound outward.
        name: the part's name, for the messages.
        features: optional name of each patch (the CAD feature it is; patches may share a
            name), kept as ``mesh.metadata["features"]``: {name: (K,) face indices}.

    Returns:
        Closed, consistently wound mesh of positive volume (``process=False``: vertices are
        the patches' in order of first appearance, merged within 1 nm; faces in the patches'
        order).

    Raises:
        TwinError: more faces than MuJoCo accepts (200,000).
        RuntimeError: the patches do not close a valid solid (a generator bug).
    """
    vertices, faces, offset = [], [], 0
    for v, f in patches:
        vertices.append(np.asarray(v, dtype=np.float64))
        faces.append(np.asarray(f, dtype=np.int64) + offset)
        offset += len(v)
    v_all = np.concatenate(vertices)
    f_all = np.concatenate(faces)
    pairs = cKDTree(v_all).query_pairs(_MERGE_TOL_M, output_type="ndarray")
    n = len(v_all)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    _, first = np.unique(labels, return_index=True)
    v_merged = v_all[first]
    f_merged = labels[f_all]
    if len(f_merged) > _MAX_FACES:
        raise TwinError(
            f"{name} has {len(f_merged)} faces at this resolution; allowed are at most "
            f"{_MAX_FACES} (MuJoCo refuses larger meshes): use a coarser resolution_m"
        )
    mesh = trimesh.Trimesh(vertices=v_merged, faces=f_merged, process=False)
    if features is not None:
        if len(features) != len(patches):
            raise RuntimeError(f"internal error: {name}: {len(features)} feature names for {len(patches)} patches")
        owner = np.repeat(np.arange(len(patches)), [len(f) for _, f in patches])
        names = np.asarray(features, dtype=object)[owner]
        mesh.metadata["features"] = {n: np.flatnonzero(names == n) for n in dict.fromkeys(features)}
    problems = []
    if np.any(f_merged[:, 0] == f_merged[:, 1]) or np.any(f_merged[:, 1] == f_merged[:, 2]) or (
        np.any(f_merged[:, 0] == f_merged[:, 2])
    ):
        problems.append("collapsed faces")
    if not mesh.is_watertight:
        problems.append("not watertight")
    if not mesh.is_winding_consistent:
        problems.append("inconsistent winding")
    if mesh.volume <= 0.0:
        problems.append("non-positive volume")
    if problems:
        raise RuntimeError(f"internal error: {name} mesh is invalid ({', '.join(problems)})")
    return mesh


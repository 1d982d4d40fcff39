"""Procedural CAD workpieces of the source documents, and loading a user's mesh.

Every generator returns one watertight, consistently wound ``trimesh.Trimesh`` with outward
normals, in the workpiece frame: metres, z up, the part resting on z = 0 (its bottom face lies
in that plane), roughly centred on the origin in x and y.

The meshes are built surface by surface so that the solid is closed by construction (no
boolean engine is needed): curved surfaces are evaluated exactly on their analytic or Bezier
definition and tessellated; planar faces are meshed by a conforming Delaunay triangulation of
their boundary loops with graded interior points, so that triangles stay well shaped (MuJoCo's
ray casts are slow on long slivers) and face counts moderate.

The source documents give no dimensions for any of these parts; the defaults are plausible
choices documented on each generator:

* ``s_surface``: document 004's S-shaped surface part (laser-scanned by the robot).
* ``hemisphere_punch``: document 000's workpiece A (hemisphere + plate + four small cylinders).
* ``bottle_punch``: document 000's workpiece B (plate + half plastic bottle of Bezier patches).
* ``inner_sphere``: document 002's "inner sphere containing a cylinder" (a spherical cavity
  opened at the top face of a block, with a cylindrical post standing inside it).
* ``through_hole``: document 002's block with a horizontal through hole.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import Delaunay, cKDTree

from twin.errors import TwinError

__all__ = [
    "WORKPIECE_NAMES",
    "MESH_EXTENSIONS",
    "s_surface",
    "s_surface_height",
    "s_surface_normal",
    "hemisphere_punch",
    "bottle_punch",
    "bottle_profile_bezier",
    "inner_sphere",
    "through_hole",
    "make_workpiece",
    "load_mesh",
]

WORKPIECE_NAMES: tuple[str, ...] = (
    "s_surface",
    "hemisphere_punch",
    "bottle_punch",
    "inner_sphere",
    "through_hole",
)
"""Names accepted by :func:`make_workpiece`."""

MESH_EXTENSIONS: tuple[str, ...] = (".stl", ".obj", ".ply")
"""File extensions accepted by :func:`load_mesh` (case-insensitive)."""

# Largest edge [m] of the graded planar faces, far from curved features.
_PLANAR_MAX_EDGE_M = 0.005
# Growth of the planar edge length per unit distance from the nearest boundary: 0.3 lets the
# edge grow from 0.5 mm to 5 mm over 15 mm while neighbouring triangles differ by < 1.5x.
_PLANAR_GRADING = 0.3
# MuJoCo's mesh loader refuses meshes with more faces than this.
_MAX_FACES = 200_000
# Two points closer than this [m] are the same vertex when the surfaces are stitched; every
# generated edge is micrometres long at least, so this cannot merge distinct vertices.
_MERGE_TOL_M = 1e-9
# Smallest distance of an interior point from the boundary, relative to the local edge length.
_CLEARANCE = 0.55
# Damped Laplacian smoothing steps applied to the interior points of planar faces.
_SMOOTHING_STEPS = 4
# Default chord tolerance [m] of the curved surfaces: the mesh deviates from them by less.
_CHORD_TOL_M = 1e-5


# --------------------------------------------------------------------------------------------
# Parameter checks
# --------------------------------------------------------------------------------------------


def _positive(name: str, value: object) -> float:
    try:
        out = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise TwinError(f"{name} must be a positive number, got {value!r}") from None
    if not (math.isfinite(out) and out > 0.0):
        raise TwinError(f"{name} must be a positive finite number, got {value!r}")
    return out


def _finite(name: str, value: object) -> float:
    try:
        out = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise TwinError(f"{name} must be a finite number, got {value!r}") from None
    if not math.isfinite(out):
        raise TwinError(f"{name} must be a finite number, got {value!r}")
    return out


def _nonnegative(name: str, value: object) -> float:
    out = _finite(name, value)
    if out < 0.0:
        raise TwinError(f"{name} must be >= 0, got {value!r}")
    return out


def _require(condition: bool, message: str) -> None:
    if not condition:
        raise TwinError(message)


def _mm(value: float) -> str:
    return f"{value * 1e3:.3g} mm"


def _check_resolution(resolution_m: object, chord_tolerance_m: object | None = None) -> tuple:
    res = _positive("resolution_m", resolution_m)
    _require(
        1e-4 <= res <= 0.01,
        f"resolution_m must be between 0.1 mm and 10 mm, got {_mm(res)}",
    )
    if chord_tolerance_m is None:
        return (res,)
    tol = _positive("chord_tolerance_m", chord_tolerance_m)
    _require(
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
    loops: Sequence[np.ndarray], max_edge: float, grading: float = _PLANAR_GRADING
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


def _planar_patch(
    loops3d: Sequence[np.ndarray],
    origin: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    outward: np.ndarray,
    max_edge: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Mesh a planar face given by 3-D boundary loops lying in the plane (origin, u, v)."""
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


def _sample_profile(
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


def _line(p: Sequence[float], q: Sequence[float]) -> Callable[[np.ndarray], np.ndarray]:
    p_arr, q_arr = np.asarray(p, dtype=np.float64), np.asarray(q, dtype=np.float64)

    def f(t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)[:, None]
        out = p_arr + t * (q_arr - p_arr)
        out[t[:, 0] == 1.0] = q_arr
        return out

    return f


def _bezier(control: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
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


def _revolve(
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
        profile: (K, 2) stations (r, a) [m], r >= 0 (from :func:`_sample_profile`).
        ring_edge: (K,) largest ring edge at each station [m].

    Returns:
        vertices (N, 3) [m], triangles (M, 3), and the vertex indices of each ring.
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
        size = self.spacing[idx] + _PLANAR_GRADING * dist
        return np.minimum(self.max_edge, size.min(axis=1))


def _loop_spacing(loop: np.ndarray) -> np.ndarray:
    """(n,) mean length of the two edges at each vertex of a closed loop (n, 3)."""
    lengths = np.linalg.norm(np.roll(loop, -1, axis=0) - loop, axis=1)
    return 0.5 * (lengths + np.roll(lengths, 1))


def _edge_points(p: np.ndarray, q: np.ndarray, size: Callable[[np.ndarray], np.ndarray] | float
                 ) -> np.ndarray:
    """Points from p to q (both included) spaced by the size field, identical either way."""
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
    """Closed loop through the corners, each side sampled by :func:`_edge_points`."""
    parts = []
    n = len(corners)
    for i in range(n):
        parts.append(_edge_points(corners[i], corners[(i + 1) % n], size)[:-1])
    return np.concatenate(parts)


def _box_patches(
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
        lo, hi: opposite corners [m].
        max_edge: largest edge [m].
        top_holes: loops (n, 3) in the plane z = hi[2] cut out of the top face.
        end_holes: {-1: loops in x = lo[0], +1: loops in x = hi[0]}.
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
        patches.append(_planar_patch([loop, *holes], corners[0], u, v, outward, max_edge))
    return patches


def _assemble(patches: Sequence[tuple[np.ndarray, np.ndarray]], name: str) -> trimesh.Trimesh:
    """Stitch patches into one mesh by merging coincident vertices, and check the solid."""
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


# --------------------------------------------------------------------------------------------
# 004: S-shaped surface part
# --------------------------------------------------------------------------------------------


def _s_params(
    length_m: float,
    width_m: float,
    base_thickness_m: float,
    amplitude_m: float,
    amplitude_gradient: float,
    crown_m: float,
) -> tuple[float, float, float, float, float, float]:
    length = _positive("length_m", length_m)
    width = _positive("width_m", width_m)
    base = _positive("base_thickness_m", base_thickness_m)
    amp = _nonnegative("amplitude_m", amplitude_m)
    grad = _finite("amplitude_gradient", amplitude_gradient)
    crown = _finite("crown_m", crown_m)
    _require(
        abs(grad) < 1.0,
        f"amplitude_gradient must be in (-1, 1), got {amplitude_gradient!r}",
    )
    lowest = base - amp * (1.0 + abs(grad)) - max(0.0, -crown)
    _require(
        lowest >= 0.2 * base and lowest >= 0.002,
        "base_thickness_m must exceed amplitude_m * (1 + |amplitude_gradient|) plus any "
        f"negative crown by a margin (the top must stay >= 2 mm and >= 20 % of the base "
        f"thickness above z = 0), got a lowest top at {_mm(lowest)}",
    )
    return length, width, base, amp, grad, crown


def s_surface_height(
    x: np.ndarray | float,
    y: np.ndarray | float,
    length_m: float = 0.12,
    width_m: float = 0.08,
    base_thickness_m: float = 0.03,
    amplitude_m: float = 0.01,
    amplitude_gradient: float = 0.3,
    crown_m: float = 0.002,
    resolution_m: float | None = None,
) -> np.ndarray:
    """Analytic height of the S-surface part's top, in the workpiece frame.

    ``z = base + amplitude * (1 + g * yn) * sin(pi * xn) + crown * yn**2`` with
    ``xn = 2 x / length`` and ``yn = 2 y / width`` in [-1, 1] over the footprint: one full
    sine period across x (the S), its amplitude changing linearly across y, and a gentle
    crown in y. The function is defined everywhere; the part covers only its footprint.

    Args:
        x, y: coordinates [m], workpiece frame, any broadcastable shapes.
        length_m, width_m, base_thickness_m, amplitude_m, amplitude_gradient, crown_m: as in
            :func:`s_surface`.
        resolution_m: accepted so that the same keyword set as :func:`s_surface` can be
            passed; it has no effect.

    Returns:
        z [m], the broadcast shape of x and y.
    """
    del resolution_m
    length, width, base, amp, grad, crown = _s_params(
        length_m, width_m, base_thickness_m, amplitude_m, amplitude_gradient, crown_m
    )
    xn = 2.0 * np.asarray(x, dtype=np.float64) / length
    yn = 2.0 * np.asarray(y, dtype=np.float64) / width
    return base + amp * (1.0 + grad * yn) * np.sin(np.pi * xn) + crown * yn**2


def s_surface_normal(
    x: np.ndarray | float,
    y: np.ndarray | float,
    length_m: float = 0.12,
    width_m: float = 0.08,
    base_thickness_m: float = 0.03,
    amplitude_m: float = 0.01,
    amplitude_gradient: float = 0.3,
    crown_m: float = 0.002,
    resolution_m: float | None = None,
) -> np.ndarray:
    """Unit outward (upward) normal of the analytic S-surface top at (x, y).

    Args:
        x, y: coordinates [m], workpiece frame, any broadcastable shapes S.
        Other arguments: as in :func:`s_surface_height`.

    Returns:
        (*S, 3) unit normals, workpiece frame.
    """
    del resolution_m
    length, width, _, amp, grad, crown = _s_params(
        length_m, width_m, base_thickness_m, amplitude_m, amplitude_gradient, crown_m
    )
    x_arr, y_arr = np.broadcast_arrays(
        np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    )
    xn, yn = 2.0 * x_arr / length, 2.0 * y_arr / width
    dz_dx = amp * (1.0 + grad * yn) * np.cos(np.pi * xn) * np.pi * 2.0 / length
    dz_dy = (amp * grad * np.sin(np.pi * xn) + 2.0 * crown * yn) * 2.0 / width
    n = np.stack([-dz_dx, -dz_dy, np.ones_like(dz_dx)], axis=-1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def _graded_drop(height: float, fine: float, coarse: float) -> np.ndarray:
    """Distances below a top corner [m], 0 first and ``height`` last, fine near the top."""
    d = [0.0]
    step = fine
    while d[-1] + step < height - 0.5 * min(step, coarse):
        d.append(d[-1] + step)
        step = min(coarse, step * (1.0 + _PLANAR_GRADING))
    d.append(height)
    return np.asarray(d)


def s_surface(
    length_m: float = 0.12,
    width_m: float = 0.08,
    base_thickness_m: float = 0.03,
    amplitude_m: float = 0.01,
    amplitude_gradient: float = 0.3,
    crown_m: float = 0.002,
    resolution_m: float = 0.0005,
) -> trimesh.Trimesh:
    """Document 004's S-shaped surface part: a block whose top is a free-form S surface.

    The top is :func:`s_surface_height` over the footprint [-length/2, length/2] x
    [-width/2, width/2], tessellated as a regular grid (each cell split along the diagonal
    that better fits the surface); vertical side walls and a flat bottom at z = 0 close it.
    Document 004 names the part ("S 形表面的工件") without dimensions; the defaults are sized
    for its Keyence IL-065 sensor (55-105 mm range) and 4 mm scan-line spacing.

    The amplitude gradient and crown make the top free-form (not an extruded or revolved
    surface), and the sine is odd in x, so no rigid motion other than the identity maps the
    part onto itself: it can be localised in all 6 DOF, from the top alone.

    With the defaults the top's chord error against the analytic height is about 1 um
    (below 2 um) and the mesh has about 87k faces (77k of them on the top).

    Args:
        length_m: footprint along x [m].
        width_m: footprint along y [m].
        base_thickness_m: mean height of the top above the bottom face [m].
        amplitude_m: amplitude of the S (sine) across x at y = 0 [m].
        amplitude_gradient: relative change of the amplitude from y = 0 to the y = +-width/2
            edges (dimensionless, |g| < 1).
        crown_m: rise of the top at the y edges relative to y = 0 [m] (may be negative).
        resolution_m: grid spacing of the top [m] (the walls and bottom are graded from it
            up to 5 mm).

    Returns:
        Watertight mesh [m], workpiece frame, bottom face at z = 0.

    Raises:
        TwinError: a parameter is not a positive finite number or the top would come within
            2 mm of the bottom.
    """
    length, width, base, amp, grad, crown = _s_params(
        length_m, width_m, base_thickness_m, amplitude_m, amplitude_gradient, crown_m
    )
    (res,) = _check_resolution(resolution_m)
    params = dict(
        length_m=length, width_m=width, base_thickness_m=base, amplitude_m=amp,
        amplitude_gradient=grad, crown_m=crown,
    )
    nx = max(2, int(math.ceil(length / res - 1e-9)))
    ny = max(2, int(math.ceil(width / res - 1e-9)))
    _require(
        (nx + 1) * (ny + 1) <= 400_000,
        f"resolution_m {_mm(res)} gives a {nx} x {ny} grid; allowed are at most "
        "400,000 top vertices (MuJoCo refuses meshes over 200k faces)",
    )
    xs = np.linspace(-length / 2, length / 2, nx + 1)
    ys = np.linspace(-width / 2, width / 2, ny + 1)
    xs[0], xs[-1], ys[0], ys[-1] = -length / 2, length / 2, -width / 2, width / 2
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    gz = s_surface_height(gx, gy, **params)
    top_v = np.column_stack([gx.ravel(), gy.ravel(), gz.ravel()])
    idx = np.arange((nx + 1) * (ny + 1)).reshape(nx + 1, ny + 1)
    v00, v10 = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    v11, v01 = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    # Split each cell along the diagonal whose midpoint lies closer to the surface.
    xc = 0.5 * (gx[:-1, :-1] + gx[1:, 1:]).ravel()
    yc = 0.5 * (gy[:-1, :-1] + gy[1:, 1:]).ravel()
    zc = s_surface_height(xc, yc, **params)
    err_main = np.abs(0.5 * (top_v[v00, 2] + top_v[v11, 2]) - zc)
    err_anti = np.abs(0.5 * (top_v[v10, 2] + top_v[v01, 2]) - zc)
    main = err_main <= err_anti
    top_f = np.concatenate(
        [
            np.column_stack([v00, v10, v11])[main],
            np.column_stack([v00, v11, v01])[main],
            np.column_stack([v00, v10, v01])[~main],
            np.column_stack([v10, v11, v01])[~main],
        ]
    )
    patches = [(top_v, top_f)]

    coarse = max(res, _PLANAR_MAX_EDGE_M)
    x0, x1, y0, y1 = -length / 2, length / 2, -width / 2, width / 2
    corner_xy = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    verticals = []
    for cx, cy in corner_xy:
        zc_top = float(s_surface_height(cx, cy, **params))
        drop = _graded_drop(zc_top, res, coarse)
        z = zc_top - drop
        z[-1] = 0.0
        z[0] = zc_top
        verticals.append(np.column_stack([np.full_like(z, cx), np.full_like(z, cy), z]))
    # Top edges of the walls, each running between consecutive corners (counter-clockwise).
    top_edges = [
        top_v[idx[:, 0]],
        top_v[idx[-1, :]],
        top_v[idx[::-1, -1]],
        top_v[idx[0, ::-1]],
    ]
    outward = [np.array([0.0, -1.0, 0.0]), np.array([1.0, 0.0, 0.0]),
               np.array([0.0, 1.0, 0.0]), np.array([-1.0, 0.0, 0.0])]
    bottom_edges = []
    for i in range(4):
        j = (i + 1) % 4
        p = np.array([*corner_xy[i], 0.0])
        q = np.array([*corner_xy[j], 0.0])
        bottom = _edge_points(p, q, coarse)
        bottom_edges.append(bottom)
        # Loop: bottom edge i -> j, up corner j, top edge j -> i, down corner i.
        loop = np.concatenate(
            [bottom[:-1], verticals[j][::-1][:-1], top_edges[i][::-1][:-1], verticals[i][:-1]]
        )
        u = (q - p) / np.linalg.norm(q - p)
        patches.append(_planar_patch([loop], p, u, np.array([0.0, 0.0, 1.0]), outward[i], coarse))
    bottom_loop = np.concatenate([e[:-1] for e in bottom_edges])
    patches.append(
        _planar_patch(
            [bottom_loop], bottom_loop[0], np.array([1.0, 0.0, 0.0]),
            np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, -1.0]), coarse,
        )
    )
    return _assemble(patches, "s_surface")


# --------------------------------------------------------------------------------------------
# 000 workpiece A: hemisphere punch
# --------------------------------------------------------------------------------------------


def hemisphere_punch(
    plate_length_m: float = 0.12,
    plate_width_m: float = 0.10,
    plate_thickness_m: float = 0.02,
    hemisphere_radius_m: float = 0.035,
    hemisphere_offset_x_m: float = 0.01,
    pin_radius_m: float = 0.006,
    pin_height_m: float = 0.015,
    pin_inset_m: float = 0.012,
    resolution_m: float = 0.001,
    chord_tolerance_m: float = _CHORD_TOL_M,
) -> trimesh.Trimesh:
    """Document 000's workpiece A, the hemisphere punch: plate + hemisphere + four pins.

    A rectangular plate [-L/2, L/2] x [-W/2, W/2] x [0, T], a hemisphere of radius R standing
    on its top face with its centre at (offset_x, 0, T), and four small cylinders (pins) on the
    top face, one near each corner, their axes ``pin_inset_m`` from the two nearest plate
    edges. Document 000 gives no dimensions; these are plausible for a small punch.

    Symmetry: with ``hemisphere_offset_x_m != 0`` (the default) and a non-square plate, no
    rigid motion other than the identity maps the part onto itself. With offset 0 the part
    has the 180 degree rotation about z (and the 90 degree ones if the plate is square).

    Args:
        plate_length_m: plate size along x [m].
        plate_width_m: plate size along y [m].
        plate_thickness_m: plate thickness [m].
        hemisphere_radius_m: hemisphere radius [m].
        hemisphere_offset_x_m: x of the hemisphere centre [m].
        pin_radius_m: pin (cylinder) radius [m].
        pin_height_m: pin height above the plate [m].
        pin_inset_m: distance of each pin axis from the two nearest plate edges [m].
        resolution_m: largest edge on the curved surfaces [m] (planar faces grade to 5 mm).
        chord_tolerance_m: largest deviation of the curved surfaces' triangles from the
            exact surface [m] (edges are also capped at ``resolution_m``).

    Returns:
        Watertight mesh [m], workpiece frame, bottom face at z = 0.

    Raises:
        TwinError: a size is not positive or the hemisphere and pins do not fit on the plate
            with at least 1 mm between them and to the plate edges.
    """
    length = _positive("plate_length_m", plate_length_m)
    width = _positive("plate_width_m", plate_width_m)
    thick = _positive("plate_thickness_m", plate_thickness_m)
    radius = _positive("hemisphere_radius_m", hemisphere_radius_m)
    offset = _finite("hemisphere_offset_x_m", hemisphere_offset_x_m)
    pin_r = _positive("pin_radius_m", pin_radius_m)
    pin_h = _positive("pin_height_m", pin_height_m)
    inset = _positive("pin_inset_m", pin_inset_m)
    res, tol = _check_resolution(resolution_m, chord_tolerance_m)
    gap = 0.001
    _require(
        abs(offset) + radius + gap <= length / 2 and radius + gap <= width / 2,
        f"the hemisphere (radius {_mm(radius)} at x = {_mm(offset)}) must lie on the "
        f"{_mm(length)} x {_mm(width)} plate with >= 1 mm to its edges",
    )
    _require(
        inset >= pin_r + gap and 2 * inset + 2 * pin_r + gap <= min(length, width),
        f"pin_inset_m must be >= pin_radius_m + 1 mm and leave the pins apart, got inset "
        f"{_mm(inset)} with pin radius {_mm(pin_r)}",
    )
    pins = [(sx * (length / 2 - inset), sy * (width / 2 - inset)) for sx in (-1, 1)
            for sy in (-1, 1)]
    for px, py in pins:
        _require(
            math.hypot(px - offset, py) >= radius + pin_r + gap,
            f"a pin at ({_mm(px)}, {_mm(py)}) overlaps the hemisphere; move the pins out "
            "(pin_inset_m) or shrink the hemisphere (>= 1 mm clearance needed)",
        )

    patches = []
    holes = []
    hemi_profile, hemi_edges = _sample_profile(
        [lambda t: np.column_stack([radius * np.cos(0.5 * np.pi * t),
                                    thick + radius * np.sin(0.5 * np.pi * t)])],
        res, tol,
    )
    hemi_profile[-1] = (0.0, thick + radius)
    v, f, rings = _revolve(hemi_profile, hemi_edges, origin=(offset, 0.0, 0.0))
    patches.append((v, f))
    holes.append(v[rings[0]])
    for px, py in pins:
        profile, edges = _sample_profile(
            [_line((pin_r, thick), (pin_r, thick + pin_h)),
             _line((pin_r, thick + pin_h), (0.0, thick + pin_h))],
            res, tol,
        )
        v, f, rings = _revolve(profile, edges, origin=(px, py, 0.0))
        patches.append((v, f))
        holes.append(v[rings[0]])
    patches.extend(
        _box_patches((-length / 2, -width / 2, 0.0), (length / 2, width / 2, thick),
                     max(res, _PLANAR_MAX_EDGE_M), top_holes=holes)
    )
    return _assemble(patches, "hemisphere_punch")


# --------------------------------------------------------------------------------------------
# 000 workpiece B: bottle punch
# --------------------------------------------------------------------------------------------


def _bottle_checks(
    plate_length_m: float,
    plate_width_m: float,
    plate_thickness_m: float,
    bottle_length_m: float,
    body_radius_m: float,
    neck_radius_m: float,
    bottle_offset_x_m: float,
) -> tuple[float, ...]:
    length = _positive("plate_length_m", plate_length_m)
    width = _positive("plate_width_m", plate_width_m)
    thick = _positive("plate_thickness_m", plate_thickness_m)
    b_len = _positive("bottle_length_m", bottle_length_m)
    body = _positive("body_radius_m", body_radius_m)
    neck = _positive("neck_radius_m", neck_radius_m)
    offset = _finite("bottle_offset_x_m", bottle_offset_x_m)
    _require(
        neck * 1.2 <= 0.9 * body,
        f"neck_radius_m must be at most 0.75 x body_radius_m (the bead on the neck is 1.2 x "
        f"the neck radius), got neck {_mm(neck)} and body {_mm(body)}",
    )
    _require(
        b_len >= 2.0 * body,
        f"bottle_length_m must be at least 2 x body_radius_m, got {_mm(b_len)} and body "
        f"radius {_mm(body)}",
    )
    _require(
        abs(offset) + b_len / 2 + 0.001 <= length / 2 and body + 0.001 <= width / 2,
        f"the bottle ({_mm(b_len)} long, radius {_mm(body)}, at x = {_mm(offset)}) must lie "
        f"on the {_mm(length)} x {_mm(width)} plate with >= 1 mm to its edges",
    )
    return length, width, thick, b_len, body, neck, offset


def bottle_profile_bezier(
    plate_length_m: float = 0.15,
    plate_width_m: float = 0.08,
    plate_thickness_m: float = 0.015,
    bottle_length_m: float = 0.11,
    body_radius_m: float = 0.025,
    neck_radius_m: float = 0.011,
    bottle_offset_x_m: float = 0.0,
    resolution_m: float | None = None,
    chord_tolerance_m: float | None = None,
) -> np.ndarray:
    """Control points of the bottle's profile: eight cubic Bezier segments.

    Each segment is (x, r): x along the bottle axis (the workpiece x axis) and r the radius.
    The bottle surface is ``(x(t), r(t) cos(phi), T + r(t) sin(phi))`` for phi in [0, pi]
    (T the plate thickness); split at phi = pi / 2 it is 16 Bezier patches (the angular
    direction being an exact circle, i.e. a rational Bezier). Flat half-disks close the
    bottle's base (x = x_start, r <= first control point's r) and mouth (x = x_end).
    The segments are: heel fillet, two body segments with a grip waist, shoulder, neck,
    two bead segments, mouth; consecutive segments join with a continuous tangent.

    Args:
        As :func:`bottle_punch` (``resolution_m`` and ``chord_tolerance_m`` are accepted and
        have no effect).

    Returns:
        (8, 4, 2) control points [m].
    """
    del resolution_m, chord_tolerance_m
    _, _, _, b_len, body, neck, offset = _bottle_checks(
        plate_length_m, plate_width_m, plate_thickness_m, bottle_length_m, body_radius_m,
        neck_radius_m, bottle_offset_x_m,
    )
    a0 = offset - b_len / 2
    big_l, big_r, n = b_len, body, neck
    fillet = 0.12 * big_r
    waist = 0.08 * big_r
    bead = 0.2 * n

    def ax(u: float) -> float:
        return a0 + u * big_l

    segs = [
        # heel fillet: from the base disk's rim (vertical tangent) onto the body
        [(a0, big_r - fillet), (a0, big_r - 0.45 * fillet), (a0 + 0.45 * fillet, big_r),
         (a0 + fillet, big_r)],
        # body into the grip waist
        [(a0 + fillet, big_r), (ax(0.14), big_r), (ax(0.2), big_r - waist),
         (ax(0.3), big_r - waist)],
        # out of the waist
        [(ax(0.3), big_r - waist), (ax(0.37), big_r - waist), (ax(0.43), big_r),
         (ax(0.5), big_r)],
        # shoulder
        [(ax(0.5), big_r), (ax(0.62), big_r), (ax(0.62), n), (ax(0.72), n)],
        # neck
        [(ax(0.72), n), (ax(0.7467), n), (ax(0.7733), n), (ax(0.8), n)],
        # bead up
        [(ax(0.8), n), (ax(0.82), n), (ax(0.82), n + bead), (ax(0.84), n + bead)],
        # bead down
        [(ax(0.84), n + bead), (ax(0.86), n + bead), (ax(0.86), n), (ax(0.88), n)],
        # mouth
        [(ax(0.88), n), (ax(0.92), n), (ax(0.96), n), (ax(1.0), n)],
    ]
    return np.asarray(segs, dtype=np.float64)


def bottle_punch(
    plate_length_m: float = 0.15,
    plate_width_m: float = 0.08,
    plate_thickness_m: float = 0.015,
    bottle_length_m: float = 0.11,
    body_radius_m: float = 0.025,
    neck_radius_m: float = 0.011,
    bottle_offset_x_m: float = 0.0,
    resolution_m: float = 0.001,
    chord_tolerance_m: float = _CHORD_TOL_M,
) -> trimesh.Trimesh:
    """Document 000's workpiece B, the plastic-bottle punch: a plate and half a bottle.

    The bottle (axis along x at y = 0, z = T) is cut along its axis; the upper half lies on
    the plate's top face. Its surface is the profile of :func:`bottle_profile_bezier`
    (eight cubic Bezier segments, 16 patches over the half turn, evaluated exactly) closed
    by flat half-disks at the base and the mouth. Document 000 gives no dimensions ("a dozen
    Bezier patches"); these are plausible for a small bottle mould.

    Symmetry: the mirror y -> -y maps the part onto itself, but it is not a rigid motion
    (it reverses orientation). The bottle's two ends differ, so no proper rigid motion other
    than the identity maps the part onto itself.

    Args:
        plate_length_m: plate size along x [m].
        plate_width_m: plate size along y [m].
        plate_thickness_m: plate thickness T [m].
        bottle_length_m: bottle length, base to mouth [m].
        body_radius_m: body radius [m].
        neck_radius_m: neck radius [m].
        bottle_offset_x_m: x of the bottle's middle [m] (the base is toward -x).
        resolution_m: largest edge on the curved surfaces [m] (planar faces grade to 5 mm).
        chord_tolerance_m: largest deviation of the bottle's triangles from its Bezier
            surface [m] (edges are also capped at ``resolution_m``).

    Returns:
        Watertight mesh [m], workpiece frame, bottom face at z = 0.

    Raises:
        TwinError: a size is not positive, the neck is too wide for the body, or the bottle
            does not fit on the plate with >= 1 mm margin.
    """
    length, width, thick, b_len, body, neck, offset = _bottle_checks(
        plate_length_m, plate_width_m, plate_thickness_m, bottle_length_m, body_radius_m,
        neck_radius_m, bottle_offset_x_m,
    )
    res, tol = _check_resolution(resolution_m, chord_tolerance_m)
    ctrl = bottle_profile_bezier(
        plate_length_m=length, plate_width_m=width, plate_thickness_m=thick,
        bottle_length_m=b_len, body_radius_m=body, neck_radius_m=neck,
        bottle_offset_x_m=offset,
    )
    a0, a1 = ctrl[0, 0, 0], ctrl[-1, -1, 0]
    # Profile as (r, a): base disk, the Bezier segments, mouth disk.
    segments = [_line((0.0, a0), (ctrl[0, 0, 1], a0))]
    segments += [_bezier(c[:, ::-1]) for c in ctrl]
    segments += [_line((ctrl[-1, -1, 1], a1), (0.0, a1))]
    profile, edges = _sample_profile(segments, res, tol)
    # Local frame: axis along +x, phi = 0 toward +y, phi = pi/2 toward +z.
    rot = np.column_stack([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    v, f, rings = _revolve(profile, edges, half=True, rotation=rot, origin=(0.0, 0.0, thick))
    # Footprint on the plate: the phi = pi ends (y < 0) base to mouth, then phi = 0 back.
    minus = [v[r[-1]] for r in rings]
    plus = [v[r[0]] for r in rings[1:-1]][::-1]
    footprint = np.asarray(minus + plus)
    patches = [(v, f)]
    patches.extend(
        _box_patches((-length / 2, -width / 2, 0.0), (length / 2, width / 2, thick),
                     max(res, _PLANAR_MAX_EDGE_M), top_holes=[footprint])
    )
    return _assemble(patches, "bottle_punch")


# --------------------------------------------------------------------------------------------
# 002: inner sphere containing a cylinder, and the through hole
# --------------------------------------------------------------------------------------------


def inner_sphere(
    block_length_m: float = 0.10,
    block_width_m: float = 0.10,
    block_height_m: float = 0.06,
    sphere_radius_m: float = 0.04,
    sphere_center_depth_m: float = 0.01,
    post_radius_m: float = 0.01,
    post_top_depth_m: float = 0.0,
    resolution_m: float = 0.001,
    chord_tolerance_m: float = _CHORD_TOL_M,
) -> trimesh.Trimesh:
    """Document 002's "inner sphere containing a cylinder" (內(nèi)部包含柱體的內(nèi)球).

    A block [-L/2, L/2] x [-W/2, W/2] x [0, H] with a spherical cavity of radius R, centred on
    the z axis ``sphere_center_depth_m`` below the top face, so that the cavity opens in the
    top face through a circle slightly smaller than its equator (the inner sphere is measured
    from inside). A cylindrical post of radius ``post_radius_m`` stands on the cavity floor
    on the axis, up to ``post_top_depth_m`` below the top face: a probe moving between
    points on opposite sides of the sphere must go over it, across the safety plane (the
    top face), as in the document's experiment (safety distance 30 mm). Document 002 gives
    no dimensions; these are plausible. Reading: 內(nèi)球 is a concave sphere measured from
    inside, 柱體 the obstacle within it that the probe must go around ("繞過柱體"), and the
    safety plane is the part's top face (上表面), which a free-standing sphere would not have.

    Symmetry: rotations about the z axis by multiples of 90 degrees (180 if L != W) map the
    part onto itself (irrelevant to path planning, which is what document 002 uses it for).

    Args:
        block_length_m: block size along x [m].
        block_width_m: block size along y [m].
        block_height_m: block height H [m].
        sphere_radius_m: cavity radius R [m].
        sphere_center_depth_m: depth of the sphere centre below the top face [m].
        post_radius_m: post radius [m].
        post_top_depth_m: depth of the post's top below the top face [m] (0: flush).
        resolution_m: largest edge on the curved surfaces [m] (planar faces grade to 5 mm).
        chord_tolerance_m: largest deviation of the curved surfaces' triangles from the
            exact surface [m] (edges are also capped at ``resolution_m``).

    Returns:
        Watertight mesh [m], workpiece frame, bottom face at z = 0.

    Raises:
        TwinError: a size is not positive, or the cavity would not open in the top face,
            break through a side or the bottom (2 mm minimum wall), or not contain the post.
    """
    length = _positive("block_length_m", block_length_m)
    width = _positive("block_width_m", block_width_m)
    height = _positive("block_height_m", block_height_m)
    radius = _positive("sphere_radius_m", sphere_radius_m)
    depth = _nonnegative("sphere_center_depth_m", sphere_center_depth_m)
    post_r = _positive("post_radius_m", post_radius_m)
    post_depth = _nonnegative("post_top_depth_m", post_top_depth_m)
    res, tol = _check_resolution(resolution_m, chord_tolerance_m)
    wall = 0.002
    _require(
        depth <= 0.9 * radius,
        f"sphere_center_depth_m must be at most 0.9 x sphere_radius_m so the cavity opens in "
        f"the top face, got {_mm(depth)} with radius {_mm(radius)}",
    )
    _require(
        radius + wall <= min(length, width) / 2,
        f"sphere_radius_m {_mm(radius)} leaves less than a 2 mm wall in the "
        f"{_mm(length)} x {_mm(width)} block",
    )
    zc = height - depth
    _require(
        zc - radius >= wall,
        f"block_height_m {_mm(height)} leaves less than a 2 mm floor under the cavity "
        f"(radius {_mm(radius)}, centre {_mm(depth)} below the top)",
    )
    opening = math.sqrt(radius**2 - depth**2)
    _require(
        post_r + 0.001 <= opening,
        f"post_radius_m must be at least 1 mm smaller than the opening radius "
        f"{_mm(opening)}, got {_mm(post_r)}",
    )
    z_foot = zc - math.sqrt(radius**2 - post_r**2)
    z_post = height - post_depth
    _require(
        z_post - z_foot >= 0.001,
        f"post_top_depth_m {_mm(post_depth)} puts the post's top below the cavity floor",
    )
    theta_open = math.atan2(depth, opening)  # angle of the rim above the equator
    theta_foot = -math.atan2(math.sqrt(radius**2 - post_r**2), post_r)

    def sphere_arc(t: np.ndarray) -> np.ndarray:
        th = theta_open + (theta_foot - theta_open) * t
        return np.column_stack([radius * np.cos(th), zc + radius * np.sin(th)])

    profile, edges = _sample_profile(
        [sphere_arc, _line((post_r, z_foot), (post_r, z_post)),
         _line((post_r, z_post), (0.0, z_post))],
        res, tol,
    )
    profile[0] = (opening, height)
    v, f, rings = _revolve(profile, edges)
    patches = [(v, f)]
    patches.extend(
        _box_patches((-length / 2, -width / 2, 0.0), (length / 2, width / 2, height),
                     max(res, _PLANAR_MAX_EDGE_M), top_holes=[v[rings[0]]])
    )
    return _assemble(patches, "inner_sphere")


def through_hole(
    block_length_m: float = 0.08,
    block_width_m: float = 0.06,
    block_height_m: float = 0.04,
    hole_diameter_m: float = 0.02,
    hole_center_height_m: float = 0.02,
    resolution_m: float = 0.001,
    chord_tolerance_m: float = _CHORD_TOL_M,
) -> trimesh.Trimesh:
    """Document 002's block with a through hole, measured from both ends.

    A block [-L/2, L/2] x [-W/2, W/2] x [0, H] with a horizontal cylindrical hole along x
    (axis y = 0, z = ``hole_center_height_m``) from end face to end face. The hole is
    horizontal because the document measures its two ends and moves the probe over the top
    face (the safety plane) between them. No dimensions are given; these are plausible.

    Symmetry: with the hole at mid-height the block has the three 180 degree rotations about
    the axes through its centre; the hole's ends are indistinguishable.

    Args:
        block_length_m: block size along x, the hole's length [m].
        block_width_m: block size along y [m].
        block_height_m: block height H [m].
        hole_diameter_m: hole diameter [m].
        hole_center_height_m: height of the hole axis above the bottom [m].
        resolution_m: largest edge on the hole surface [m] (planar faces grade to 5 mm).
        chord_tolerance_m: largest deviation of the curved surfaces' triangles from the
            exact surface [m] (edges are also capped at ``resolution_m``).

    Returns:
        Watertight mesh [m] of genus 1, workpiece frame, bottom face at z = 0.

    Raises:
        TwinError: a size is not positive or the hole leaves less than a 2 mm wall.
    """
    length = _positive("block_length_m", block_length_m)
    width = _positive("block_width_m", block_width_m)
    height = _positive("block_height_m", block_height_m)
    radius = _positive("hole_diameter_m", hole_diameter_m) / 2.0
    zh = _positive("hole_center_height_m", hole_center_height_m)
    res, tol = _check_resolution(resolution_m, chord_tolerance_m)
    wall = 0.002
    _require(
        radius + wall <= width / 2 and zh - radius >= wall and zh + radius + wall <= height,
        f"the hole (diameter {_mm(2 * radius)} at height {_mm(zh)}) must leave >= 2 mm walls "
        f"in the {_mm(width)} wide, {_mm(height)} high block",
    )
    # Run the profile from +x to -x so the triangles face the axis (out of the material).
    profile, edges = _sample_profile(
        [_line((radius, length / 2), (radius, -length / 2))], res, tol
    )
    rot = np.column_stack([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    v, f, rings = _revolve(profile, edges, rotation=rot, origin=(0.0, 0.0, zh))
    patches = [(v, f)]
    patches.extend(
        _box_patches((-length / 2, -width / 2, 0.0), (length / 2, width / 2, height),
                     max(res, _PLANAR_MAX_EDGE_M),
                     end_holes={1: [v[rings[0]]], -1: [v[rings[-1]]]})
    )
    return _assemble(patches, "through_hole")


# --------------------------------------------------------------------------------------------
# Dispatch and loading
# --------------------------------------------------------------------------------------------

_GENERATORS: dict[str, Callable[..., trimesh.Trimesh]] = {
    "s_surface": s_surface,
    "hemisphere_punch": hemisphere_punch,
    "bottle_punch": bottle_punch,
    "inner_sphere": inner_sphere,
    "through_hole": through_hole,
}


def make_workpiece(name: str, **params: object) -> trimesh.Trimesh:
    """Build a named workpiece.

    Args:
        name: one of :data:`WORKPIECE_NAMES`.
        **params: keyword arguments of that generator (all have defaults).

    Returns:
        Watertight mesh [m], workpiece frame, bottom face at z = 0.

    Raises:
        TwinError: unknown name, unknown parameter, or a parameter the generator refuses.
    """
    if not isinstance(name, str) or name not in _GENERATORS:
        raise TwinError(
            f"unknown workpiece {name!r}; valid names are: {', '.join(WORKPIECE_NAMES)}"
        )
    generator = _GENERATORS[name]
    valid = list(inspect.signature(generator).parameters)
    for key in params:
        if key not in valid:
            raise TwinError(
                f"unknown parameter {key!r} for workpiece {name!r}; valid parameters are: "
                f"{', '.join(valid)}"
            )
    return generator(**params)


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text or type(exc).__name__


def load_mesh(path: str | Path, units: str) -> trimesh.Trimesh:
    """Load a user's workpiece mesh (STL, OBJ or PLY) and convert it to metres.

    A file holding several bodies (an OBJ with several objects, a scene) is concatenated
    into one mesh. The mesh is returned as stored (vertices merged, no repair); callers that
    need a closed solid check ``is_watertight``.

    Args:
        path: file path; the extension (case-insensitive) must be one of
            :data:`MESH_EXTENSIONS`.
        units: length unit of the file's coordinates, "m" or "mm".

    Returns:
        Mesh with vertices in metres, in the file's own frame.

    Raises:
        TwinError: bad units, unsupported extension, missing or unreadable file, or a file
            that holds no triangles.
    """
    if units not in ("m", "mm"):
        raise TwinError(f"units must be 'm' or 'mm', got {units!r}")
    p = Path(path)
    ext = p.suffix.lower()
    if ext not in MESH_EXTENSIONS:
        raise TwinError(
            f"unsupported mesh file extension {p.suffix or '(none)'!r} for {str(p)!r}; "
            f"allowed: {', '.join(MESH_EXTENSIONS)}"
        )
    if not p.exists():
        raise TwinError(f"mesh file not found: {str(p)!r}")
    if not p.is_file():
        raise TwinError(f"mesh path is not a file: {str(p)!r}")
    try:
        loaded = trimesh.load(str(p), file_type=ext[1:], process=True)
    except Exception as exc:  # noqa: BLE001 - any parser failure is an unreadable file
        raise TwinError(f"could not read mesh file {str(p)!r}: {_one_line(exc)}") from exc
    if isinstance(loaded, trimesh.Scene):
        geometries = [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh) and len(g.faces)]
        if not geometries:
            raise TwinError(f"mesh file {str(p)!r} has no faces")
        mesh = trimesh.util.concatenate(geometries) if len(geometries) > 1 else geometries[0]
    elif isinstance(loaded, trimesh.Trimesh):
        mesh = loaded
    else:
        raise TwinError(
            f"mesh file {str(p)!r} has no faces (it holds a {type(loaded).__name__})"
        )
    if len(mesh.faces) == 0:
        raise TwinError(f"mesh file {str(p)!r} has no faces")
    if not np.all(np.isfinite(mesh.vertices)):
        raise TwinError(f"mesh file {str(p)!r} has non-finite vertex coordinates")
    if units == "mm":
        mesh.apply_scale(1e-3)
    return mesh


# --------------------------------------------------------------------------------------------
# Registration hook: generated parts defined in other modules (twin/symmetric_parts.py: the
# symmetric and hybrid localization parts) add themselves to make_workpiece and
# WORKPIECE_NAMES here.
# --------------------------------------------------------------------------------------------


def register_workpiece(name: str, generator: Callable[..., trimesh.Trimesh]) -> None:
    """Make ``generator`` available as ``make_workpiece(name)`` and in WORKPIECE_NAMES."""
    global WORKPIECE_NAMES
    if name in _GENERATORS and _GENERATORS[name] is not generator:
        raise TwinError(f"workpiece {name!r} is already registered")
    _GENERATORS[name] = generator
    if name not in WORKPIECE_NAMES:
        WORKPIECE_NAMES = WORKPIECE_NAMES + (name,)


import twin.parts.symmetric  # noqa: E402,F401  (registers its parts through the hook above)

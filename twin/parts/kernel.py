"""Meshing kernel of the generated workpieces: watertight solids built surface by surface.

The generators of :mod:`twin.parts` build every part from the pieces here, so that the solid
is closed by construction (no boolean engine is needed):

* curved surfaces are surfaces of revolution: a profile of :func:`line_segment` and
  :func:`cubic_bezier` curves in (r, a) coordinates, sampled by :func:`sample_profile`
  against a chord tolerance and revolved by :func:`revolve`;
* planar faces are meshed by :func:`~twin.parts.planar.planar_patch` (:mod:`twin.parts.planar`),
  a conforming Delaunay triangulation of their boundary loops with graded interior points;
  :func:`box_patches` gives the six faces of a block with holes cut where curved surfaces
  meet it;
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
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from algorithms.arraytypes import FloatArray, IntArray
from twin.errors import TwinError
from twin.parts.planar import PLANAR_GRADING, planar_patch

__all__ = [
    "CHORD_TOL_M",
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
    "require",
    "revolve",
    "sample_profile",
]

CHORD_TOL_M = 1e-5
"""Default chord tolerance [m] of the curved surfaces: the mesh deviates from them by less."""

# MuJoCo's mesh loader refuses meshes with more faces than this.
_MAX_FACES = 200_000
# Two points closer than this [m] are the same vertex when the surfaces are stitched; every
# generated edge is micrometres long at least, so this cannot merge distinct vertices.
_MERGE_TOL_M = 1e-9


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
# Surfaces of revolution
# --------------------------------------------------------------------------------------------


def _graded(values: FloatArray, arc: FloatArray, grading: float) -> FloatArray:
    """Smallest ``values[j] + grading * |arc[i] - arc[j]|`` over j, for samples along a curve."""
    out = values.copy()
    for i in range(1, len(out)):
        out[i] = min(out[i], out[i - 1] + grading * (arc[i] - arc[i - 1]))
    for i in range(len(out) - 2, -1, -1):
        out[i] = min(out[i], out[i + 1] + grading * (arc[i + 1] - arc[i]))
    return out


# Dense samples per profile segment of the curvature and size analysis of :func:`sample_profile`.
_DENSE_SAMPLES = 2001


@dataclass(frozen=True)
class _DenseSegment:
    """A profile segment sampled densely, with the size limits at each sample.

    Attributes:
        curve: the segment: t (K,) in [0, 1] -> (K, 2) points (r, a) [m].
        t: (D,) parameters of the dense samples.
        arc: (D,) arc length along the whole profile [m].
        ring_edge: (D,) largest ring edge [m] for the chord tolerance (not graded, no floor).
        step: (D,) largest profile step [m] for the chord tolerance (not graded).
    """

    curve: Callable[[FloatArray], FloatArray]
    t: FloatArray
    arc: FloatArray
    ring_edge: FloatArray
    step: FloatArray


def _dense_segment(seg: Callable[[FloatArray], FloatArray], arc0: float, resolution: float,
                   chord_tol: float) -> _DenseSegment:
    """Sample one segment densely and bound its ring edge and profile step (see
    :func:`sample_profile`); its arc length starts at ``arc0`` [m]."""
    t = np.linspace(0.0, 1.0, _DENSE_SAMPLES)
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
    return _DenseSegment(seg, t, arc, ring_edge, step)


def _resample(part: _DenseSegment, step: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Stations (n + 1, 2) of one segment spaced by the graded ``step`` (D,) [m] at its dense
    samples, both ends included exactly, and their arc lengths (n + 1,) [m]."""
    t, arc = part.t, part.arc
    density = 1.0 / step
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (density[1:] + density[:-1]) * np.diff(arc))])
    n = max(1, int(math.ceil(cum[-1] - 1e-9)))
    t_s = np.interp(np.linspace(0.0, cum[-1], n + 1), cum, t)
    t_s[0], t_s[-1] = 0.0, 1.0
    return part.curve(t_s), np.interp(t_s, t, arc)


def _station_ring_edge(arc_stations: FloatArray, arc_all: FloatArray, edge_all: FloatArray,
                       ends: list[float]) -> FloatArray:
    """The graded ring edge (K,) [m] at the stations' arc lengths.

    At a station shared by two segments (a sharp edge) the finer ring edge wins, which the
    graded field already holds there: the dense samples of both segments share its arc.
    """
    ring_edge = np.interp(arc_stations, arc_all, edge_all)
    at_joint = np.isin(arc_stations, np.asarray(ends[:-1]))
    for i in np.nonzero(at_joint)[0]:
        ring_edge[i] = float(edge_all[arc_all == arc_stations[i]].min())
    return ring_edge


def sample_profile(
    segments: Sequence[Callable[[FloatArray], FloatArray]], resolution: float, chord_tol: float
) -> tuple[FloatArray, FloatArray]:
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
    parts: list[_DenseSegment] = []
    arc0 = 0.0
    for seg in segments:
        parts.append(_dense_segment(seg, arc0, resolution, chord_tol))
        arc0 = parts[-1].arc[-1]
    arc_all = np.concatenate([part.arc for part in parts])
    floor = 0.05 * resolution  # near a pole the ring edge tends to 0; the ring count is >= 3
    edge_all = _graded(np.maximum(np.concatenate([part.ring_edge for part in parts]), floor), arc_all, 0.5)
    step_all = _graded(np.minimum(np.concatenate([part.step for part in parts]), 2.0 * edge_all), arc_all, 0.5)

    stations: list[tuple[FloatArray, FloatArray]] = []
    offset = 0
    for part in parts:
        n_t = len(part.t)
        samples, arc_s = _resample(part, step_all[offset : offset + n_t])
        offset += n_t
        stations.append((samples, arc_s) if not stations else (samples[1:], arc_s[1:]))
    profile = np.concatenate([st[0] for st in stations])
    arc_stations = np.concatenate([st[1] for st in stations])
    ends = [part.arc[-1] for part in parts]
    return profile, _station_ring_edge(arc_stations, arc_all, edge_all, ends)


def line_segment(p: Sequence[float], q: Sequence[float]) -> Callable[[FloatArray], FloatArray]:
    """Straight profile segment from p to q, for :func:`sample_profile`.

    Args:
        p, q: (2,) end points (r, a) [m].

    Returns:
        f(t) for t (K,) in [0, 1]: (K, 2) points; f(1) is exactly q.
    """
    p_arr, q_arr = np.asarray(p, dtype=np.float64), np.asarray(q, dtype=np.float64)

    def f(t: FloatArray) -> FloatArray:
        t = np.asarray(t, dtype=np.float64)[:, None]
        out = p_arr + t * (q_arr - p_arr)
        out[t[:, 0] == 1.0] = q_arr
        return out

    return f


def cubic_bezier(control: FloatArray) -> Callable[[FloatArray], FloatArray]:
    """Cubic Bezier profile segment, for :func:`sample_profile`.

    Args:
        control: (4, 2) control points (r, a) [m].

    Returns:
        f(t) for t (K,) in [0, 1]: (K, 2) points of the curve.
    """
    c = np.asarray(control, dtype=np.float64)

    def f(t: FloatArray) -> FloatArray:
        t = np.asarray(t, dtype=np.float64)[:, None]
        s = 1.0 - t
        return s**3 * c[0] + 3 * s**2 * t * c[1] + 3 * s * t**2 * c[2] + t**3 * c[3]

    return f


def _zip_rings(a: IntArray, b: IntArray, pa: FloatArray, pb: FloatArray, closed: bool) -> IntArray:
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
    profile: FloatArray,
    ring_edge: FloatArray,
    half: bool = False,
    rotation: FloatArray | None = None,
    origin: Sequence[float] = (0.0, 0.0, 0.0),
) -> tuple[FloatArray, IntArray, list[IntArray]]:
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
            phi: np.ndarray
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

    def __init__(self, points: FloatArray, spacing: FloatArray, max_edge: float) -> None:
        self.max_edge = max_edge
        self.points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        self.spacing = np.asarray(spacing, dtype=np.float64).reshape(-1)
        self.tree = cKDTree(self.points) if len(self.points) else None

    def __call__(self, x: FloatArray) -> FloatArray:
        x = np.asarray(x, dtype=np.float64).reshape(-1, 3)
        if self.tree is None:
            return np.full(len(x), self.max_edge)
        # The smallest target over the nearest few features, not just the nearest one.
        k = min(16, len(self.points))
        dist, idx = self.tree.query(x, k=k)
        dist, idx = dist.reshape(len(x), k), idx.reshape(len(x), k)
        size = self.spacing[idx] + PLANAR_GRADING * dist
        return np.minimum(self.max_edge, size.min(axis=1))


def _loop_spacing(loop: FloatArray) -> FloatArray:
    """(n,) mean length of the two edges at each vertex of a closed loop (n, 3)."""
    lengths = np.linalg.norm(np.roll(loop, -1, axis=0) - loop, axis=1)
    return 0.5 * (lengths + np.roll(lengths, 1))


def edge_points(p: FloatArray, q: FloatArray, size: Callable[[FloatArray], FloatArray] | float
                 ) -> FloatArray:
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
    corners: Sequence[FloatArray], size: Callable[[FloatArray], FloatArray] | float
) -> FloatArray:
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
    top_holes: Sequence[FloatArray] = (),
    end_holes: dict[int, Sequence[FloatArray]] | None = None,
) -> list[tuple[FloatArray, IntArray]]:
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

    def corner(x: float, y: float, z: float) -> FloatArray:
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


def assemble(patches: Sequence[tuple[FloatArray, IntArray]], name: str,
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


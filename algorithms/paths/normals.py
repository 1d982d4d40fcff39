"""Normals of scan-line clouds (document 004, section 3.2, eqs. 8-10) and k-NN PCA normals.

Cross-line triangulation (document 004): a point ``p = p_i,j`` of line ``i`` has its
neighbours ``a = p_i,j+1`` and ``b = p_i,j-1`` on its own line (the nearest samples at least a
tenth of the line's median step away: a sensor at rest repeats its point) and the nearest points
``n+ `` and ``n-`` on the adjacent lines ``i + 1`` and ``i - 1``. The four triangles of the
fan around ``p``,

    (p, a, n+),  (p, n+, b),  (p, b, n-),  (p, n-, a),

all wound the same way (right-handed about the normal), give eq. (8)'s cross products; the
normal is their area-weighted mean (the sum of the cross products, each twice its triangle's
area, normalised: eqs. 9-10). On the first and last line (one adjacent line) or at a line end
(one neighbour on the line) the triangles that exist are used: two on a boundary, as the
document says, one at a corner. (The document lists the four triangles with one index
garbled; the fan above is the reading whose sum is the central difference
``(a - b) x (n+ - n-)``: second-order accurate when the neighbours sit symmetrically.)

As printed (``triangles="printed"``): the document's own list, with ``n+'`` and ``n-'`` the
points after ``n+`` and ``n-`` on their lines (``p_i+1,j+1`` and ``p_i-1,j+1``),

    (p, a, n-),  (p, n-, n-'),  (p, n-', n+),  (p, n+, n+'),

each "ordered to satisfy the right-hand rule": its normal turned to the side of the fan's (the
orientation the line structure gives), then the area-weighted mean; a triangle whose points
are missing (first or last line, a line's end) is left out, which leaves two on a boundary
(at a corner where none exists, the fan's normal).

Orientation: with lines ordered across the part by ``across`` and points along each line by
``direction`` (as :func:`algorithms.paths.pointcloud.organize_scan_lines` orders them), the fan's
normal is ``direction x across``; ``orient`` (a direction the normals should face, e.g.
towards the sensor) flips the whole set when most of it faces away.

PCA (the usual method, for comparison): the eigenvector of the smallest eigenvalue of the
covariance of the ``k`` nearest neighbours (the point included). Document 004 says it fails on
scan-line clouds because the neighbours all lie on one line; ``benchmarks/results_normals.md``
measures when.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial import cKDTree

from algorithms.arraytypes import ArrayLike, FloatArray
from algorithms.errors import AlgorithmError


class NormalsError(AlgorithmError):
    """Bad input to normal estimation."""


def _check_lines(lines: Sequence[ArrayLike]) -> list[FloatArray]:
    out = []
    for i, line in enumerate(lines):
        a = np.asarray(line, dtype=np.float64)
        if a.ndim != 2 or a.shape[1] != 3:
            raise NormalsError(f"line {i} must be (n, 3), got shape {a.shape}")
        if len(a) == 0:
            raise NormalsError(f"line {i} is empty")
        if not np.all(np.isfinite(a)):
            raise NormalsError(f"line {i} contains NaN or infinite coordinates")
        out.append(a)
    if len(out) < 2:
        raise NormalsError(f"cross-line triangulation needs at least 2 lines, got {len(out)}")
    return out


TRIANGLES = ("fan", "printed")


def triangulation_normals(lines: Sequence[ArrayLike], orient: ArrayLike | None = None,
                          triangles: str = "fan") -> tuple[FloatArray, ...]:
    """Unit normals of every point of a scan-line cloud by cross-line triangulation.

    Args:
        lines: L >= 2 arrays (n_i, 3) [m], ordered along the lines and across (see module).
        orient: optional (3,) direction the normals should face on the whole.
        triangles: ``"fan"`` (ours, the central-difference fan) or ``"printed"`` (the
            document's list; module docstring).

    Returns:
        L arrays (n_i, 3) of unit normals, aligned with ``lines``.

    Raises:
        NormalsError: fewer than 2 lines, an empty line, non-finite points, or a point whose
            triangles are all degenerate (coincident or collinear neighbours).
    """
    if triangles not in TRIANGLES:
        raise NormalsError(f"triangles must be one of {', '.join(TRIANGLES)}, got {triangles!r}")
    L = _check_lines(lines)
    trees = [cKDTree(line) for line in L]
    out = []
    total = np.zeros(3)
    for i, p in enumerate(L):
        n = len(p)
        acc = np.zeros((n, 3))
        # Neighbours on the line: the nearest samples at least a tenth of the median step away
        # (a sensor at rest repeats its point; a near-duplicate neighbour has no direction).
        step = np.linalg.norm(np.diff(p, axis=0), axis=1)
        s = np.concatenate([[0.0], np.cumsum(step)])
        tau = 0.1 * np.median(step) if n > 1 else 0.0
        ia = np.searchsorted(s, s + tau, side="left")
        ia = np.where(ia == np.arange(n), ia + 1, ia)
        ib = np.searchsorted(s, s - tau, side="right") - 1
        ib = np.where(ib == np.arange(n), ib - 1, ib)
        has_a = ia < n
        has_b = ib >= 0
        a = p[np.minimum(ia, n - 1)] - p
        b = p[np.maximum(ib, 0)] - p
        near = {}   # adjacent line -> the index of each point's nearest point on it
        for adj, sign in ((i + 1, 1.0), (i - 1, -1.0)):
            if adj < 0 or adj >= len(L):
                continue
            _, m = trees[adj].query(p)
            near[adj] = m
            c = L[adj][m] - p
            # Next line (sign +1): (p, a, n+) and (p, n+, b); previous line: (p, b, n-), (p, n-, a).
            # Both pairs reduce to sign * (a x c) and sign * (c x b).
            acc += sign * has_a[:, None] * np.cross(a, c)
            acc += sign * has_b[:, None] * np.cross(c, b)
        if triangles == "printed":
            acc = _printed_sum(L, i, p, a, has_a, near, acc)
        norm = np.linalg.norm(acc, axis=1)
        bad = np.flatnonzero(norm <= 1e-300)
        if len(bad):
            raise NormalsError(f"line {i}, point {int(bad[0])}: all triangles degenerate (coincident neighbours)")
        nn = acc / norm[:, None]
        out.append(nn)
        total += nn.sum(axis=0)
    if orient is not None:
        o = np.asarray(orient, dtype=np.float64)
        if o.shape != (3,) or not np.all(np.isfinite(o)):
            raise NormalsError(f"orient must be a finite (3,) vector, got {o!r}")
        if total @ o < 0:
            out = [-n for n in out]
    return tuple(out)


def _printed_sum(L: list[FloatArray], i: int, p: FloatArray, a: FloatArray, has_a: np.ndarray, near: dict,
                 fan: FloatArray) -> FloatArray:
    """The document's four triangles' cross products (each twice its area along its normal),
    each turned to the side of the ``fan``'s sum, added; the fan's sum where none exists
    (module docstring)."""
    n = len(p)
    vertex: dict[str, tuple[FloatArray, np.ndarray]] = {"a": (a, has_a)}
    for adj, tag in ((i - 1, "-"), (i + 1, "+")):
        if adj in near:
            m = near[adj]
            vertex[tag] = (L[adj][m] - p, np.ones(n, dtype=bool))
            after = np.minimum(m + 1, len(L[adj]) - 1)
            vertex[tag + "'"] = (L[adj][after] - p, m + 1 < len(L[adj]))
    acc = np.zeros((n, 3))
    for u, v in (("a", "-"), ("-", "-'"), ("-'", "+"), ("+", "+'")):
        if u not in vertex or v not in vertex:
            continue
        cross = np.cross(vertex[u][0], vertex[v][0])
        cross *= np.where(np.einsum("ij,ij->i", cross, fan) < 0.0, -1.0, 1.0)[:, None]
        acc += (vertex[u][1] & vertex[v][1])[:, None] * cross
    none = ~np.any(acc != 0.0, axis=1)
    acc[none] = fan[none]   # a corner where none of the listed triangles exists: the fan's
    return acc


def pca_normals(points: ArrayLike, k: int = 16, orient: ArrayLike | None = None) -> FloatArray:
    """k-nearest-neighbour PCA normals.

    Args:
        points: (N, 3) [m].
        k: neighbours, the point itself included (3 <= k <= N).
        orient: optional (3,) direction; each normal is flipped to face it (PCA has no sign).

    Returns:
        (N, 3) unit normals.
    """
    P = np.asarray(points, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or not np.all(np.isfinite(P)):
        raise NormalsError(f"points must be finite (N, 3), got shape {P.shape}")
    if not (isinstance(k, (int, np.integer)) and 3 <= k <= len(P)):
        raise NormalsError(f"k must be an integer in [3, {len(P)}], got {k!r}")
    tree = cKDTree(P)
    n = np.empty_like(P)
    step = max(1, 2_000_000 // int(k))  # bound the (chunk, k, 3) neighbourhood array
    for c0 in range(0, len(P), step):
        _, nb = tree.query(P[c0:c0 + step], k=int(k))
        Q = P[nb]
        Q = Q - Q.mean(axis=1, keepdims=True)
        _, V = np.linalg.eigh(np.einsum("nki,nkj->nij", Q, Q))
        n[c0:c0 + step] = V[:, :, 0]
    if orient is not None:
        o = np.asarray(orient, dtype=np.float64)
        n = np.where((n @ o)[:, None] < 0, -n, n)
    return n


def angle_deg(a: ArrayLike, b: ArrayLike, unsigned: bool = False) -> FloatArray:
    """(N,) angles [deg] between unit vectors; ``unsigned`` ignores the sign (PCA normals)."""
    c = np.einsum("ij,ij->i", np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))
    if unsigned:
        c = np.abs(c)
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def smooth_line_normals(lines: Sequence[ArrayLike], normals: Sequence[ArrayLike],
                        knot_spacing_m: float = 0.004) -> tuple[FloatArray, ...]:
    """Normals smoothed along each line by a cubic least-squares B-spline in arc length.

    Cross-line triangulation takes the *nearest* point of each adjacent line, which jumps
    from one sample to the next as the point moves along; the normals then step by a few
    hundredths of a degree from point to point. Harmless for a normal estimate, but a tool
    orientation built from them makes the wrist's acceleration noisy (the second difference
    of the orientation over 1 mm). The fit (one knot span per ``knot_spacing_m``, components
    fitted independently, then renormalised) removes that without bending the surface's own
    variation, which spans centimetres.

    Args:
        lines: L arrays (n_i, 3) [m], the points the normals belong to.
        normals: L arrays (n_i, 3) unit normals.
        knot_spacing_m: arc length per knot span [m].

    Returns:
        L arrays (n_i, 3) of unit normals.
    """
    from scipy.interpolate import make_lsq_spline

    if not (np.isfinite(knot_spacing_m) and knot_spacing_m > 0):
        raise NormalsError(f"knot_spacing_m must be > 0, got {knot_spacing_m!r}")
    out = []
    for i, (p, n) in enumerate(zip(lines, normals, strict=True)):
        p = np.asarray(p, dtype=np.float64)
        n = np.asarray(n, dtype=np.float64)
        if p.shape != n.shape:
            raise NormalsError(f"line {i}: points {p.shape} and normals {n.shape} differ in shape")
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
        spans = int(min(max(1, round(s[-1] / knot_spacing_m)), max(1, (len(p) - 4) // 2 + 1)))
        if len(p) < 4 or s[-1] <= 0:
            out.append(n.copy())
            continue
        u = s / s[-1]
        keep = np.concatenate([[True], np.diff(u) > 0])
        interior = np.quantile(u[keep], np.linspace(0.0, 1.0, spans + 1)[1:-1]) if spans > 1 else np.empty(0)
        t = np.concatenate([np.zeros(4), interior, np.ones(4)])
        m = make_lsq_spline(u[keep], n[keep], t, k=3)(u)
        out.append(m / np.linalg.norm(m, axis=1, keepdims=True))
    return tuple(out)

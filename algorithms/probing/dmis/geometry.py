"""Features from points and from other features, as a CMM's software computes them: least-squares
fits of points, planes, lines, circles, spheres and cylinders to measured surface points; the
minimum-zone (Chebyshev) flatness and roundness ISO 1101 defines; and the DMIS constructions
(best fit, intersection, projection, midpoint) of nominal and actual features alike.

Frame and units: metres, any one frame for all inputs; a fitted feature comes out as a
:class:`~algorithms.probing.dmis.model.Feature` with the nominal's label, kind and ``inner``, its
directions oriented as the nominal's.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.optimize import least_squares, linprog

from algorithms.arraytypes import FloatArray
from algorithms.errors import AlgorithmError
from algorithms.probing.dmis.model import Feature

#: The fewest points each fit takes.
MIN_POINTS = {"POINT": 1, "PLANE": 3, "LINE": 2, "CIRCLE": 3, "SPHERE": 4, "CYLNDR": 6, "CONE": 7}


def perpendicular(v: FloatArray) -> FloatArray:
    """A unit vector perpendicular to the unit vector ``v`` (the base axis least aligned with it, projected)."""
    e = np.eye(3)[int(np.argmin(np.abs(v)))]
    u = e - (e @ v) * v
    return u / np.linalg.norm(u)


def _oriented(d: FloatArray, like: FloatArray | None) -> FloatArray:
    return -d if like is not None and float(d @ like) < 0.0 else d


def plane_frame(normal: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Two unit vectors spanning the plane of ``normal``."""
    u = perpendicular(normal)
    return u, np.cross(normal, u)


def fit_plane(points: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The least-squares plane: its centroid and its unit normal (sign arbitrary)."""
    c = points.mean(axis=0)
    return c, np.linalg.svd(points - c)[2][-1]


def fit_line(points: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The least-squares 3D line: its centroid and its unit direction (sign arbitrary)."""
    c = points.mean(axis=0)
    return c, np.linalg.svd(points - c)[2][0]


def fit_circle_2d(uv: FloatArray) -> tuple[FloatArray, float]:
    """The geometric least-squares circle of 2D points: centre and radius (Kasa start, then
    Gauss-Newton on the radial residuals)."""
    A = np.column_stack([2 * uv, np.ones(len(uv))])
    b = (uv**2).sum(axis=1)
    (cx, cy, k), *_ = np.linalg.lstsq(A, b, rcond=None)
    r0 = float(np.sqrt(max(k + cx * cx + cy * cy, 0.0)))
    sol = least_squares(lambda p: np.linalg.norm(uv - p[:2], axis=1) - p[2], [cx, cy, r0], method="lm")
    return sol.x[:2], float(abs(sol.x[2]))


def fit_sphere(points: FloatArray) -> tuple[FloatArray, float]:
    """The geometric least-squares sphere: centre and radius."""
    A = np.column_stack([2 * points, np.ones(len(points))])
    b = (points**2).sum(axis=1)
    sol0, *_ = np.linalg.lstsq(A, b, rcond=None)
    r0 = float(np.sqrt(max(sol0[3] + sol0[:3] @ sol0[:3], 0.0)))
    sol = least_squares(lambda p: np.linalg.norm(points - p[:3], axis=1) - p[3], [*sol0[:3], r0], method="lm")
    return sol.x[:3], float(abs(sol.x[3]))


def fit_cylinder(points: FloatArray, axis_point: FloatArray, axis: FloatArray, radius: float
                 ) -> tuple[FloatArray, FloatArray, float]:
    """The geometric least-squares cylinder started from a nominal axis: a point on the axis
    (the foot of the points' centroid), the unit axis and the radius."""
    u, v = plane_frame(axis)

    def unpack(p):
        d = axis + p[2] * u + p[3] * v
        d = d / np.linalg.norm(d)
        return axis_point + p[0] * u + p[1] * v, d, p[4]

    def residuals(p):
        a, d, r = unpack(p)
        w = points - a
        return np.linalg.norm(w - np.outer(w @ d, d), axis=1) - r

    sol = least_squares(residuals, [0.0, 0.0, 0.0, 0.0, radius], method="lm")
    a, d, r = unpack(sol.x)
    foot = a + ((points.mean(axis=0) - a) @ d) * d
    return foot, d, float(abs(r))


def fit_cone(points: FloatArray, apex: FloatArray, axis: FloatArray, half_angle: float
             ) -> tuple[FloatArray, FloatArray, float]:
    """The geometric least-squares cone started from a nominal apex and axis: apex, unit axis
    (pointing from the apex into the cone) and half angle [rad]."""
    u, v = plane_frame(axis)

    def unpack(p):
        d = axis + p[3] * u + p[4] * v
        return apex + p[0] * u + p[1] * v + p[2] * axis, d / np.linalg.norm(d), p[5]

    def residuals(p):
        a, d, h = unpack(p)
        w = points - a
        along = w @ d
        radial = np.linalg.norm(w - np.outer(along, d), axis=1)
        return radial * np.cos(h) - along * np.sin(h)

    sol = least_squares(residuals, [0.0, 0.0, 0.0, 0.0, 0.0, half_angle], method="lm")
    a, d, h = unpack(sol.x)
    return a, d, float(abs(h))


def min_zone_flatness(points: FloatArray, normal: FloatArray) -> float:
    """The minimum-zone flatness [m]: the least distance between two parallel planes holding
    every point (a linear program on the plane's tilt about the least-squares normal; the small-
    angle form is exact to (tilt)^2, below 1e-9 of the value for any tilt a CMM part shows). If
    the solver fails, the range about the least-squares plane (never smaller) is returned."""
    c = points.mean(axis=0)
    u, v = plane_frame(normal)
    x, y, z = (points - c) @ u, (points - c) @ v, (points - c) @ normal
    # the solver's tolerances are absolute: scale heights and positions to order one
    hz = max(float(np.ptp(z)), 1e-15)
    hx = max(float(np.ptp(x)), float(np.ptp(y)), 1e-15)
    x, y, zs = x / hx, y / hx, z / hz
    n = len(points)
    # variables a, b, c, t: minimise t with |z - (a x + b y + c)| <= t / 2
    A = np.block([[-x[:, None], -y[:, None], -np.ones((n, 1)), -0.5 * np.ones((n, 1))],
                  [x[:, None], y[:, None], np.ones((n, 1)), -0.5 * np.ones((n, 1))]])
    b = np.concatenate([-zs, zs])
    res = linprog([0, 0, 0, 1], A_ub=A, b_ub=b, bounds=[(None, None)] * 3 + [(0, None)], method="highs")
    return float(min(res.x[3], 1.0) * hz) if res.success else float(np.ptp(z))


def min_zone_roundness(uv: FloatArray, centre: FloatArray) -> float:
    """The minimum-zone roundness [m] of 2D points: the least radial width of two concentric
    circles holding them (a linear program on the centre's shift from ``centre``, linear to first
    order in the shift). If the solver fails, the radial range about ``centre`` is returned."""
    w = uv - centre
    r = np.linalg.norm(w, axis=1)
    e = w / r[:, None]
    h = max(float(np.ptp(r)), 1e-15)
    rs = (r - r.mean()) / h  # the solver's tolerances are absolute: widths of order one
    n = len(uv)
    # r_i(s) = r_i - e_i . s; minimise t with rmin <= r_i(s) <= rmin + t: variables sx, sy, rmin, t
    A = np.block([[e, np.ones((n, 1)), np.zeros((n, 1))],
                  [-e, -np.ones((n, 1)), -np.ones((n, 1))]])
    b = np.concatenate([rs, -rs])
    res = linprog([0, 0, 0, 1], A_ub=A, b_ub=b, bounds=[(None, None)] * 3 + [(0, None)], method="highs")
    return float(min(res.x[3], 1.0) * h) if res.success else float(np.ptp(r))


def surface_normal(f: Feature, p: FloatArray) -> FloatArray:
    """The outward surface normal of nominal ``f`` at (or nearest) ``p``.

    Raises:
        AlgorithmError: a line without a surface normal, or ``p`` on the feature's axis or centre.
    """
    if f.kind in ("POINT", "PLANE"):
        return direction_of(f)
    if f.kind == "LINE":
        if f.normal is None:
            raise AlgorithmError(f"line F({f.label}) has no surface normal")
        return f.normal
    w = p - f.point_m
    if f.kind != "SPHERE":
        d = direction_of(f)
        w = w - (w @ d) * d
    norm = float(np.linalg.norm(w))
    if norm < 1e-9:
        raise AlgorithmError(f"the point lies on the axis of F({f.label}): its normal is not defined; give i,j,k")
    return -w / norm if f.inner else w / norm


def nominal_touches(f: Feature, n: int) -> list[tuple[FloatArray, FloatArray]]:
    """``n`` touches (surface point, outward normal) on nominal ``f`` where a program gives none:
    the point itself, or spread evenly round a circle from its first in-plane axis.

    Raises:
        AlgorithmError: a kind other than a point or a circle (its touches are not generated).
    """
    if f.kind == "POINT":
        return [(f.point_m, direction_of(f))] * n
    if f.kind == "CIRCLE" and f.size_m is not None:
        u, v = plane_frame(direction_of(f))
        out = []
        for k in range(n):
            e = np.cos(2 * np.pi * k / n) * u + np.sin(2 * np.pi * k / n) * v
            out.append((f.point_m + f.size_m / 2 * e, -e if f.inner else e))
        return out
    raise AlgorithmError(f"MEAS/{f.kind} of F({f.label}) without PTMEAS: the touches of a {f.kind} are not generated "
                         "(only points and circles are); give each touch as PTMEAS/CART,x,y,z,i,j,k")


def fitted(nominal: Feature, points: FloatArray) -> tuple[Feature, FloatArray]:
    """The actual feature of ``nominal``'s kind fitted to measured surface points, and each
    point's residual [m] (signed along the outward normal where the kind has one).

    Raises:
        AlgorithmError: too few points for the kind, or a kind this module does not fit.
    """
    kind = nominal.kind
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    need = MIN_POINTS.get(kind)
    if need is None:
        raise AlgorithmError(f"F({nominal.label}): a {kind} is not fitted (fitted kinds: {', '.join(MIN_POINTS)})")
    if len(points) < need:
        raise AlgorithmError(f"F({nominal.label}): a {kind} needs at least {need} measured points, got {len(points)}")
    d0 = nominal.direction
    if kind == "POINT":
        p = points.mean(axis=0)
        res = (points - nominal.point_m) @ d0 if d0 is not None else np.linalg.norm(points - p, axis=1)
        return replace(nominal, point_m=p), res
    if kind == "PLANE":
        c, n = fit_plane(points)
        n = _oriented(n, d0)
        return replace(nominal, point_m=c, direction=n), (points - c) @ n
    if kind == "LINE":
        c, d = fit_line(points)
        d = _oriented(d, d0)
        w = points - c
        res = np.linalg.norm(w - np.outer(w @ d, d), axis=1)
        m = nominal.normal - (nominal.normal @ d) * d if nominal.normal is not None else np.zeros(3)
        if np.linalg.norm(m) > 1e-9:  # a line on a surface: the residual along its surface normal
            res = w @ (m / np.linalg.norm(m))
        length = float(np.ptp(w @ d))
        return replace(nominal, point_m=c + (w @ d).min() * d, direction=d, size_m=length), res
    if kind == "SPHERE":
        c, r = fit_sphere(points)
        res = np.linalg.norm(points - c, axis=1) - r
        return replace(nominal, point_m=c, size_m=2 * r), -res if nominal.inner else res
    assert d0 is not None
    if kind == "CIRCLE":
        # the circle in the plane normal to its nominal axis, through the points' mean height
        u, v = plane_frame(d0)
        c0 = points.mean(axis=0)
        uv = np.column_stack([(points - c0) @ u, (points - c0) @ v])
        centre2, r = fit_circle_2d(uv)
        res = np.linalg.norm(uv - centre2, axis=1) - r
        c = c0 + centre2[0] * u + centre2[1] * v
        return replace(nominal, point_m=c, size_m=2 * r), -res if nominal.inner else res
    if kind == "CYLNDR":
        assert nominal.size_m is not None
        a, d, r = fit_cylinder(points, nominal.point_m, d0, nominal.size_m / 2)
        d = _oriented(d, d0)
        w = points - a
        res = np.linalg.norm(w - np.outer(w @ d, d), axis=1) - r
        return replace(nominal, point_m=a, direction=d, size_m=2 * r), -res if nominal.inner else res
    assert nominal.angle_rad is not None
    a, d, h = fit_cone(points, nominal.point_m, d0, nominal.angle_rad / 2)
    w = points - a
    along = w @ d
    res = np.linalg.norm(w - np.outer(along, d), axis=1) * np.cos(h) - along * np.sin(h)
    return replace(nominal, point_m=a, direction=d, angle_rad=2 * h), -res if nominal.inner else res


#: The constructions read, by (kind, method).
CONSTRUCTIONS = ("POINT BF", "LINE BF", "PLANE BF", "CIRCLE BF", "SPHERE BF", "POINT INTOF", "LINE INTOF",
                 "POINT PROJCT", "CIRCLE PROJCT", "LINE PROJCT", "POINT MIDPT")


def direction_of(f: Feature) -> FloatArray:
    """``f``'s direction; an AlgorithmError for a feature without one (a sphere)."""
    if f.direction is None:
        raise AlgorithmError(f"{f.label}, a {f.kind}, has no direction")
    return f.direction


def _need(label: str, kind: str, method: str, inputs: list[Feature], n: int,
          allowed: tuple[str, ...] | None = None) -> None:
    kinds = [f.kind for f in inputs]
    if len(inputs) < n or (allowed is not None and any(k not in allowed for k in kinds)):
        raise AlgorithmError(f"CONST/{kind},F({label}),{method} takes {n} or more features"
                             + (f" of kinds {', '.join(allowed)}" if allowed else "")
                             + f", got {', '.join(kinds) or 'none'}")


def _best_fit(label: str, kind: str, inputs: list[Feature], like: Feature | None, where) -> Feature:
    pts = np.vstack([f.point_m[None] for f in inputs]) if inputs else np.zeros((0, 3))
    _need(label, kind, "BF", inputs, MIN_POINTS[kind])
    nominal = like if like is not None else Feature(label, kind, None, pts.mean(axis=0), None, None, None, None, where)
    if kind == "CIRCLE" and nominal.direction is None:
        nominal = replace(nominal, direction=fit_plane(pts)[1])
    return fitted(replace(nominal, kind=kind, label=label, where=where), pts)[0]


def _intersection(label: str, kind: str, inputs: list[Feature], ref_dir: FloatArray | None) -> tuple:
    """(point, direction) of INTOF: two planes give a line; a line (or axis) and a plane, or two
    lines, a point (for two skew lines, the midpoint of their common perpendicular)."""
    _need(label, kind, "INTOF", inputs, 2)
    a, b = inputs[0], inputs[1]
    if kind == "LINE":
        _need(label, kind, "INTOF", inputs, 2, ("PLANE",))
        na, nb = direction_of(a), direction_of(b)
        d = np.cross(na, nb)
        if np.linalg.norm(d) < 1e-9:
            raise AlgorithmError(f"CONST/LINE,F({label}),INTOF: the planes are parallel")
        d = _oriented(d / np.linalg.norm(d), ref_dir)
        A = np.vstack([na, nb, d])
        return np.linalg.solve(A, np.array([na @ a.point_m, nb @ b.point_m, d @ a.point_m])), d
    planes = [f for f in (a, b) if f.kind == "PLANE"]
    others = [f for f in (a, b) if f.kind != "PLANE"]
    axial = ("LINE", "CYLNDR", "CONE", "CIRCLE")
    if len(planes) == 1 and others[0].direction is not None and others[0].kind in axial:
        pl, ln = planes[0], others[0]
        n, d = direction_of(pl), direction_of(ln)
        denom = float(d @ n)
        if abs(denom) < 1e-9:
            raise AlgorithmError(f"CONST/POINT,F({label}),INTOF: the line lies parallel to the plane")
        return ln.point_m + float((pl.point_m - ln.point_m) @ n) / denom * d, n
    if not planes and a.direction is not None and b.direction is not None:
        d1, d2, w = direction_of(a), direction_of(b), a.point_m - b.point_m
        B = float(d1 @ d2)
        den = 1.0 - B * B
        if den < 1e-12:
            raise AlgorithmError(f"CONST/POINT,F({label}),INTOF: the lines are parallel")
        s = (B * (d2 @ w) - (d1 @ w)) / den
        t = ((d2 @ w) - B * (d1 @ w)) / den
        return ((a.point_m + s * d1) + (b.point_m + t * d2)) / 2, None
    raise AlgorithmError(f"CONST/POINT,F({label}),INTOF takes a line (or an axis) and a plane, or two lines; "
                         f"got {', '.join(f.kind for f in inputs)}")


def construct(label: str, kind: str, method: str, inputs: list[Feature], like: Feature | None, where) -> Feature:
    """Feature ``label`` built by ``method`` from ``inputs`` (DMIS ``CONST/kind,F(label),method,...``).

    ``BF`` fits the kind to the inputs' points (their centres); ``INTOF`` intersects (a line and a
    plane, two lines: the midpoint of their common perpendicular, two planes: a line); ``PROJCT``
    projects the first input onto the plane given second (or onto the work plane z = 0 of the
    frame, when only one is given); ``MIDPT`` is the midpoint of two features' points.
    ``like``: a feature whose directions the result's are oriented as (the nominal, when building
    the actual), or None.

    Raises:
        AlgorithmError: a (kind, method) not in :data:`CONSTRUCTIONS`, or inputs of the wrong kinds.
    """
    if f"{kind} {method}" not in CONSTRUCTIONS:
        raise AlgorithmError(f"CONST/{kind},...,{method} is not a construction this reader builds: "
                             f"{', '.join(CONSTRUCTIONS)}")
    ref_dir = like.direction if like is not None else None

    def feature(point, direction=None, normal=None, size=None, inner=None) -> Feature:
        return Feature(label, kind, inner, np.asarray(point, dtype=np.float64), direction, normal, size, None, where)

    if method == "BF":
        return _best_fit(label, kind, inputs, like, where)
    if method == "MIDPT":
        _need(label, kind, method, inputs, 2)
        return feature((inputs[0].point_m + inputs[1].point_m) / 2)
    if method == "INTOF":
        return feature(*_intersection(label, kind, inputs, ref_dir))
    _need(label, kind, method, inputs, 1)  # PROJCT
    src = inputs[0]
    if len(inputs) > 1:
        if inputs[1].kind != "PLANE":
            raise AlgorithmError(f"CONST/{kind},F({label}),PROJCT projects onto a plane, got a {inputs[1].kind}")
        q, n = inputs[1].point_m, direction_of(inputs[1])
    else:
        q, n = np.zeros(3), np.array([0.0, 0.0, 1.0])
    p = src.point_m - ((src.point_m - q) @ n) * n
    if kind == "LINE":
        if src.direction is None:
            raise AlgorithmError(f"CONST/LINE,F({label}),PROJCT projects a line, got a {src.kind}")
        d = direction_of(src)
        d = d - (d @ n) * n
        return feature(p, direction=_oriented(d / np.linalg.norm(d), ref_dir), normal=src.normal)
    if kind == "CIRCLE":
        return feature(p, direction=n, size=src.size_m, inner=src.inner)
    return feature(p, direction=n)

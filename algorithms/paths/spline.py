"""Per-line cubic B-spline least-squares fits (document 004, eqs. 3-7) and resampling.

Document 004 fits each scan line with a NURBS curve of unit weights, which is a plain B-spline
``P(u) = sum_i B_i,3(u) D_i`` (eq. 5), the control points ``D_i`` minimising
``sum_j |P(u_j) - p_j|^2`` (eq. 7) with centripetal parameters ``u_j`` (Lee 1989:
``u_j - u_(j-1) ~ |p_j - p_(j-1)|^(1/2)``, normalised to [0, 1]). The fit removes the
measurement fluctuation (document 004, fig. 9); the curve is then resampled at the spacing
the process asks for.

Choices the document leaves open:

* Knots: clamped cubic, interior knots at quantiles of the data parameters, one knot span
  per ``knot_spacing_m`` of line (2 mm by default: a low-pass that keeps features of a few mm
  and averages about 40 samples of a 0.05 mm-spaced scan per span). Quantiles keep every
  span populated, so the Schoenberg-Whitney conditions hold and the system is well posed.
* The fit's stated error: the RMS and maximum over the data of the distance from each point
  to the curve (the foot found by Newton's method from ``u_j``; the residual at ``u_j``
  itself also measures the parameterisation's drift along the curve, not the fit); a point
  beyond an end of the curve is measured from the end's tangent line.
* Resampling: equal arc length along the fitted curve (arc length by dense evaluation), the
  spacing adjusted so that both line ends are kept: ``n = round(L / spacing)`` intervals.

scipy's ``make_lsq_spline`` solves eq. 7 (vector-valued y, one solve for x, y, z).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import BSpline, make_lsq_spline

from algorithms.arraytypes import ArrayLike, FloatArray
from algorithms.errors import AlgorithmError

KNOT_SPACING_M = 0.002
DEGREE = 3
# Evaluations per knot span (at least) used to measure arc length for resampling.
ARC_SAMPLES_PER_SPAN = 64


class SplineError(AlgorithmError):
    """Bad input to a line fit."""


def centripetal_parameters(points: ArrayLike) -> FloatArray:
    """(n,) centripetal parameters in [0, 1] of an ordered polyline (n, 3).

    Raises:
        SplineError: fewer than 2 points or all points coincide.
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or len(p) < 2:
        raise SplineError(f"points must be (n, d) with n >= 2, got shape {p.shape}")
    step = np.sqrt(np.linalg.norm(np.diff(p, axis=0), axis=1))
    u = np.concatenate([[0.0], np.cumsum(step)])
    if u[-1] <= 0:
        raise SplineError("all points of the line coincide")
    return u / u[-1]


@dataclass(frozen=True, eq=False)
class LineFit:
    """A cubic B-spline fit of one line.

    Attributes:
        spline: vector-valued ``scipy.interpolate.BSpline`` on [0, 1] -> (3,) [m].
        u: (n,) centripetal parameters of the data points.
        rms_error_m: RMS distance of the data points to the curve [m].
        max_error_m: largest distance of a data point to the curve [m].
        length_m: arc length of the fitted curve [m].
        n_points: data points fitted.
        n_spans: knot spans.
    """

    spline: BSpline = field(repr=False)
    u: FloatArray = field(repr=False)
    rms_error_m: float
    max_error_m: float
    length_m: float
    n_points: int
    n_spans: int
    _arc: tuple[FloatArray, ...] = field(repr=False, default=())  # (u, s): arc length s [m] at u

    def __call__(self, u: ArrayLike) -> FloatArray:
        """Curve points (..., 3) [m] at parameters ``u`` in [0, 1]."""
        return self.spline(u)

    def resample(self, spacing_m: float) -> tuple[FloatArray, FloatArray]:
        """Points every ``spacing_m`` of arc length (both ends kept) and unit tangents.

        Returns:
            (M, 3) points [m] and (M, 3) unit tangents (along increasing u).
        """
        if not (np.isfinite(spacing_m) and spacing_m > 0):
            raise SplineError(f"resampling spacing must be > 0 m, got {spacing_m}")
        uu, ss = self._arc
        n = max(1, int(round(self.length_m / spacing_m)))
        s = np.linspace(0.0, self.length_m, n + 1)
        u = np.interp(s, ss, uu)
        pts = self.spline(u)
        d = self.spline.derivative()(u)
        tan = d / np.linalg.norm(d, axis=1, keepdims=True)
        return pts, tan


def fit_line(points: ArrayLike, knot_spacing_m: float = KNOT_SPACING_M, degree: int = DEGREE) -> LineFit:
    """Least-squares B-spline fit of one ordered line with centripetal parameters.

    Args:
        points: (n, 3) [m] ordered along the line.
        knot_spacing_m: arc length per knot span [m].
        degree: spline degree (3: cubic, document 004).

    Raises:
        SplineError: too few points for one cubic span, bad spacing.
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise SplineError(f"points must be (n, 3), got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise SplineError("points contain NaN or infinite coordinates; drop invalid samples first")
    if len(p) < degree + 1:
        raise SplineError(f"a degree-{degree} fit needs at least {degree + 1} points, got {len(p)}")
    if not (np.isfinite(knot_spacing_m) and knot_spacing_m > 0):
        raise SplineError(f"knot_spacing_m must be > 0, got {knot_spacing_m}")
    u = centripetal_parameters(p)
    chord = float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1)))
    # Enough data per span: at least degree + 1 points per span on average.
    spans = int(max(1, min(round(chord / knot_spacing_m), (len(p) - degree - 1) // 2 + 1)))
    interior = np.quantile(u, np.linspace(0.0, 1.0, spans + 1)[1:-1]) if spans > 1 else np.empty(0)
    t = np.concatenate([np.zeros(degree + 1), interior, np.ones(degree + 1)])
    try:
        spl = make_lsq_spline(u, p, t, k=degree)
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise SplineError(f"B-spline least squares failed ({len(p)} points, {spans} spans): {exc}") from None
    r = _distance_to_curve(spl, u, p)
    uu = np.linspace(0.0, 1.0, spans * ARC_SAMPLES_PER_SPAN + 1)
    q = spl(uu)
    ss = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(q, axis=0), axis=1))])
    return LineFit(spl, u, float(np.sqrt(np.mean(r**2))), float(r.max()), float(ss[-1]), len(p),
                   spans, (uu, ss))


def _distance_to_curve(spl: BSpline, u0: FloatArray, p: FloatArray, iterations: int = 4) -> FloatArray:
    """Distance of each point to the curve, by Newton's method on the foot parameter from ``u0``."""
    d1, d2 = spl.derivative(1), spl.derivative(2)
    u = u0.copy()
    for _ in range(iterations):
        e = spl(u) - p
        t1, t2 = d1(u), d2(u)
        g = np.einsum("ij,ij->i", e, t1)
        h = np.einsum("ij,ij->i", t1, t1) + np.einsum("ij,ij->i", e, t2)
        step = np.where(h > 0, g / np.where(h > 0, h, 1.0), 0.0)
        u = np.clip(u - step, 0.0, 1.0)
    # Perpendicular part only: a point beyond an end of the curve (its foot clamped at u = 0
    # or 1) is measured from the tangent line there, not from the end point.
    e = spl(u) - p
    t = d1(u)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    e -= np.einsum("ij,ij->i", e, t)[:, None] * t
    return np.linalg.norm(e, axis=1)


@dataclass(frozen=True)
class FittedLines:
    """Fits of all lines of a cloud and their resampled points.

    Attributes:
        fits: one :class:`LineFit` per line.
        lines: resampled points per line, each (M_i, 3) [m].
        tangents: unit tangents per line, each (M_i, 3).
        spacing_m: the requested resampling spacing [m].
        rms_error_m: RMS fit error over all data points [m].
        max_error_m: largest fit error [m].
    """

    fits: tuple[LineFit, ...]
    lines: tuple[FloatArray, ...]
    tangents: tuple[FloatArray, ...]
    spacing_m: float
    rms_error_m: float
    max_error_m: float


def fit_lines(lines: Sequence[ArrayLike], spacing_m: float, knot_spacing_m: float = KNOT_SPACING_M) -> FittedLines:
    """Fit every line (see :func:`fit_line`) and resample each at ``spacing_m``."""
    fits, pts, tans = [], [], []
    sq, n = 0.0, 0
    for i, line in enumerate(lines):
        try:
            f = fit_line(line, knot_spacing_m)
        except SplineError as exc:
            raise SplineError(f"line {i}: {exc}") from None
        p, t = f.resample(spacing_m)
        fits.append(f)
        pts.append(p)
        tans.append(t)
        sq += f.rms_error_m**2 * f.n_points
        n += f.n_points
    if not fits:
        raise SplineError("no line to fit")
    return FittedLines(tuple(fits), tuple(pts), tuple(tans), float(spacing_m), float(np.sqrt(sq / n)),
                       float(max(f.max_error_m for f in fits)))

"""Probe qualification on a reference sphere, and probe radius compensation.

A touch probe reports the ball *centre* at the trigger, not the contact point. Qualification
probes the outside of a reference sphere of known radius ``R`` (a calibrated artefact) from
many directions: the triggered centres lie on a sphere of radius ``R + r_eff`` about the
sphere's centre, and the fitted radius gives the *effective* ball radius ``r_eff``. It is
the nominal ball radius less the mean pre-travel (the ball has moved past the contact when
it triggers), so compensating measured centres with ``r_eff`` removes the mean pre-travel
as well, as on a CMM. The direction-dependent rest of the pre-travel stays in the points.

Compensation moves each centre back along the part's outward normal at the contact by
``r_eff``; the normal is estimated from the CAD model at the current pose estimate, so an
error ``theta`` in it leaves the error ``r_eff (1 - cos theta)`` along the normal
(:func:`cosine_error_m`) and ``r_eff sin theta`` along the surface.

All coordinates in one frame (the machine's or the robot base's), metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from algorithms.arraytypes import ArrayLike, FloatArray
from algorithms.errors import AlgorithmError

__all__ = [
    "Qualification",
    "SphereFit",
    "compensate",
    "cosine_error_m",
    "fit_sphere",
    "qualification_directions",
    "qualify_ball",
]

#: Gauss-Newton stops when the step (centre and radius) is shorter than this [m].
STEP_TOL_M = 1e-15
MAX_ITERATIONS = 50
#: Points whose smallest spread (singular value of the centred points) is below this
#: fraction of the largest lie on a plane (or a line): no unique sphere passes through them.
COPLANAR_REL = 1e-9
#: A normal may differ from unit length by this much.
UNIT_TOL = 1e-6
#: Points per ring of the qualification pattern (as on a CMM: rings of about 8 points).
RING_POINTS = 8


@dataclass(frozen=True)
class SphereFit:
    """Least-squares sphere through points.

    Attributes:
        centre: (3,) [m] the sphere's centre, frame of the points.
        radius_m: its radius [m].
        rms_m: RMS of the residuals [m].
        residuals_m: (N,) [m] ``|p_i - centre| - radius_m``, positive outside.
        iterations: Gauss-Newton iterations run.
        converged: whether the last step was shorter than ``STEP_TOL_M``.
    """

    centre: FloatArray
    radius_m: float
    rms_m: float
    residuals_m: FloatArray
    iterations: int
    converged: bool


@dataclass(frozen=True)
class Qualification:
    """The effective ball radius from probing a reference sphere.

    Attributes:
        effective_radius_m: ``r_eff`` [m]: nominal ball radius less the mean pre-travel.
        sphere_centre: (3,) [m] the reference sphere's centre, frame of the centres.
        rms_m: RMS residual of the sphere fit [m] (pre-travel variation and repeatability).
        n_points: number of touches used.
    """

    effective_radius_m: float
    sphere_centre: FloatArray
    rms_m: float
    n_points: int


def fit_sphere(points: ArrayLike) -> SphereFit:
    """Least-squares sphere minimising the geometric distances ``|p_i - c| - radius``.

    Starts from the algebraic fit (linear in ``c`` and ``radius^2 - |c|^2``) and refines
    with Gauss-Newton on the geometric distance until the step is below ``STEP_TOL_M`` or
    after ``MAX_ITERATIONS``.

    Args:
        points: (N, 3) [m] points on (or near) a sphere, N >= 4, not coplanar.

    Raises:
        AlgorithmError: wrong shape, fewer than 4 points, non-finite or coplanar points.
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 4:
        raise AlgorithmError(f"points must be (N, 3) with N >= 4, got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise AlgorithmError("points must be finite")
    # centring keeps the algebraic system well conditioned far from the origin
    mean = p.mean(axis=0)
    q = p - mean
    s = np.linalg.svd(q, compute_uv=False)
    if s[-1] <= COPLANAR_REL * s[0]:
        raise AlgorithmError("points lie on one plane (or line): a sphere needs at least 4 points that are not "
                             "coplanar")
    A = np.hstack([2.0 * q, np.ones((len(q), 1))])
    sol = np.linalg.lstsq(A, np.einsum("ij,ij->i", q, q), rcond=None)[0]
    c = sol[:3]
    radius = float(np.sqrt(max(sol[3] + c @ c, 0.0)))
    converged = False
    iterations = 0
    while iterations < MAX_ITERATIONS and not converged:
        iterations += 1
        d = q - c
        dist = np.linalg.norm(d, axis=1)
        J = np.hstack([-d / dist[:, None], -np.ones((len(q), 1))])
        step = np.linalg.lstsq(J, -(dist - radius), rcond=None)[0]
        c = c + step[:3]
        radius += float(step[3])
        converged = bool(np.linalg.norm(step) < STEP_TOL_M)
    residuals = np.linalg.norm(q - c, axis=1) - radius
    return SphereFit(centre=c + mean, radius_m=radius, rms_m=float(np.sqrt(np.mean(residuals**2))),
                     residuals_m=residuals, iterations=iterations, converged=converged)


def qualify_ball(centres: ArrayLike, sphere_radius_m: float) -> Qualification:
    """Effective ball radius from ball centres triggered on the outside of a reference sphere.

    Args:
        centres: (N, 3) [m] ball-centre positions at the triggers, N >= 4, not coplanar.
        sphere_radius_m: calibrated radius of the reference sphere [m].

    Raises:
        AlgorithmError: bad centres (see fit_sphere), a radius that is not a positive finite
            length, or a fitted radius not larger than the sphere's (the centres cannot come
            from probing its outside with this radius).
    """
    if not (np.isfinite(sphere_radius_m) and sphere_radius_m > 0):
        raise AlgorithmError(f"sphere_radius_m must be a positive finite length [m], got {sphere_radius_m}")
    fit = fit_sphere(centres)
    r_eff = fit.radius_m - float(sphere_radius_m)
    if not r_eff > 0:
        raise AlgorithmError(f"the centres lie on a sphere of radius {fit.radius_m:.6g} m, not larger than the "
                             f"reference sphere's {sphere_radius_m:.6g} m: check the sphere radius")
    return Qualification(effective_radius_m=r_eff, sphere_centre=fit.centre, rms_m=fit.rms_m,
                         n_points=len(fit.residuals_m))


def qualification_directions(n_points: int = 25, min_elevation_deg: float = 0.0) -> FloatArray:
    """Outward sphere normals to probe a reference sphere at: a pole point plus rings.

    As in a CMM qualification pattern: one touch at the pole, the rest on rings of about
    ``RING_POINTS`` touches at elevations evenly spaced from ``min_elevation_deg`` (the
    lowest ring) toward the pole, each ring turned by half a step against the one below so
    the touches interleave. Deterministic.

    Args:
        n_points: number of directions, >= 4 (the pole and a ring of 3 fix a sphere).
        min_elevation_deg: elevation of the lowest ring above the equator [deg], in [0, 90)
            (the stem of the sphere blocks the lower hemisphere).

    Returns:
        (n_points, 3) unit vectors with ``z >= sin(min_elevation)``, the pole first.
    """
    if isinstance(n_points, bool) or not isinstance(n_points, int | np.integer) or n_points < 4:
        raise AlgorithmError(f"n_points must be an integer >= 4, got {n_points!r}")
    if not (np.isfinite(min_elevation_deg) and 0.0 <= min_elevation_deg < 90.0):
        raise AlgorithmError(f"min_elevation_deg must be in [0, 90), got {min_elevation_deg}")
    rest = int(n_points) - 1
    n_rings = max(1, round(rest / RING_POINTS))
    counts = np.full(n_rings, rest // n_rings)
    counts[: rest % n_rings] += 1  # the lower, longer rings take the extra points
    elevations = np.deg2rad(min_elevation_deg + (90.0 - min_elevation_deg) * np.arange(n_rings) / n_rings)
    out = [np.array([0.0, 0.0, 1.0])]
    for j, (count, elevation) in enumerate(zip(counts, elevations, strict=True)):
        azimuth = 2.0 * np.pi * (np.arange(count) + 0.5 * (j % 2)) / count
        out.extend(np.column_stack([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                                    np.full(count, np.sin(elevation))]))
    return np.array(out)


def compensate(centres: ArrayLike, normals: ArrayLike, effective_radius_m: float) -> FloatArray:
    """Surface points from triggered ball centres: ``centres - r_eff * normals``.

    Args:
        centres: (N, 3) [m] ball centres at the triggers.
        normals: (N, 3) outward unit normals of the part at the contacts (estimated from the
            CAD model at the current pose estimate), same frame.
        effective_radius_m: ``r_eff`` from :func:`qualify_ball` [m].

    Returns:
        (N, 3) [m] contact points, same frame.
    """
    c = np.asarray(centres, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    if c.ndim != 2 or c.shape[1] != 3 or n.shape != c.shape:
        raise AlgorithmError(f"centres and normals must both be (N, 3), got {c.shape} and {n.shape}")
    if not (np.all(np.isfinite(c)) and np.all(np.isfinite(n))):
        raise AlgorithmError("centres and normals must be finite")
    bad = np.abs(np.linalg.norm(n, axis=1) - 1.0) > UNIT_TOL
    if bad.any():
        raise AlgorithmError(f"normals must be unit vectors: {int(bad.sum())} of {len(n)} are not")
    if not (np.isfinite(effective_radius_m) and effective_radius_m > 0):
        raise AlgorithmError(f"effective_radius_m must be a positive finite length [m], got {effective_radius_m}")
    return c - float(effective_radius_m) * n


def cosine_error_m(effective_radius_m: float, normal_error_rad: ArrayLike) -> FloatArray | float:
    """Error along the normal [m] left by compensating along a normal off by ``theta``.

    ``r (1 - cos theta)``, evaluated as ``2 r sin^2(theta / 2)``, which keeps its precision
    for small angles where ``1 - cos`` cancels.

    Args:
        effective_radius_m: ``r`` [m], >= 0.
        normal_error_rad: angle(s) between the true and the used normal [rad], any shape.

    Returns:
        The errors [m], the shape of ``normal_error_rad`` (a float for a scalar).
    """
    if not (np.isfinite(effective_radius_m) and effective_radius_m >= 0):
        raise AlgorithmError(f"effective_radius_m must be a finite length >= 0 [m], got {effective_radius_m}")
    theta = np.asarray(normal_error_rad, dtype=np.float64)
    if not np.all(np.isfinite(theta)):
        raise AlgorithmError("normal_error_rad must be finite")
    out = 2.0 * float(effective_radius_m) * np.sin(0.5 * theta) ** 2
    return float(out) if out.ndim == 0 else out

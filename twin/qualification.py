"""Probe qualification on the cell's reference sphere, as a CMM qualifies a stylus: the
effective ball radius (which absorbs the mean sideways pre-travel) and the ball-centre offset
(which absorbs the axial excess and any error of the probe's mount), and the combined random
standard uncertainty of one compensated probe point. Robot base frame, SI units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from algorithms.geometry.se3 import inv_pose, transform_points
from algorithms.probing.qualification import qualify_ball
from twin.probing import ProbeHit, ProbeTarget
from twin.realize import Realized
from twin.sensors.touch_probe import probe_spec

# Equator points of the qualification pattern start at this azimuth (world), then evenly spaced.
QUALIFICATION_ELEVATION_DEG = 0.0


@dataclass(frozen=True)
class Qualification:
    """The probe's qualification on the reference sphere (robot base frame).

    Attributes:
        effective_radius_m: the ball radius the points are compensated with [m].
        offset_probe_m: (3,) correction added to every recorded ball centre, probe frame [m].
        sphere_centre: (3,) the fitted sphere centre (from the recorded centres) [m].
        rms_m: RMS residual of the sphere fit [m].
        radius_std_m, offset_std_m: standard uncertainties of the radius and each offset component [m].
        hits: the probing moves on the sphere.
    """

    effective_radius_m: float
    offset_probe_m: np.ndarray
    sphere_centre: np.ndarray
    rms_m: float
    radius_std_m: float
    offset_std_m: float
    hits: tuple




def qualification_targets(realized: Realized) -> list[ProbeTarget]:
    """The reference sphere's qualification pattern (base frame): ``qualification_points``
    on its equator, evenly spaced, and its pole. With two elevations only, the sphere fit's
    radius is that of the equator (sideways) touches, and the pole's axial excess goes to
    the centre (the ball-centre offset), so the effective radius is the nominal radius minus
    the mean sideways pre-travel."""
    p = probe_spec(realized.scenario)
    T_bw = inv_pose(realized.scenario.T_world_base)
    az = 2 * np.pi * np.arange(p.qualification_points) / p.qualification_points
    el = np.radians(QUALIFICATION_ELEVATION_DEG)
    n_world = np.vstack([np.column_stack([np.cos(az) * np.cos(el), np.sin(az) * np.cos(el),
                                          np.full(len(az), np.sin(el))]), [[0.0, 0.0, 1.0]]])
    pts_world = p.sphere_xyz_m + p.sphere_radius_m * n_world
    pts = transform_points(T_bw, pts_world)
    normals = n_world @ T_bw[:3, :3].T
    return [ProbeTarget(pts[i], normals[i], f"sphere {i + 1}") for i in range(len(pts))]


def qualify(hits: tuple[ProbeHit, ...], realized: Realized) -> Qualification:
    """The effective ball radius and ball-centre offset from the sphere's hits."""
    p = probe_spec(realized.scenario)
    centres = np.array([h.centre for h in hits])
    q = qualify_ball(centres, p.sphere_radius_m)
    known = transform_points(inv_pose(realized.scenario.T_world_base), p.sphere_xyz_m[None])[0]
    # The probe frame's orientation is the same (stylus down) for every hit up to its spin,
    # which leaves an offset along the stylus unchanged: take the mean rotation's frame.
    R = hits[-1].R_base_probe
    offset_probe = R.T @ (known - q.sphere_centre)
    n = len(centres)
    # Standard uncertainties of the 4-parameter fit (radius, centre) from its residual.
    u = centres - q.sphere_centre
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    A = np.column_stack([np.ones(n), u])
    sigma = max(q.rms_m * np.sqrt(n / max(n - 4, 1)), 1e-12)
    C = sigma**2 * np.linalg.inv(A.T @ A)
    return Qualification(q.effective_radius_m, offset_probe, q.sphere_centre, q.rms_m, float(np.sqrt(C[0, 0])),
                         float(np.sqrt(np.max(np.diag(C)[1:]))), hits)



def probe_sigma_m(realized: Realized) -> float:
    """Combined random standard uncertainty of one compensated probe point along its normal
    [m]: the unidirectional repeatability and the pre-travel variation left after
    qualification (Type B, uniform within the model's 3D pre-travel variation)."""
    p = probe_spec(realized.scenario)
    s = p.stylus_length_m / p.reference_stylus_m
    ptv_half = 0.5 * s * (max(p.axial_pretravel_m, p.lateral_pretravel_m + p.lobe_m)
                          - min(p.axial_pretravel_m, p.lateral_pretravel_m - p.lobe_m))
    return float(np.sqrt((p.repeatability_2sigma_m / 2) ** 2 + ptv_half**2 / 3))


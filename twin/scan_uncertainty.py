"""The covariance of a pose localized from a laser scan: the random part (repeatability and
quantisation) from the fit's Cramer-Rao covariance, and the sensor's linearity curve as a
systematic error common to every point of the scan (GUM: a Type B effect, not white noise).
"""

from __future__ import annotations

import numpy as np

from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import inv_pose, transform_points
from algorithms.registration.result import RegistrationResult
from algorithms.registration.uncertainty import systematic_covariance
from twin.scan import Scan
from twin.sensors.laser import sensor_sigma_m


def pose_covariance(scan: Scan, localization: RegistrationResult, index: MeshIndex) -> np.ndarray:
    """The estimate's covariance along its determined directions: the Cramer-Rao term of the
    random errors (repeatability and quantisation) plus the sensor's linearity curve as a
    systematic error: Legendre polynomials of degree 0-3 in the measured distance across the
    window, each coefficient with the standard deviation ``linearity_m`` (the curve is known
    only by its +/- band, and one smooth shape can carry the whole band: the IL-065's
    sin-shaped curve has degree-1 and degree-3 coefficients of 0.95 and 1.16 times the band);
    :func:`algorithms.registration.uncertainty.systematic_covariance`."""
    sc = scan.scenario
    D = np.asarray(localization.determined_directions, dtype=np.float64).reshape(-1, 6)
    C = np.asarray(localization.covariance, dtype=np.float64)
    if len(D) == 0:
        return C
    s, n = sc.sensor, sc.noise
    sigma_all = sensor_sigma_m(sc)
    lin = s.linearity_m if n.linearity else 0.0
    # the random part of sigma_all: without the linearity band's share (linearity / sqrt 3)
    C = C * max(sigma_all**2 - lin**2 / 3.0, 0.0) / sigma_all**2
    if lin == 0.0:
        return C
    mask = scan.valid & (scan.line >= 0)[:, None]
    d = scan.d[mask][localization.inliers]
    pts = scan.points_base[mask][localization.inliers]
    near, far = s.window_m
    u = np.clip(2.0 * (d - s.reference_m) / (far - near), -1.0, 1.0)
    basis = np.polynomial.legendre.legvander(u, 3)
    cp = index.query(transform_points(inv_pose(localization.T_world_workpiece), pts))
    normals = index.smooth_normals(cp.face, cp.foot)
    return C + systematic_covariance(cp.foot, normals, D, basis, np.full(4, lin))


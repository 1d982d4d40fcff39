"""The uncertainty of the points of a laser scan and of the pose localized from them.

The standard uncertainty of one point along its surface normal (what the fit check and the
Cramer-Rao covariance take as sigma) combines every source the scenario declares random per
reading:

    sigma_i^2 = u_sensor^2 + sigma_enc^2 sum_j (n_i . dp_i/dq_j)^2,
    sigma    = sqrt(mean_i sigma_i^2)

with ``u_sensor`` the sensor's combined standard uncertainty (repeatability, linearity band,
quantisation: :func:`twin.sensors.laser.sensor_sigma_m`), ``sigma_enc`` the encoders' noise per
joint, ``dp_i/dq_j`` how point i moves with joint j at its logged joints (the nominal
kinematics, central differences) and ``n_i`` the CAD normal at the point's foot at the nominal
pose. A time skew or a kinematic error is one fixed value for the whole scan (a systematic
effect), not in sigma.

The pose covariance: the random part (repeatability, quantisation, encoder noise) from the
fit's Cramer-Rao covariance, and the sensor's linearity curve as a systematic error common to
every point of the scan (GUM: a Type B effect, not white noise).
"""

from __future__ import annotations

import numpy as np

from algorithms.geometry.kinematics import dh_forward
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import inv_pose, transform_points
from algorithms.registration.result import RegistrationResult
from algorithms.registration.uncertainty import systematic_covariance
from twin.robot import UR5E_DH
from twin.scan import Scan
from twin.scenario import Scenario
from twin.sensors.laser import sensor_sigma_m

#: Joint step of the central differences [rad].
JOINT_STEP_RAD = 1e-6


def encoder_variance_m2(q: np.ndarray, points_base: np.ndarray, normals_base: np.ndarray,
                        encoder_sigma_rad: float) -> np.ndarray:
    """(M,) variance [m^2] along each point's normal from the joint encoders' noise
    (module docstring); ``q``: (M, 6) the joints logged with each point, base frame points and
    unit normals (M, 3)."""
    T = dh_forward(q, UR5E_DH)
    T_inv = np.linalg.inv(T)
    ph = np.concatenate([points_base, np.ones((len(points_base), 1))], axis=1)
    var = np.zeros(len(points_base))
    for j in range(6):
        dq = np.zeros(6)
        dq[j] = JOINT_STEP_RAD
        D = (dh_forward(q + dq, UR5E_DH) - dh_forward(q - dq, UR5E_DH)) @ T_inv / (2.0 * JOINT_STEP_RAD)
        dp = np.einsum("nij,nj->ni", D[:, :3, :], ph)
        var += np.einsum("ni,ni->n", dp, normals_base) ** 2
    return encoder_sigma_rad**2 * var


def reading_sigma_m(scenario: Scenario, q: np.ndarray, points_base: np.ndarray,
                    T_base_workpiece_nominal: np.ndarray, index: MeshIndex) -> float:
    """The standard uncertainty of one point along its normal [m] (module docstring): the
    sensor's combined uncertainty, and the encoders' noise propagated at each point's joints
    ``q`` (M, 6), normals from the CAD model at the nominal pose."""
    u_sensor = sensor_sigma_m(scenario)
    sigma_enc = scenario.noise.encoder_sigma_rad
    if sigma_enc == 0.0 or len(points_base) == 0:
        return u_sensor
    cp = index.query(transform_points(inv_pose(T_base_workpiece_nominal), points_base))
    normals = index.smooth_normals(cp.face, cp.foot) @ T_base_workpiece_nominal[:3, :3].T
    var = encoder_variance_m2(q, points_base, normals, sigma_enc)
    return float(np.sqrt(u_sensor**2 + np.mean(var)))


def scan_reading_sigma_m(scan: Scan, index: MeshIndex) -> float:
    """:func:`reading_sigma_m` of a scan's points on its lines (those the loop localizes)."""
    mask = scan.valid & (scan.line >= 0)[:, None]
    q = np.broadcast_to(scan.q[:, None, :], (*mask.shape, 6))[mask]
    return reading_sigma_m(scan.scenario, q, scan.points_base[mask], scan.T_base_workpiece_nominal, index)


def pose_covariance(scan: Scan, localization: RegistrationResult, index: MeshIndex,
                    sigma_m: float | None = None) -> np.ndarray:
    """The estimate's covariance along its determined directions: the Cramer-Rao term of the
    random errors (repeatability, quantisation and encoder noise, with ``sigma_m`` the sigma the
    fit used) plus the sensor's linearity curve as a
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
    # the sigma the fit used (default: the sensor's alone)
    sigma_all = sensor_sigma_m(sc) if sigma_m is None else sigma_m
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


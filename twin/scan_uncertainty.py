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
every point of the scan (GUM: a Type B effect, not white noise; :func:`linearity_covariance`).
``benchmarks/bench_coverage.py`` measures how often the true error lies inside the stated
95 % region (``benchmarks/results_coverage.md``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.special import chdtri

from algorithms.geometry.kinematics import dh_forward
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import inv_pose, transform_points
from algorithms.registration.result import RegistrationResult
from algorithms.registration.uncertainty import systematic_response
from twin.robot import UR5E_DH
from twin.scan import Scan
from twin.scenario import NoiseSpec, Scenario, SensorSpec
from twin.sensors.laser import LINEARITY_VARIANCE_FACTOR, reading_uncertainty_m, sensor_sigma_m, window_coordinate


@dataclass(frozen=True)
class ScanReadings:
    """The points on a scan folder's lines, with what their uncertainty needs
    (:func:`twin.io.scan_files.read_scan_readings`).

    Attributes:
        points_base: (M, 3) points rebuilt with the believed kinematics and hand-eye, robot
            base frame [m] (the points ``points.ply`` holds, on the scan lines only).
        d: (M,) their measured distances [m]; beams_base: (M, 3) unit beam directions.
        q: (M, 6) the joints logged with each point [rad].
        sensor, noise: the scan's sensor settings and error switches (its scenario's).
        T_base_workpiece_nominal: (4, 4) the pose the scan was planned on.
    """

    points_base: np.ndarray
    d: np.ndarray
    beams_base: np.ndarray
    q: np.ndarray
    sensor: SensorSpec
    noise: NoiseSpec
    T_base_workpiece_nominal: np.ndarray


#: Draws and seed of the Monte Carlo coverage region (:func:`coverage_region_m2`).
REGION_DRAWS = 20000
REGION_SEED = 101

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
    return point_sigma_m(scenario.sensor, scenario.noise, q, points_base, T_base_workpiece_nominal, index)


def white_reading_sigma_m(scenario: Scenario, q: np.ndarray, points_base: np.ndarray,
                          T_base_workpiece_nominal: np.ndarray, index: MeshIndex) -> float:
    """The part of :func:`reading_sigma_m` that is independent from reading to reading [m]: the
    repeatability, the quantisation and the encoders' noise, without the linearity curve (a
    systematic error shared by neighbouring readings). The Cramer-Rao bound is taken with it."""
    return point_sigma_m(scenario.sensor, scenario.noise, q, points_base, T_base_workpiece_nominal, index,
                         white_only=True)


def point_sigma_m(sensor: SensorSpec, noise: NoiseSpec, q: np.ndarray, points_base: np.ndarray,
                  T_base_workpiece_nominal: np.ndarray, index: MeshIndex, white_only: bool = False) -> float:
    """:func:`reading_sigma_m` from the sensor's and the noise's settings (``white_only``: without
    the linearity curve, :func:`white_reading_sigma_m`)."""
    u_sensor = reading_uncertainty_m(sensor, replace(noise, linearity=False) if white_only else noise)
    sigma_enc = noise.encoder_sigma_rad
    if sigma_enc == 0.0 or len(points_base) == 0:
        return u_sensor
    cp = index.query(transform_points(inv_pose(T_base_workpiece_nominal), points_base))
    normals = index.smooth_normals(cp.face, cp.foot) @ T_base_workpiece_nominal[:3, :3].T
    var = encoder_variance_m2(q, points_base, normals, sigma_enc)
    return float(np.sqrt(u_sensor**2 + np.mean(var)))


def scan_reading_sigma_m(scan: Scan, index: MeshIndex, white_only: bool = False) -> float:
    """:func:`reading_sigma_m` of a scan's points on its lines (those the loop localizes);
    ``white_only``: :func:`white_reading_sigma_m`."""
    mask = scan.valid & (scan.line >= 0)[:, None]
    q = np.broadcast_to(scan.q[:, None, :], (*mask.shape, 6))[mask]
    return point_sigma_m(scan.scenario.sensor, scan.scenario.noise, q, scan.points_base[mask],
                         scan.T_base_workpiece_nominal, index, white_only)


def beam_directions_base(q: np.ndarray, beam_dirs_sensor: np.ndarray, T_flange_sensor: np.ndarray) -> np.ndarray:
    """(N, B, 3) unit beam directions in the robot base frame at the joints ``q`` (N, 6), with
    the believed kinematics and hand-eye (as the points are rebuilt)."""
    R = (dh_forward(q, UR5E_DH) @ T_flange_sensor)[:, :3, :3]
    return np.einsum("nij,bj->nbi", R, np.asarray(beam_dirs_sensor, dtype=np.float64))


def linearity_response(sensor: SensorSpec, d: np.ndarray, beams_world: np.ndarray, points_world: np.ndarray,
                       T_world_workpiece: np.ndarray, directions: np.ndarray, index: MeshIndex) -> np.ndarray:
    """(q, 2) how the pose moves along ``directions`` per metre of the linearity curve's
    ``sin(pi u)`` and ``cos(pi u)`` coefficients (:func:`linearity_covariance`)."""
    u = window_coordinate(d, sensor)
    cp = index.query(transform_points(inv_pose(T_world_workpiece), points_world))
    normals = index.smooth_normals(cp.face, cp.foot)
    cos_incidence = np.abs(np.einsum("ni,ni->n", beams_world @ T_world_workpiece[:3, :3], normals))
    basis = np.column_stack([np.sin(np.pi * u), np.cos(np.pi * u)]) * cos_incidence[:, None]
    return systematic_response(cp.foot, normals, directions, basis)


def linearity_covariance(sensor: SensorSpec, d: np.ndarray, beams_world: np.ndarray, points_world: np.ndarray,
                         T_world_workpiece: np.ndarray, directions: np.ndarray, index: MeshIndex) -> np.ndarray:
    """The pose covariance along ``directions`` (q, 6) that the sensor's linearity curve causes,
    a systematic error common to every point of the scan (GUM: a Type B evaluation).

    The curve is ``e(u) = L sin(pi u + phase)`` (:mod:`twin.sensors.laser`) with the phase of
    this sensor unit unknown, uniform: ``e = a sin(pi u) + b cos(pi u)`` with ``a, b``
    uncorrelated, each of variance ``L^2 / 2``. The error moves a point along its beam, so
    along the surface normal by ``e |b . n|``: the two basis functions are taken at each
    point's measured distance ``d`` and incidence (:func:`algorithms.registration.uncertainty.systematic_response`).

    Args:
        d: (M,) measured distances [m]; beams_world: (M, 3) unit beam directions; points_world:
            (M, 3) the points, all in the frame of ``T_world_workpiece`` (the fit's pose).
    """
    return linearity_share(linearity_response(sensor, d, beams_world, points_world, T_world_workpiece, directions,
                                              index), sensor)


def linearity_share(G_linearity: np.ndarray, sensor: SensorSpec) -> np.ndarray:
    """The covariance ``G var G^T`` of the response ``G_linearity`` (q, 2) (:func:`linearity_response`):
    each coefficient of the curve of variance ``LINEARITY_VARIANCE_FACTOR linearity_m^2``."""
    return (G_linearity * LINEARITY_VARIANCE_FACTOR * sensor.linearity_m**2) @ G_linearity.T


def coverage_region_m2(C_random: np.ndarray, G_linearity: np.ndarray, linearity_m: float, C_total: np.ndarray,
                       p: float = 0.95, draws: int = REGION_DRAWS) -> float:
    """The squared radius ``r2`` of the region ``m^T C_total^-1 m <= r2`` that holds the pose
    error with probability ``p`` under the propagated distribution (JCGM 101, Monte Carlo):
    the random part Gaussian with ``C_random``, the linearity curve
    ``linearity_m sin(pi u + phase)`` with the phase uniform (``G_linearity`` (q, 2) its response,
    :func:`linearity_response`). ``draws`` draws from a fixed seed (the same region every time).
    Where the bounded systematic part dominates, the radius is below the chi-square quantile."""
    rng = np.random.default_rng(REGION_SEED)
    phase = rng.uniform(0.0, 2.0 * np.pi, draws)
    w, V = np.linalg.eigh(0.5 * (C_random + C_random.T))
    root = V * np.sqrt(np.clip(w, 0.0, None))
    e = (G_linearity @ (linearity_m * np.vstack([np.sin(phase), np.cos(phase)]))).T \
        + rng.standard_normal((draws, len(C_total))) @ root.T
    m2 = np.einsum("ij,ij->i", e, np.linalg.solve(C_total, e.T).T)
    return float(np.quantile(m2, p))


def random_share(covariance: np.ndarray, sensor: SensorSpec, noise: NoiseSpec, sigma_m: float) -> np.ndarray:
    """The fit's covariance (made with ``sigma_m``, every source the reading's sigma holds)
    scaled to its random sources alone: without the linearity curve's share of the variance."""
    lin2 = LINEARITY_VARIANCE_FACTOR * sensor.linearity_m**2 if noise.linearity else 0.0
    return covariance * max(sigma_m**2 - lin2, 0.0) / sigma_m**2


def pose_covariance(scan: Scan, localization: RegistrationResult, index: MeshIndex,
                    sigma_m: float | None = None) -> np.ndarray:
    """The estimate's covariance along its determined directions: the Cramer-Rao term of the
    random errors (repeatability, quantisation and encoder noise, with ``sigma_m`` the sigma the
    fit used; default the sensor's alone) plus the sensor's linearity curve as a systematic
    error (:func:`linearity_covariance`)."""
    sc = scan.scenario
    D = np.asarray(localization.determined_directions, dtype=np.float64).reshape(-1, 6)
    C = np.asarray(localization.covariance, dtype=np.float64)
    if len(D) == 0:
        return C
    sigma = sensor_sigma_m(sc) if sigma_m is None else sigma_m
    C = random_share(C, sc.sensor, sc.noise, sigma)
    if not sc.noise.linearity or sc.sensor.linearity_m == 0.0:
        return C
    mask = scan.valid & (scan.line >= 0)[:, None]
    beams = beam_directions_base(scan.q, scan.beam_dirs_sensor, scan.T_flange_sensor_nominal)
    keep = localization.inliers
    return C + linearity_covariance(sc.sensor, scan.d[mask][keep], beams[mask][keep],
                                    scan.points_base[mask][keep], localization.T_world_workpiece, D, index)


@dataclass(frozen=True)
class ScanCovariance:
    """The covariance of a pose localized from a scan's readings (:func:`scan_covariance`).

    Attributes:
        total: (q, q) random and systematic, along the result's determined directions.
        random: (q, q) the random sources alone.
        kind: "random and systematic" or "random only"; sources: the sources it holds.
        region_m2: the 95 % coverage region ``m^T total^-1 m <= region_m2`` of the propagated
            distribution (:func:`coverage_region_m2`; the chi-square quantile where all is Gaussian).
    """

    total: np.ndarray
    random: np.ndarray
    kind: str
    sources: tuple[str, ...]
    region_m2: float


def scan_covariance(localization: RegistrationResult, readings: ScanReadings, index: MeshIndex, sigma_m: float,
                    sigma_given: bool = False) -> ScanCovariance | None:
    """The covariance of a pose fitted (with sigma ``sigma_m``) to every point of ``readings``:
    its random sources (repeatability, quantisation, encoder noise: the fit's Cramer-Rao
    covariance, without the linearity curve's share of ``sigma_m`` unless the sigma was given
    by the user, ``sigma_given``) and the linearity curve as a systematic effect
    (:func:`linearity_covariance`). None where the fit has no covariance or was not made on
    these points."""
    if localization.covariance is None or not sigma_m or len(np.asarray(localization.inliers)) != len(readings.d):
        return None
    s, n = readings.sensor, readings.noise
    C_random = np.asarray(localization.covariance, dtype=np.float64)
    if not sigma_given:
        C_random = random_share(C_random, s, n, sigma_m)
    sources = [name for name, on in (("repeatability", n.gaussian), ("quantisation", n.quantization),
                                     ("encoder noise", n.encoder_sigma_rad > 0)) if on]
    q = len(C_random)
    if not (n.linearity and s.linearity_m > 0):
        return ScanCovariance(C_random, C_random, "random only", tuple(sources), float(chdtri(q, 0.05)))
    D = np.asarray(localization.determined_directions, dtype=np.float64).reshape(-1, 6)
    keep = np.asarray(localization.inliers)
    G = linearity_response(s, readings.d[keep], readings.beams_base[keep], readings.points_base[keep],
                           localization.T_world_workpiece, D, index)
    C = C_random + linearity_share(G, s)
    sources.append("linearity curve (systematic, Type B: a sine of unknown phase within its band)")
    return ScanCovariance(C, C_random, "random and systematic", tuple(sources),
                          coverage_region_m2(C_random, G, s.linearity_m, C))

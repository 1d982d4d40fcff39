"""Laser triangulation displacement sensor model (defaults: Keyence IL-065).

The geometry comes from exact rays against the mesh triangles (MuJoCo's rangefinder for the
point sensor, :mod:`twin.sensors.raycast` for the line profiler's beams and every receiver
ray); this module turns the ideal hit into what the sensor reports. Every effect is switchable in the
scenario's ``[noise]`` table:

* no hit, or a measured distance outside ``window_m``: invalid (``d`` = NaN, never 0 or clamped);
* ``incidence``: noise sigma grows as ``sigma / cos(theta)`` with the angle theta between the
  beam and the surface normal, and no return beyond ``max_incidence_deg``;
* ``occlusion``: the spot must be visible from the receiver, offset from the emitter by the
  triangulation baseline (sensor +x for the point sensor, +y for the line profiler, whose fan
  lies in the x-z plane), and must face it;
* ``gaussian``: repeatability noise N(0, sigma^2) along the beam;
* ``linearity``: a systematic curve ``e(d) = linearity_m * sin(pi * u + phase)``,
  ``u = 2 (d - reference) / (far - near)``: one period over the window, within the
  +/- ``linearity_m`` band (the +/-10 um band of the IL-065); with the default phase 0 it is
  zero at the reference and at the window ends. A sensor unit's phase is unknown to its user
  (``linearity_phase_deg = "random"`` draws it per realization); the uncertainty the twin
  states takes it as uniform (:data:`LINEARITY_VARIANCE_FACTOR`,
  :func:`twin.scan_uncertainty.linearity_covariance`);
* ``quantization``: the output rounded to ``resolution_m``.

Status codes per sample (``status`` column): 0 valid, 1 no hit, 2 outside the window,
3 incidence angle past the maximum, 4 receiver occluded.
"""

from __future__ import annotations

import mujoco
import numpy as np

from twin.robot import GROUP_ARM, JOINT_NAMES, STATIC_GROUPS
from twin.scenario import NoiseSpec, Scenario, SensorSpec
from twin.sensors.base import INCIDENCE, NO_HIT, OCCLUDED, OUT_OF_WINDOW, VALID, Measurement, RawRays, RaySensor
from twin.sensors.raycast import BLOCK_RAYS, CellRays

# Start the receiver ray this far off the surface so it does not hit its own start point.
OCCLUSION_RAY_OFFSET_M = 1e-7


#: The variance of the linearity error at one distance, in units of ``linearity_m^2``: the mean
#: of ``sin^2`` over a phase uniform in [0, 2 pi) (the arcsine distribution on the band).
LINEARITY_VARIANCE_FACTOR = 0.5


def window_coordinate(d: np.ndarray, sensor: SensorSpec) -> np.ndarray:
    """``u = 2 (d - reference) / (far - near)``: the distance's place in the window."""
    near, far = sensor.window_m
    return 2.0 * (np.asarray(d, dtype=np.float64) - sensor.reference_m) / (far - near)


def linearity_error_m(d: np.ndarray, sensor: SensorSpec) -> np.ndarray:
    """The systematic linearity error curve at distance ``d`` [m] (module docstring)."""
    if sensor.linearity_phase_deg is None:
        raise ValueError("the sensor's linearity phase is drawn per realization: use the realized sensor")
    return sensor.linearity_m * np.sin(np.pi * window_coordinate(d, sensor) + np.radians(sensor.linearity_phase_deg))


def sensor_sigma_m(scenario: Scenario) -> float:
    """Combined standard uncertainty of one distance (GUM) [m] of the scenario's sensor
    (:func:`reading_uncertainty_m`)."""
    return reading_uncertainty_m(scenario.sensor, scenario.noise)


def reading_uncertainty_m(s: SensorSpec, n: NoiseSpec) -> float:
    """Combined standard uncertainty of one distance (GUM) [m]: repeatability, linearity band
    (a sine of unknown phase: amplitude * sqrt(LINEARITY_VARIANCE_FACTOR)) and quantisation
    (step / sqrt 12), for the switched-on sources."""
    var = (s.sigma_m**2 if n.gaussian else 0.0) \
        + (LINEARITY_VARIANCE_FACTOR * s.linearity_m**2 if n.linearity else 0.0) \
        + ((s.resolution_m / np.sqrt(12)) ** 2 if n.quantization else 0.0)
    return float(np.sqrt(var))


def occluded(rays: RawRays, check: np.ndarray, static_groups: np.ndarray, cast: CellRays) -> np.ndarray:
    """True where the receiver cannot see the laser spot (the surface faces away, or a static
    geom is in the way), for the rays ``check`` selects; False elsewhere. Only the spots that
    face the receiver cost a ray. Samples are taken in blocks (see ``raycast.BLOCK_RAYS``)."""
    out = np.zeros(check.shape, dtype=bool)

    def block(rows: slice) -> None:
        part = RawRays(rays.dist[rows], rays.origin[rows], rays.direction[rows], rays.normal[rows],
                       rays.receiver[rows])
        out[rows] = _occluded_block(part, check[rows], static_groups, cast)

    per_row = check.shape[1] if check.ndim > 1 else 1
    cast.map_blocks(block, len(check), max(1, BLOCK_RAYS // per_row), check.size)
    return out


def _occluded_block(rays: RawRays, check: np.ndarray, static_groups: np.ndarray, cast: CellRays) -> np.ndarray:
    # whole-array arithmetic, then one gather: origin and receiver may be broadcast views,
    # which a boolean index gathers slowly
    spot = rays.origin + rays.direction * rays.dist[..., None]
    to_rx = rays.receiver - spot
    with np.errstate(invalid="ignore"):   # misses carry dist -1 and a zero normal: not checked
        facing = np.einsum("...i,...i->...", to_rx, rays.normal) > 0.0
    out = check & ~facing
    cast_rays = check & facing
    if not np.any(cast_rays):
        return out
    to_rx = to_rx[cast_rays]
    length = np.sqrt(np.einsum("ij,ij->i", to_rx, to_rx))
    n = rays.normal[cast_rays]
    start = spot[cast_rays] + OCCLUSION_RAY_OFFSET_M * n
    out[cast_rays] = cast.blocked(start, to_rx / length[:, None], length, static_groups)
    return out


def measure(rays: RawRays, sensor: SensorSpec, noise: NoiseSpec, rng: np.random.Generator,
            cast: CellRays, static_groups: np.ndarray = STATIC_GROUPS) -> Measurement:
    """Apply the sensor model to ideal rays (vectorised over all samples and beams)."""
    dist = np.asarray(rays.dist, dtype=np.float64)
    hit = dist >= 0.0
    status = np.where(hit, VALID, NO_HIT).astype(np.uint8)
    cos_inc = np.clip(-np.einsum("...i,...i->...", rays.direction, rays.normal), -1.0, 1.0)
    incidence = np.where(hit, np.arccos(np.abs(cos_inc)), np.nan)

    if noise.incidence:
        too_steep = hit & (incidence > np.radians(sensor.max_incidence_deg))
        status[too_steep] = INCIDENCE
    if noise.occlusion:
        status[occluded(rays, status == VALID, static_groups, cast)] = OCCLUDED

    d = np.where(hit, dist, np.nan)
    # Draw noise for every sample so the stream does not depend on which samples are valid.
    z = rng.standard_normal(dist.shape)
    if noise.gaussian:
        sigma = sensor.sigma_m / np.maximum(np.cos(incidence), 1e-3) if noise.incidence \
            else np.full(dist.shape, sensor.sigma_m)
        d = d + sigma * z
    if noise.linearity:
        d = d + linearity_error_m(d, sensor)
    if noise.quantization and sensor.resolution_m > 0:
        d = np.round(d / sensor.resolution_m) * sensor.resolution_m
    near, far = sensor.window_m
    outside = (status == VALID) & ~((d >= near) & (d <= far))
    status[outside] = OUT_OF_WINDOW
    valid = status == VALID
    d = np.where(valid, d, np.nan)
    return Measurement(d, valid, status, incidence, np.where(hit, dist, -1.0))


class LaserSensor(RaySensor):
    """A laser triangulation sensor on the flange (the IL-065 model above); point or line."""

    _rays: CellRays | None = None
    _rays_of: mujoco.MjModel | None = None

    def cell_rays(self, model: mujoco.MjModel) -> CellRays:
        """The bulk ray caster of the cell compiled as ``model`` (built on first use and kept:
        a scan asks for it once per chunk of steps)."""
        if self._rays is None or self._rays_of is not model:
            qpos_adr = np.array([model.joint(name).qposadr[0] for name in JOINT_NAMES])
            self._rays, self._rays_of = CellRays(model, qpos_adr), model
        return self._rays

    def __getstate__(self) -> dict:
        # The caster holds Embree scenes and MuJoCo data: rebuilt where the sensor is unpickled.
        return {k: v for k, v in self.__dict__.items() if k not in ("_rays", "_rays_of")}

    def measure(self, rays: RawRays, rng: np.random.Generator, model: mujoco.MjModel) -> Measurement:
        return measure(rays, self.spec, self.noise, rng, self.cell_rays(model), STATIC_GROUPS)

    def _attach_body(self, spec: mujoco.MjSpec, body: mujoco.MjsBody) -> None:
        """Housing, emitter site ``laser`` (the sensor frame), ``receiver`` site, and the frame-axis
        sensors that carry the receiver's direction."""
        body.add_geom(name="laser_housing", type=mujoco.mjtGeom.mjGEOM_BOX,
                      size=[0.015, 0.010, 0.025], pos=[self.spec.baseline_m / 2, 0, -0.026],
                      rgba=[0.15, 0.3, 0.8, 1], group=GROUP_ARM, contype=1, conaffinity=0)
        body.add_site(name="laser", pos=[0, 0, 0], size=[0.002, 0, 0], rgba=[1, 0, 0, 1])
        body.add_site(name="receiver", pos=[self.spec.baseline_m, 0, 0], size=[0.002, 0, 0])

    @staticmethod
    def _add_axis_sensors(spec: mujoco.MjSpec) -> None:
        for axis, kind in (("x", mujoco.mjtSensor.mjSENS_FRAMEXAXIS), ("y", mujoco.mjtSensor.mjSENS_FRAMEYAXIS)):
            spec.add_sensor(name=f"laser_{axis}axis", type=kind, objtype=mujoco.mjtObj.mjOBJ_SITE, objname="laser")

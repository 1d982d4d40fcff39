"""Laser triangulation displacement sensor model (defaults: Keyence IL-065).

The geometry comes from MuJoCo's rangefinder (exact ray against the mesh triangles); this
module turns the ideal hit into what the sensor reports. Every effect is switchable in the
scenario's ``[noise]`` table:

* no hit, or a measured distance outside ``window_m``: invalid (``d`` = NaN, never 0 or clamped);
* ``incidence``: noise sigma grows as ``sigma / cos(theta)`` with the angle theta between the
  beam and the surface normal, and no return beyond ``max_incidence_deg``;
* ``occlusion``: the spot must be visible from the receiver, offset from the emitter by the
  triangulation baseline (sensor +x for the point sensor, +y for the line profiler, whose fan
  lies in the x-z plane), and must face it;
* ``gaussian``: repeatability noise N(0, sigma^2) along the beam;
* ``linearity``: a systematic curve ``e(d) = linearity_m * sin(pi * u)``,
  ``u = 2 (d - reference) / (far - near)``: zero at the reference and at the window ends,
  +/- ``linearity_m`` in between (the +/-10 um band of the IL-065);
* ``quantization``: the output rounded to ``resolution_m``.

Status codes per sample (``status`` column): 0 valid, 1 no hit, 2 outside the window,
3 incidence angle past the maximum, 4 receiver occluded.
"""

from __future__ import annotations

import mujoco
import mujoco.batch
import numpy as np

from twin.robot import GROUP_ARM, STATIC_GROUPS
from twin.scenario import NoiseSpec, SensorSpec
from twin.sensors.base import INCIDENCE, NO_HIT, OCCLUDED, OUT_OF_WINDOW, VALID, Measurement, RawRays, RaySensor

# Start the receiver ray this far off the surface so it does not hit its own start point.
OCCLUSION_RAY_OFFSET_M = 1e-7
# The receiver rays of a long scan are cast on this many threads.
RAY_THREADS = 2


def linearity_error_m(d: np.ndarray, sensor: SensorSpec) -> np.ndarray:
    """The systematic linearity error curve at distance ``d`` [m]."""
    near, far = sensor.window_m
    u = 2.0 * (d - sensor.reference_m) / (far - near)
    return sensor.linearity_m * np.sin(np.pi * u)


def cast_static_rays(batch, start: np.ndarray, unit: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """Distances of many rays against static geoms, split over the batch's simulations (threads).

    The geoms hit are static, so every simulation of the batch sees the same scene whatever
    its joint state; -1 where a ray hits nothing.
    """
    nsim = batch.nsim if hasattr(batch, "nsim") else 1
    n = len(start)
    per = -(-n // nsim)
    pad = per * nsim - n
    if pad:
        start = np.vstack([start, np.repeat(start[-1:], pad, axis=0)])
        unit = np.vstack([unit, np.repeat(unit[-1:], pad, axis=0)])
    dist, _ = batch.ray(start.reshape(nsim, per, 3), unit.reshape(nsim, per, 3),
                        geomgroup=groups, flg_static=True)
    return dist.reshape(-1)[:n]


def occluded(model: mujoco.MjModel, rays: RawRays, hit: np.ndarray, static_groups: np.ndarray,
             batch: mujoco.batch.Batch | None = None) -> np.ndarray:
    """True where the receiver cannot see the laser spot (blocked, or the surface faces away)."""
    out = np.zeros(hit.shape, dtype=bool)
    if not np.any(hit):
        return out
    spot = rays.origin[hit] + rays.direction[hit] * rays.dist[hit, None]
    n = rays.normal[hit]
    to_rx = rays.receiver[hit] - spot
    length = np.linalg.norm(to_rx, axis=1)
    unit = to_rx / np.maximum(length, 1e-300)[:, None]
    facing = np.einsum("ij,ij->i", unit, n) > 0.0
    start = spot + OCCLUSION_RAY_OFFSET_M * n
    if batch is None:
        batch = mujoco.batch.Batch(model, RAY_THREADS, nthread=RAY_THREADS)
    dist = cast_static_rays(batch, start, unit, static_groups)
    blocked = (dist >= 0.0) & (dist < length)
    out[hit] = blocked | ~facing
    return out


def measure(rays: RawRays, sensor: SensorSpec, noise: NoiseSpec, rng: np.random.Generator,
            model: mujoco.MjModel, static_groups: np.ndarray = STATIC_GROUPS,
            batch: mujoco.batch.Batch | None = None) -> Measurement:
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
        blocked = occluded(model, rays, hit, static_groups, batch) & (status == VALID)
        status[blocked] = OCCLUDED

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

    def measure(self, rays: RawRays, rng: np.random.Generator, model: mujoco.MjModel,
                batch: mujoco.batch.Batch | None = None) -> Measurement:
        return measure(rays, self.spec, self.noise, rng, model, STATIC_GROUPS, batch)

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

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

from dataclasses import dataclass

import mujoco
import mujoco.batch
import numpy as np

from twin.scenario import NoiseSpec, SensorSpec

VALID, NO_HIT, OUT_OF_WINDOW, INCIDENCE, OCCLUDED = 0, 1, 2, 3, 4
STATUS_NAMES = {VALID: "valid", NO_HIT: "no_hit", OUT_OF_WINDOW: "out_of_window",
                INCIDENCE: "incidence", OCCLUDED: "occluded"}
# Start the receiver ray this far off the surface so it does not hit its own start point.
OCCLUSION_RAY_OFFSET_M = 1e-7
# The receiver rays of a long scan are cast on this many threads.
RAY_THREADS = 2


@dataclass(frozen=True)
class RawRays:
    """Ideal ray-cast results for a batch of beams (any leading shape).

    Attributes:
        dist: distance from the emitter to the hit [m], -1 for no hit.
        origin: (..., 3) emitter position, world [m].
        direction: (..., 3) unit beam direction, world.
        normal: (..., 3) outward surface normal at the hit, world (0 on a miss).
        receiver: (..., 3) receiver position, world [m].
    """

    dist: np.ndarray
    origin: np.ndarray
    direction: np.ndarray
    normal: np.ndarray
    receiver: np.ndarray


@dataclass(frozen=True)
class Measurement:
    """What the sensor reports: ``d`` [m] (NaN when invalid), ``valid``, ``status`` codes,
    ``incidence_rad`` (NaN on a miss) and the ideal distance ``d_true`` [m] (-1 on a miss)."""

    d: np.ndarray
    valid: np.ndarray
    status: np.ndarray
    incidence_rad: np.ndarray
    d_true: np.ndarray


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
             batch: "mujoco.batch.Batch | None" = None) -> np.ndarray:
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
            model: mujoco.MjModel, static_groups: np.ndarray,
            batch: "mujoco.batch.Batch | None" = None) -> Measurement:
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

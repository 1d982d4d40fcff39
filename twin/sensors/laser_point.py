"""The laser point sensor: one beam along the sensor's +z (a MuJoCo site rangefinder)."""

from __future__ import annotations

import mujoco
import numpy as np

from algorithms.geometry.kinematics import DHTable, reconstruct_points
from twin.sensors.base import RawRays, sensor_slice
from twin.sensors.laser import LaserSensor

# Rangefinder data fields (bitfield of mjtRayDataField): dist | dir | origin | point | normal.
RAYDATA_ALL = 1 | 2 | 4 | 8 | 16


class LaserPoint(LaserSensor):
    """IL-065-class point sensor; B = 1."""

    kind = "point"

    @property
    def beams(self) -> int:
        return 1

    def beam_dirs_sensor(self) -> np.ndarray:
        return np.array([[0.0, 0.0, 1.0]])

    def attach(self, spec: mujoco.MjSpec, body: mujoco.MjsBody) -> None:
        self._attach_body(spec, body)
        self._add_axis_sensors(spec)
        spec.add_sensor(name="laser_ray", type=mujoco.mjtSensor.mjSENS_RANGEFINDER,
                        objtype=mujoco.mjtObj.mjOBJ_SITE, objname="laser", intprm=[RAYDATA_ALL, 0, 0])

    def decode(self, model: mujoco.MjModel, sensordata: np.ndarray, q: np.ndarray) -> RawRays:
        # one ray a step: MuJoCo's site rangefinder, evaluated in the rollout
        ray = sensordata[:, sensor_slice(model, "laser_ray")]
        xaxis = sensordata[:, sensor_slice(model, "laser_xaxis")]
        origin = ray[:, None, 4:7]
        # The receiver sits the triangulation baseline along the sensor's +x.
        return RawRays(ray[:, 0:1], origin, ray[:, None, 1:4], ray[:, None, 10:13],
                       origin + self.spec.baseline_m * xaxis[:, None, :])

    def reconstruct(self, q: np.ndarray, d: np.ndarray, dh: DHTable, T_flange_sensor: np.ndarray) -> np.ndarray:
        return reconstruct_points(q, d[:, 0], dh, T_flange_sensor)[:, None, :]

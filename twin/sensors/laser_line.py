"""The laser line profiler: B beams in a fan in the sensor's x-z plane, one profile per step.

The fan is a 1-pixel-high perspective camera rangefinder (one ray per pixel); its beams all
leave the emitter, the site origin.
"""

from __future__ import annotations

import mujoco
import numpy as np

from algorithms.geometry.kinematics import DHTable, reconstruct_line_points
from twin.sensors.base import RawRays, sensor_slice
from twin.sensors.laser import LaserSensor

RAYDATA_LINE = 1 | 2 | 16  # dist, dir, normal per beam


class LaserLine(LaserSensor):
    """Line profiler: ``spec.beams`` beams over ``spec.fan_deg``; the receiver is offset along +y."""

    kind = "line"

    @property
    def beams(self) -> int:
        return int(self.spec.beams)

    def beam_dirs_sensor(self) -> np.ndarray:
        """Pixel centres spread evenly over ``fan_deg`` in the sensor's x-z plane."""
        half_width = np.tan(np.radians(self.spec.fan_deg) / 2)
        b = self.beams
        x = ((np.arange(b) + 0.5) / b * 2.0 - 1.0) * half_width
        dirs = np.column_stack([x, np.zeros(b), np.ones(b)])
        return dirs / np.linalg.norm(dirs, axis=1, keepdims=True)

    def attach(self, spec: mujoco.MjSpec, body: mujoco.MjsBody) -> None:
        self._attach_body(spec, body)
        n = self.beams
        half = np.radians(self.spec.fan_deg) / 2
        # An N x 1 image: the vertical field of view fovy makes the horizontal one
        # 2 atan(N tan(fovy / 2)), so choose fovy for the fan's full width.
        fovy_deg = float(np.degrees(2 * np.arctan(np.tan(half) / n)))
        # Cameras look along their -z: turn 180 deg about x so the camera's -z is the sensor's +z.
        body.add_camera(name="laser_fan", pos=[0, 0, 0], quat=[0, 1, 0, 0], resolution=[n, 1], fovy=fovy_deg)
        self._add_axis_sensors(spec)
        # The camera's ray data carry no origin: the emitter's position comes from the site.
        spec.add_sensor(name="laser_pos", type=mujoco.mjtSensor.mjSENS_FRAMEPOS, objtype=mujoco.mjtObj.mjOBJ_SITE,
                        objname="laser")
        spec.add_sensor(name="laser_ray", type=mujoco.mjtSensor.mjSENS_RANGEFINDER,
                        objtype=mujoco.mjtObj.mjOBJ_CAMERA, objname="laser_fan", intprm=[RAYDATA_LINE, 0, 0])

    def decode(self, model: mujoco.MjModel, sensordata: np.ndarray) -> RawRays:
        n, b = len(sensordata), self.beams
        r = sensordata[:, sensor_slice(model, "laser_ray")].reshape(n, b, 7)
        yaxis = sensordata[:, sensor_slice(model, "laser_yaxis")]
        emitter = sensordata[:, sensor_slice(model, "laser_pos")]
        origin = np.broadcast_to(emitter[:, None, :], (n, b, 3)).copy()
        receiver = np.broadcast_to((self.spec.baseline_m * yaxis + emitter)[:, None, :], (n, b, 3)).copy()
        return RawRays(r[:, :, 0], origin, r[:, :, 1:4], r[:, :, 4:7], receiver)

    def reconstruct(self, q: np.ndarray, d: np.ndarray, dh: DHTable, T_flange_sensor: np.ndarray) -> np.ndarray:
        return reconstruct_line_points(q, d, self.beam_dirs_sensor(), dh, T_flange_sensor)

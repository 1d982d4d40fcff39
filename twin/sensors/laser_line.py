"""The laser line profiler: B beams in a fan in the sensor's x-z plane, one profile per step.

The beams all leave the emitter, the site origin, spread evenly over the fan like the pixels
of a 1-pixel-high perspective camera. They are cast in bulk after the rollout
(:class:`twin.sensors.raycast.CellRays`: what MuJoCo's camera rangefinder returns, at
Embree's speed), from the emitter and frame axes the rollout's sensors recorded and the
joints of each step.
"""

from __future__ import annotations

import mujoco
import numpy as np

from algorithms.geometry.kinematics import DHTable, reconstruct_line_points
from twin.sensors.base import RawRays, sensor_slice
from twin.sensors.laser import LaserSensor


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
        self._add_axis_sensors(spec)
        spec.add_sensor(name="laser_pos", type=mujoco.mjtSensor.mjSENS_FRAMEPOS, objtype=mujoco.mjtObj.mjOBJ_SITE,
                        objname="laser")

    def decode(self, model: mujoco.MjModel, sensordata: np.ndarray, q: np.ndarray) -> RawRays:
        n, b = len(sensordata), self.beams
        xaxis = sensordata[:, sensor_slice(model, "laser_xaxis")]
        yaxis = sensordata[:, sensor_slice(model, "laser_yaxis")]
        emitter = sensordata[:, sensor_slice(model, "laser_pos")]
        zaxis = np.cross(xaxis, yaxis)
        local = self.beam_dirs_sensor()
        direction = local[None, :, 0:1] * xaxis[:, None, :] + local[None, :, 2:3] * zaxis[:, None, :]
        dist, normal = self.cell_rays(model).beams(emitter, direction, q, int(model.site(self.site).bodyid[0]))
        receiver = self.spec.baseline_m * yaxis + emitter
        return RawRays(dist, np.broadcast_to(emitter[:, None, :], (n, b, 3)), direction, normal,
                       np.broadcast_to(receiver[:, None, :], (n, b, 3)))

    def reconstruct(self, q: np.ndarray, d: np.ndarray, dh: DHTable, T_flange_sensor: np.ndarray) -> np.ndarray:
        return reconstruct_line_points(q, d, self.beam_dirs_sensor(), dh, T_flange_sensor)

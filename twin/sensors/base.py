"""The sensor interface of the cell: what every sensor on the arm does, whatever it measures.

Every sensor (:class:`Sensor`) is attached to the cell's MjSpec on the flange: its geometry,
the site whose pose is its frame and its MuJoCo sensors. Two families build on it: the ray
sensors (:class:`RaySensor`: the laser point sensor and the laser line profiler) and the
touch-trigger probe (:mod:`twin.sensors.touch_probe`).

A ray sensor turns the
per-step ``sensordata`` and joints of the 1 ms rollout into ideal readings, turns them into what the
real device reports (its error model) and rebuilds points in the robot base frame from the
encoder readings (document 004, eq. 2). Every array it returns has a fixed ``(N, B)`` leading
shape: N samples (1 ms apart) by B beams (B = 1 for a point sensor), so no stage needs to
know which sensor it has.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import mujoco
import numpy as np

from algorithms.geometry.kinematics import DHTable
from twin.scenario import NoiseSpec, SensorSpec

VALID, NO_HIT, OUT_OF_WINDOW, INCIDENCE, OCCLUDED = 0, 1, 2, 3, 4
STATUS_NAMES = {VALID: "valid", NO_HIT: "no_hit", OUT_OF_WINDOW: "out_of_window",
                INCIDENCE: "incidence", OCCLUDED: "occluded"}


@dataclass(frozen=True)
class RawRays:
    """Ideal ray-cast results, (N, B) leading shape.

    Attributes:
        dist: (N, B) distance from the emitter to the hit [m], -1 for no hit.
        origin: (N, B, 3) emitter position, world [m] (the beams of a sample share it: may be
            a read-only broadcast of (N, 1, 3)).
        direction: (N, B, 3) unit beam direction, world.
        normal: (N, B, 3) outward surface normal at the hit, world (0 on a miss).
        receiver: (N, B, 3) receiver position, world [m] (shared likewise).
    """

    dist: np.ndarray
    origin: np.ndarray
    direction: np.ndarray
    normal: np.ndarray
    receiver: np.ndarray


@dataclass(frozen=True)
class Measurement:
    """What the sensor reports, (N, B) each: ``d`` [m] (NaN when invalid), ``valid``, ``status``
    codes, ``incidence_rad`` (NaN on a miss) and the ideal distance ``d_true`` [m] (-1 on a miss)."""

    d: np.ndarray
    valid: np.ndarray
    status: np.ndarray
    incidence_rad: np.ndarray
    d_true: np.ndarray


class Sensor(ABC):
    """A sensor on the flange: it adds its geometry, sites and MuJoCo sensors to the cell.

    Attributes:
        kind: the scenario's name of this sensor ("point", "line", "touch_probe").
        site: the name of the site whose pose is the sensor frame.
    """

    kind: str = ""
    site: str = ""

    @abstractmethod
    def attach(self, spec: mujoco.MjSpec, body: mujoco.MjsBody) -> None:
        """Add the sensor's geometry, sites and MuJoCo sensors to ``body`` (the sensor frame)."""


class RaySensor(Sensor):
    """A ray-casting sensor (the laser point sensor and the laser line profiler).

    Attributes:
        spec: the scenario's ``[sensor]`` settings; noise: its ``[noise]`` switches.
        beams: B, the number of beams per sample.
    """

    site: str = "laser"

    def __init__(self, spec: SensorSpec, noise: NoiseSpec):
        self.spec = spec
        self.noise = noise

    def with_settings(self, spec: SensorSpec, noise: NoiseSpec) -> RaySensor:
        """This sensor as another unit of its kind (``spec``: e.g. its own linearity curve) under
        other error switches (``noise``), sharing its ray casters (built per cell model)."""
        other = object.__new__(type(self))   # not copy.copy: the pickled state leaves the casters out
        other.__dict__.update(self.__dict__)
        other.spec, other.noise = spec, noise
        return other

    @property
    @abstractmethod
    def beams(self) -> int:
        """B: beams per sample."""

    @abstractmethod
    def beam_dirs_sensor(self) -> np.ndarray:
        """(B, 3) unit beam directions in the sensor frame."""

    @abstractmethod
    def decode(self, model: mujoco.MjModel, sensordata: np.ndarray, q: np.ndarray) -> RawRays:
        """Ideal readings of a chunk of steps from their ``sensordata`` rows ((n, nsensordata))
        and the joints (n, 6) [rad] the sensors were evaluated at."""

    @abstractmethod
    def measure(self, rays: RawRays, rng: np.random.Generator, model: mujoco.MjModel) -> Measurement:
        """The device's error model applied to ideal readings (vectorised over (N, B)) in the
        cell compiled as ``model``."""

    @abstractmethod
    def reconstruct(self, q: np.ndarray, d: np.ndarray, dh: DHTable, T_flange_sensor: np.ndarray) -> np.ndarray:
        """(N, B, 3) points in the robot base frame from encoder readings (N, 6) and readings (N, B)."""


def sensor_slice(model: mujoco.MjModel, name: str) -> slice:
    """The columns of ``sensordata`` a named MuJoCo sensor fills."""
    s = model.sensor(name)
    return slice(int(s.adr[0]), int(s.adr[0] + s.dim[0]))

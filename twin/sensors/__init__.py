"""Sensors on the arm: one base class (:class:`Sensor`), one module per kind.

The laser sensors are ray sensors (:class:`RaySensor`); a scenario's ``[sensor]`` table
chooses one of them by its ``kind``. The touch-trigger probe
(:class:`twin.sensors.touch_probe.TouchProbe`) is mounted beside the laser when the scenario
has a ``[probe]`` table. To add a ray sensor: subclass :class:`RaySensor` in a new module and
add its ``kind`` to ``SENSORS`` below (and to the scenario's allowed ``sensor.kind`` values).
"""

from twin.scenario import NoiseSpec, SensorSpec
from twin.sensors.base import STATUS_NAMES, Measurement, RawRays, RaySensor, Sensor
from twin.sensors.laser_line import LaserLine
from twin.sensors.laser_point import LaserPoint

SENSORS: dict[str, type[RaySensor]] = {LaserPoint.kind: LaserPoint, LaserLine.kind: LaserLine}


def make_sensor(spec: SensorSpec, noise: NoiseSpec) -> RaySensor:
    """The sensor object for the scenario's ``[sensor]`` table."""
    return SENSORS[spec.kind](spec, noise)


__all__ = ["SENSORS", "STATUS_NAMES", "LaserLine", "LaserPoint", "Measurement", "RawRays", "RaySensor", "Sensor",
           "make_sensor"]

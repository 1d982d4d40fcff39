"""Sensors on the arm: one base class (:class:`Sensor`), one module per kind.

To add a sensor: subclass :class:`twin.sensors.base.Sensor` in a new module and add its
``kind`` to ``SENSORS`` below (and to the scenario's allowed ``sensor.kind`` values).
"""

from twin.scenario import NoiseSpec, SensorSpec
from twin.sensors.base import STATUS_NAMES, Measurement, RawRays, Sensor
from twin.sensors.laser_line import LaserLine
from twin.sensors.laser_point import LaserPoint

SENSORS: dict[str, type[Sensor]] = {LaserPoint.kind: LaserPoint, LaserLine.kind: LaserLine}


def make_sensor(spec: SensorSpec, noise: NoiseSpec) -> Sensor:
    """The sensor object for the scenario's ``[sensor]`` table."""
    return SENSORS[spec.kind](spec, noise)


__all__ = ["SENSORS", "STATUS_NAMES", "LaserLine", "LaserPoint", "Measurement", "RawRays", "Sensor", "make_sensor"]

"""The scan-cell digital twin: scenarios, MuJoCo cell, laser sensor, scans, replay, CLI."""

from twin.errors import TwinError

__all__ = ["TwinError"]

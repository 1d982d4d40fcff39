"""Gymnasium environments for active localization (``import twin.env`` registers them).

- ``twin/ActiveScan-v0`` (:class:`twin.env.active_scan.ActiveScanEnv`): choose the next laser
  scan segment.
- ``twin/ActiveProbe-v0`` (:class:`twin.env.active_probe.ActiveProbeEnv`): choose the next
  touch-probe point.

``gymnasium.make("twin/ActiveScan-v0")`` after ``import twin.env``, or
``gymnasium.make("twin.env:twin/ActiveScan-v0")`` without it.
"""

from gymnasium.envs.registration import register, registry

ACTIVE_SCAN_ID = "twin/ActiveScan-v0"
ACTIVE_PROBE_ID = "twin/ActiveProbe-v0"


def register_envs() -> None:
    """Register the project's environments with gymnasium (once)."""
    if ACTIVE_SCAN_ID not in registry:
        register(id=ACTIVE_SCAN_ID, entry_point="twin.env.active_scan:ActiveScanEnv")
    if ACTIVE_PROBE_ID not in registry:
        register(id=ACTIVE_PROBE_ID, entry_point="twin.env.active_probe:ActiveProbeEnv")


register_envs()

"""Gymnasium environments for active localization (``import twin.env`` registers them).

- ``twin/ActiveScan-v0`` (:class:`twin.env.active_scan.ActiveScanEnv`): choose the next laser
  scan segment.
- ``twin/ActiveProbe-v0`` (:class:`twin.env.active_probe.ActiveProbeEnv`): choose the next
  touch-probe point.

``gymnasium.make("twin/ActiveScan-v0")`` after ``import twin`` (which registers them when
gymnasium is imported, without importing it itself) or ``import twin.env``. Both are registered
with ``max_episode_steps=30`` (gymnasium's ``TimeLimit`` truncates).

Rendering (``render_mode="rgb_array"``) without a display and without ``MUJOCO_GL`` uses MuJoCo's
EGL context, else OSMesa (:func:`twin.env.base.headless_gl_context`).
"""

from gymnasium.envs.registration import register, registry

ACTIVE_SCAN_ID = "twin/ActiveScan-v0"
ACTIVE_PROBE_ID = "twin/ActiveProbe-v0"
#: The step budget of both registrations (the environments' own ``max_steps`` by default).
MAX_EPISODE_STEPS = 30


def register_envs() -> None:
    """Register the project's environments with gymnasium (once)."""
    if ACTIVE_SCAN_ID not in registry:
        register(id=ACTIVE_SCAN_ID, entry_point="twin.env.active_scan:ActiveScanEnv",
                 max_episode_steps=MAX_EPISODE_STEPS)
    if ACTIVE_PROBE_ID not in registry:
        register(id=ACTIVE_PROBE_ID, entry_point="twin.env.active_probe:ActiveProbeEnv",
                 max_episode_steps=MAX_EPISODE_STEPS)


register_envs()

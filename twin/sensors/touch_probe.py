"""A kinematic touch-trigger probe on the flange (defaults: a Renishaw TP20 class probe with
its standard-force module, ``[probe]`` in a scenario).

Geometry (probe frame: z along the stylus, from the probe body to the ball; origin at the
body's back face): the body and module as one cylinder (``body_radius_m`` x
``body_length_m``), the stylus stem (``stylus_radius_m``, from the module's face to the ball
centre, ``stylus_length_m``) and the ball (``ball_radius_m``). The geoms are for display
and for the arm's own contact sensors: they take no part in MuJoCo's collisions, because
MuJoCo collides a mesh as its convex hull. The probe's contact with the part is measured on
the exact triangles instead (:meth:`algorithms.geometry.mesh_index.MeshIndex.signed_distance`,
the project's own mesh index): the touch of the ball, and any unintended contact of the
stylus or the body.

Trigger model (:func:`find_trigger`): the ball touches the exact surface when its centre
comes within the ball radius of it; the machine then travels on by the pre-travel of the
motion's direction in the probe frame (three-lobed sideways, larger along the stylus,
growing with the stylus length, plus unidirectional repeatability noise:
:class:`algorithms.probing.pretravel.PretravelModel`, where the sources of the defaults are
given) and the probe triggers there. The controller latches the joint encoders at the
trigger; the recorded hit is the ball centre computed from those readings with the nominal
kinematics, so servo lag does not enter and kinematic errors do, as on a real machine.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np

from algorithms.probing.pretravel import PretravelModel
from twin.errors import TwinError
from twin.robot import GROUP_ARM
from twin.scenario import NoiseSpec, ProbeSpec, Scenario
from twin.sensors.base import Sensor

BALL_SITE = "probe_ball"
MODULE_SITE = "probe_module"
# Secant refinements of the touch instant between two 1 ms samples (the gap to a curved
# surface is not linear in time; three steps take it to machine precision at probing speeds).
TOUCH_REFINEMENTS = 3



def probe_spec(scenario: Scenario) -> ProbeSpec:
    """The scenario's ``[probe]`` table.

    Raises:
        TwinError: the scenario has no touch probe.
    """
    if scenario.probe is None:
        raise TwinError(f"scenario {scenario.name!r} has no [probe] table: the touch probe is not mounted")
    return scenario.probe

@dataclass(frozen=True)
class Trigger:
    """Where and when the probe triggered, from the true motion (world frame).

    Attributes:
        touch_t_s, trigger_t_s: time of the first touch and of the trigger [s].
        centre_touch: (3,) true ball centre at the touch [m].
        centre_trigger: (3,) true ball centre at the trigger [m].
        direction: (3,) unit direction of the ball's motion at the touch.
        pretravel_m: travel from the touch to the trigger (model + repeatability) [m].
    """

    touch_t_s: float
    trigger_t_s: float
    centre_touch: np.ndarray
    centre_trigger: np.ndarray
    direction: np.ndarray
    pretravel_m: float


class TouchProbe(Sensor):
    """The touch-trigger probe: its geometry on the flange and its trigger model."""

    kind = "touch_probe"
    site = "probe"

    def __init__(self, spec: ProbeSpec, noise: NoiseSpec):
        self.spec = spec
        self.noise = noise
        self.pretravel = PretravelModel(
            lateral_m=spec.lateral_pretravel_m, lobe_m=spec.lobe_m, lobe_phase_rad=np.radians(spec.lobe_phase_deg),
            axial_m=spec.axial_pretravel_m, reference_stylus_m=spec.reference_stylus_m,
            stylus_m=spec.stylus_length_m, repeatability_sigma_m=spec.repeatability_2sigma_m / 2.0)

    def attach(self, spec: mujoco.MjSpec, body: mujoco.MjsBody) -> None:
        p = self.spec
        rgba_body, rgba_stylus, rgba_ball = [0.15, 0.15, 0.17, 1], [0.7, 0.7, 0.72, 1], [0.75, 0.1, 0.12, 1]
        common = {"contype": 0, "conaffinity": 0, "group": GROUP_ARM}
        body.add_geom(name="probe_body", type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                      size=[p.body_radius_m, p.body_length_m / 2, 0], pos=[0, 0, p.body_length_m / 2],
                      rgba=rgba_body, **common)
        stem = p.stylus_length_m - p.ball_radius_m
        body.add_geom(name="probe_stylus", type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                      size=[p.stylus_radius_m, stem / 2, 0], pos=[0, 0, p.body_length_m + stem / 2],
                      rgba=rgba_stylus, **common)
        body.add_geom(name="probe_ball", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[p.ball_radius_m, 0, 0],
                      pos=[0, 0, p.tip_length_m], rgba=rgba_ball, **common)
        body.add_site(name=self.site, pos=[0, 0, 0], size=[0.001, 0, 0])
        body.add_site(name=MODULE_SITE, pos=[0, 0, p.body_length_m], size=[0.001, 0, 0])
        body.add_site(name=BALL_SITE, pos=[0, 0, p.tip_length_m], size=[0.001, 0, 0])
        for site in (BALL_SITE, MODULE_SITE):
            spec.add_sensor(name=f"{site}_pos", type=mujoco.mjtSensor.mjSENS_FRAMEPOS,
                            objtype=mujoco.mjtObj.mjOBJ_SITE, objname=site)

    def pretravel_direction(self, direction_world: np.ndarray, R_world_probe: np.ndarray) -> np.ndarray:
        """The motion direction in the probe frame (the pre-travel model's argument)."""
        return np.asarray(direction_world, dtype=np.float64) @ R_world_probe


def find_trigger(t: np.ndarray, centres: np.ndarray, gap: Callable[[np.ndarray], np.ndarray],
                 draw_pretravel: Callable[[np.ndarray], float]) -> Trigger | None:
    """The touch and the trigger along a sampled ball-centre motion (1 ms samples).

    Args:
        t: (n,) sample times [s].
        centres: (n, 3) true ball-centre positions [m] (any fixed frame, e.g. the world).
        gap: signed distance of ball-centre positions (k, 3) to the exact surface minus the
            ball radius [m]: positive in the air, zero at the touch.
        draw_pretravel: the pre-travel [m] for a unit motion direction (3,) in the same frame
            (the model plus its repeatability noise).

    Returns:
        The trigger, or None when the ball does not touch, or the trigger lies beyond the
        last sample (more motion is needed to know).
    """
    g = gap(centres)
    inside = np.flatnonzero(g <= 0.0)
    if len(inside) == 0 or inside[0] == 0:
        return None
    k = int(inside[0])
    # The touch between samples k-1 and k: secant steps on the exact gap.
    a, b = 0.0, 1.0
    ga, gb = float(g[k - 1]), float(g[k])
    s = ga / (ga - gb)
    for _ in range(TOUCH_REFINEMENTS):
        gs = float(gap((centres[k - 1] + s * (centres[k] - centres[k - 1]))[None])[0])
        if gs > 0:
            a, ga = s, gs
        else:
            b, gb = s, gs
        if ga == gb:
            break
        s = a + ga * (b - a) / (ga - gb)
    step = centres[k] - centres[k - 1]
    direction = step / np.linalg.norm(step)
    c_touch = centres[k - 1] + s * step
    t_touch = float(t[k - 1] + s * (t[k] - t[k - 1]))
    delta = float(draw_pretravel(direction))
    # Walk on along the sampled motion until the travel since the touch reaches delta.
    pts = np.vstack([c_touch, centres[k:]])
    ts = np.concatenate([[t_touch], t[k:]])
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    j = int(np.searchsorted(cum, delta, side="left"))
    if j >= len(cum):
        return None
    if j == 0:
        return Trigger(t_touch, t_touch, c_touch, c_touch.copy(), direction, delta)
    f = (delta - cum[j - 1]) / seg[j - 1]
    c_trig = pts[j - 1] + f * (pts[j] - pts[j - 1])
    t_trig = float(ts[j - 1] + f * (ts[j] - ts[j - 1]))
    return Trigger(t_touch, t_trig, c_touch, c_trig, direction, delta)

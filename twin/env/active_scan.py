"""``twin/ActiveScan-v0``: choose the next laser scan segment to pin the part down fastest.

Each step the agent names a short scan segment (:mod:`twin.env.views`); the environment
solves the joints with mink, simulates the motion and the line in the true cell at 1 ms with
the scenario's sensor model and arm (:mod:`twin.env.arm`), adds the points and re-localizes
on every point so far (:func:`algorithms.registration.bayes.localize_map`: maximum a posteriori
with the placement prior, so directions the points do not fix yet stay at the prior; one
linearity offset per ``LINEARITY_BIN_M`` of readings; points near sharp edges left out; from
the current estimate, falling back to the prior mean when that fit is not trusted).

Observation (float64, 20 values, ``OBSERVATION_LAYOUT``):

- ``pose`` (6): the estimate relative to the nominal pose, the twist ``log(T_nom^-1 T_est)``
  ``[omega (rad), v (m)]`` in the workpiece frame;
- ``log_eigenvalues`` (6): ascending log-eigenvalues of the posterior pose information
  (prior + points), rotations scaled by the part's size (:mod:`twin.env.information`);
- ``points`` (1): the number of points measured so far;
- ``last_gain`` (1): the information gain of the last segment [nats];
- ``joints`` (6): the arm's joint positions [rad].

Reward: the information gain of the segment [nats] minus ``time_cost_per_s`` per second of
motion; a view that misses the part or that the arm cannot reach measures nothing and costs
``unreachable_penalty``; a collision costs ``collision_penalty`` and ends the episode.

Terminated when the largest standard deviation of any rotation is under ``tolerance_deg``
and of any translation under ``tolerance_m`` (directions the shape cannot fix excepted), for a
trusted fit (:mod:`twin.env.base`) confirmed by a segment it had not seen (``is_success``), or
on a collision; truncated after ``max_steps`` steps.

Episodes: ``reset(seed=...)`` draws, from that seed alone, the scenario (one of
``scenarios``), the part's true pose (the nominal pose moved by a Gaussian twist of
``placement_sigma_m`` and ``placement_sigma_deg`` per axis: the prior the information starts
from) and the seed of every random stream of the cell (sensor, encoders, kinematic errors).
The same seed and the same actions give the same episode, bit for bit.

Actions outside [-1, 1] are clipped (``info["clipped"]``); an action of the wrong shape or
with a non-finite value is refused with ``ValueError``.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from algorithms.geometry.kinematics import ur_inverse
from algorithms.geometry.se3 import inv_pose
from algorithms.registration.bayes import MapResult, localize_map, normalized_innovations
from twin.cell import Cell
from twin.env.arm import ScanArm, SegmentResult, build_scan_cell
from twin.env.base import (
    EDGE_BAND_MIN_M,
    EDGE_BAND_SIGMAS,
    INNOVATION_GATE,
    MAX_OUTLIER_FRACTION,
    OBSERVATION_LAYOUT,
    OBSERVATION_SIZE,
    PRIOR_MAHALANOBIS_MAX,
    SCENARIOS_DIR,
    ActiveLocalizationEnv,
    EnvScenario,
    prepare,
    seed_realized,
)
from twin.env.views import ACTION_SIZE, View, decode_action, segment_centre, sensor_line
from twin.realize import Realized
from twin.robot import UR5E_DH
from twin.scenario import NoiseSpec, Scenario, SensorSpec

# The episodes, the estimate and the stopping rule live in twin.env.base (shared with the
# touch-probe sibling); its constants stay importable from here.
__all__ = ["ActiveScanEnv", "DEFAULT_SCENARIOS", "EDGE_BAND_MIN_M", "EDGE_BAND_SIGMAS", "EnvScenario",
           "INNOVATION_GATE", "LINEARITY_BIN_M", "MAX_OUTLIER_FRACTION", "OBSERVATION_LAYOUT", "OBSERVATION_SIZE",
           "PRIOR_MAHALANOBIS_MAX", "SCENARIOS_DIR", "bias_sigma_m", "point_sigma_m", "prepare"]

DEFAULT_SCENARIOS = ("bracket.toml",)
#: The linearity error is estimated as one offset per bin of readings this wide [m] (the
#: IL-065's +/-10 um curve over its 50 mm window changes by about 1.3 um across 1 mm).
LINEARITY_BIN_M = 0.001


@dataclass(frozen=True)
class ScanScenario(EnvScenario):
    """A scenario prepared for scanning: :class:`twin.env.base.EnvScenario` and the nominal
    cell with the part's collision shape (the arm's planning checks)."""

    clearance: Cell


#: Views tried at construction to check that the arm reaches the part at all.
_CHECK_VIEWS = [(az, el) for el in (90.0, 60.0, 35.0) for az in range(-180, 180, 30)]


def _reachable_views(env_scenario: EnvScenario) -> int:
    """How many of ``_CHECK_VIEWS`` (aimed at the part's centre, mid-window) the arm reaches by
    the closed-form inverse kinematics within its joint ranges."""
    sc = env_scenario.scenario
    T_world_wp = sc.workpiece.T_world_workpiece_nominal
    model = env_scenario.nominal.model
    lo, hi = model.jnt_range[:6, 0], model.jnt_range[:6, 1]
    w = 0.5 * (sc.sensor.window_m[0] + sc.sensor.window_m[1])
    poses = []
    for az, el in _CHECK_VIEWS:
        view = View(np.radians(az), np.radians(el), w, 0.0, (0.0, 0.0))
        c = segment_centre(view, T_world_wp, env_scenario.workpiece, env_scenario.geometry)
        if c is not None:
            poses.append(sensor_line(view, c, 0.0)[0])
    if not poses:
        return 0
    T_base_flange = inv_pose(sc.T_world_base) @ np.array(poses) @ inv_pose(sc.sensor.T_flange_sensor)
    sol = ur_inverse(T_base_flange, UR5E_DH)
    ok = sol.valid & np.all((sol.q >= lo) & (sol.q <= hi), axis=-1)
    return int(ok.any(axis=1).sum())


def point_sigma_m(sensor: SensorSpec, noise: NoiseSpec) -> float:
    """A point's noise along the beam at normal incidence [m]: repeatability and the output's
    quantisation (uniform, step / sqrt(12)), as switched on."""
    var = (sensor.sigma_m**2 if noise.gaussian else 0.0) + \
        (sensor.resolution_m**2 / 12 if noise.quantization else 0.0)
    return float(max(np.sqrt(var), 1e-9))


def bias_sigma_m(sensor: SensorSpec, noise: NoiseSpec) -> float:
    """The spread of the linearity error over readings [m]: the RMS of a sine curve of
    amplitude ``linearity_m``, ``linearity_m / sqrt(2)`` (0 when switched off)."""
    return float(sensor.linearity_m / np.sqrt(2)) if noise.linearity else 0.0


class ActiveScanEnv(ActiveLocalizationEnv):
    """Active localization with a laser displacement sensor (module docstring).

    Args:
        scenarios: a scenario file, a :class:`Scenario`, or a list of them (names resolve in
            the project's ``scenarios/`` folder); each episode draws one.
        tolerance_m, tolerance_deg: the standard deviations that end an episode.
        max_steps: the step budget (truncation).
        segment_length_m: length of each scan line [m].
        retract_m: how far the sensor backs off along its beam between lines [m].
        time_cost_per_s: reward lost per second of motion.
        unreachable_penalty: reward lost by a view that misses the part or is out of reach.
        collision_penalty: reward lost by a collision (the episode ends).
        placement_sigma_m, placement_sigma_deg: the fixture's placement scatter per axis.
        points_per_segment: a line's valid 1 ms samples are thinned to at most this many,
            evenly spaced, before localization (the white noise then still counts for less
            than the linearity error: thinning 600 samples to 100 changes a line's
            information little and the fit's cost a lot).
        render_mode: None or ``"rgb_array"``; width, height: the rendered image [pixels].
    """

    action_size = ACTION_SIZE

    def __init__(self, scenarios=DEFAULT_SCENARIOS, tolerance_m: float = 10e-6, tolerance_deg: float = 0.01,
                 max_steps: int = 30, segment_length_m: float = 0.03, retract_m: float = 0.03,
                 time_cost_per_s: float = 0.5, unreachable_penalty: float = 1.0, collision_penalty: float = 10.0,
                 placement_sigma_m: float = 1e-3, placement_sigma_deg: float = 0.5, points_per_segment: int = 100,
                 render_mode: str | None = None, width: int = 640, height: int = 480):
        super().__init__(scenarios, tolerance_m=tolerance_m, tolerance_deg=tolerance_deg, max_steps=max_steps,
                         time_cost_per_s=time_cost_per_s, unreachable_penalty=unreachable_penalty,
                         collision_penalty=collision_penalty, placement_sigma_m=placement_sigma_m,
                         placement_sigma_deg=placement_sigma_deg, render_mode=render_mode, width=width,
                         height=height, points_per_step=points_per_segment,
                         positive={"segment_length_m": segment_length_m},
                         nonnegative={"retract_m": retract_m}, counts={"points_per_segment": points_per_segment})
        self.points_per_segment = points_per_segment
        self.segment_length_m = float(segment_length_m)
        self.retract_m = float(retract_m)

    def _check_scenario(self, es: EnvScenario) -> None:
        if es.scenario.sensor.kind != "point":
            raise ValueError(f"scenario {es.scenario.name!r}: ActiveScan-v0 takes a laser point sensor "
                             f"(sensor.kind = 'point'), got {es.scenario.sensor.kind!r}")
        if _reachable_views(es) == 0:
            raise ValueError(f"scenario {es.scenario.name!r}: the arm reaches none of {len(_CHECK_VIEWS)} "
                             f"views of the part (elevations 90, 60 and 35 deg, every 30 deg of azimuth); "
                             f"move the part or the robot base")

    # ------------------------------------------------------------------ episodes
    def _prepare(self, scenario: Scenario) -> ScanScenario:
        es = prepare(scenario)
        return ScanScenario(**{f.name: getattr(es, f.name) for f in fields(es)},
                            clearance=build_scan_cell(seed_realized(scenario, es.workpiece), es.hfield, "nominal"))

    def _start_episode(self, es: EnvScenario, realized: Realized) -> dict:
        if not isinstance(es, ScanScenario):   # _prepare makes every scenario of this environment one
            raise TypeError(f"ActiveScanEnv runs on a ScanScenario (from its _prepare), got {type(es).__name__}")
        true_cell = build_scan_cell(realized, es.hfield)
        arm = ScanArm(realized, es.nominal, true_cell, es.clearance, realized.scenario.scan.speed_m_s,
                      self.retract_m)
        return {"arm": arm, "readings": np.zeros(0), "beams": np.zeros((0, 3))}

    # ------------------------------------------------------------------ steps
    def _measure(self, action: np.ndarray, events: dict) -> SegmentResult | None:
        """The segment the action names, planned and scanned (None: out of reach or blind)."""
        ep = self.episode
        es, realized, arm = ep["es"], ep["realized"], ep["arm"]
        view = decode_action(action, es.geometry)
        T_world_est = realized.scenario.T_world_base @ ep["T_base_est"]
        centre = segment_centre(view, T_world_est, es.workpiece, es.geometry)
        if centre is None:
            events["unreachable"] = "the beam misses the part"
            return None
        motion = arm.plan(*sensor_line(view, centre, self.segment_length_m))
        if isinstance(motion, str):
            events["unreachable"] = motion
            return None
        result = arm.execute(motion)
        events["segment_points"] = len(result.points_base)
        events["duration_s"] = result.duration_s
        return result.decimated(self.points_per_segment)

    def _append(self, result: SegmentResult) -> None:
        ep = self.episode
        ep["readings"] = np.concatenate([ep["readings"], result.readings_m])
        ep["beams"] = np.vstack([ep["beams"], np.repeat(result.beam_base[None], len(result.points_base), 0)])

    def _innovations(self, result: SegmentResult) -> np.ndarray:
        ep = self.episode
        sensor, noise = ep["realized"].scenario.sensor, ep["realized"].scenario.noise
        return normalized_innovations(result.points_base,
                                      np.repeat(result.beam_base[None], len(result.points_base), 0),
                                      ep["es"].workpiece.index, ep["T_base_est"], ep["fit"].covariance,
                                      point_sigma_m(sensor, noise), bias_sigma_m(sensor, noise), noise.incidence)

    def _localize(self, init: np.ndarray | None) -> MapResult:
        """Maximum a posteriori with the placement prior and one linearity offset per bin of
        readings (``LINEARITY_BIN_M``), from ``init``."""
        ep = self.episode
        sensor, noise = ep["realized"].scenario.sensor, ep["realized"].scenario.noise
        bins = np.floor((ep["readings"] - sensor.window_m[0]) / LINEARITY_BIN_M).astype(np.int64)
        return localize_map(ep["points"], ep["es"].workpiece.index, ep["realized"].T_base_workpiece_nominal,
                            self.prior, point_sigma_m(sensor, noise), init=init, groups=np.clip(bins, 0, None),
                            beams=ep["beams"], bias_sigma_m=bias_sigma_m(sensor, noise),
                            incidence_noise=noise.incidence, edges=ep["es"].edges, edge_band_m=self.edge_band_m())

    def _point_sigma_m(self) -> float:
        sc = self.episode["realized"].scenario
        return point_sigma_m(sc.sensor, sc.noise)

    def _joints(self) -> np.ndarray:
        return self.episode["arm"].joints()

    def _render_scene(self) -> tuple[Cell, np.ndarray]:
        arm = self.episode["arm"]
        return arm.cell, arm.state

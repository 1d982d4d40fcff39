"""``twin/ActiveScan-v0``: choose the next laser scan segment to pin the part down fastest
(:class:`ActiveScanEnv`; its docstring has the spaces, rewards and episode rules).

How a step is simulated: the segment the action names (:mod:`twin.env.views`) is planned with
mink and the motion and the line are simulated in the true cell at 1 ms with the scenario's
sensor model and arm (:mod:`twin.env.arm`); the points are added and the part re-localized on
every point so far (:func:`algorithms.registration.bayes.localize_map`: maximum a posteriori
with the placement prior, so directions the points do not fix yet stay at the prior; one
linearity offset per ``LINEARITY_BIN_M`` of readings; points near sharp edges left out; from
the current estimate, falling back to the prior mean when that fit is not trusted).
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
    DEFAULT_MAX_STEPS,
    EDGE_BAND_MIN_M,
    EDGE_BAND_SIGMAS,
    INNOVATION_GATE,
    MAX_OUTLIER_FRACTION,
    PRIOR_MAHALANOBIS_MAX,
    SCENARIOS_DIR,
    ActiveLocalizationEnv,
    EnvScenario,
    ScenarioChoice,
    prepare,
    seed_realized,
)
from twin.env.views import ACTION_SIZE, ELEVATION_MIN_DEG, decode_action, segment_centre, sensor_line, view_table
from twin.realize import Realized
from twin.robot import UR5E_DH
from twin.scenario import NoiseSpec, Scenario, SensorSpec

# The episodes, the estimate and the stopping rule live in twin.env.base (shared with the
# touch-probe sibling); its constants stay importable from here.
__all__ = ["ActiveScanEnv", "DEFAULT_SCENARIOS", "EDGE_BAND_MIN_M", "EDGE_BAND_SIGMAS", "EnvScenario",
           "INNOVATION_GATE", "LINEARITY_BIN_M", "MAX_OUTLIER_FRACTION",
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


#: Views tried at construction to check that the arm reaches the part at all: (azimuth,
#: elevation) [deg], aimed at the part's centre, mid-window.
_CHECK_VIEWS = [(az, el) for el in (90.0, 60.0, 35.0) for az in range(-180, 180, 30)]


def _check_actions() -> np.ndarray:
    a1 = [2 * (el - ELEVATION_MIN_DEG) / (90.0 - ELEVATION_MIN_DEG) - 1 for _, el in _CHECK_VIEWS]
    return np.array([[az / 180.0, e, 0.0, 0.0, 0.0, 0.0] for (az, _), e in zip(_CHECK_VIEWS, a1, strict=True)])


def reachable_views(env_scenario: EnvScenario, actions: np.ndarray, length_m: float) -> np.ndarray:
    """(N,) bool: which of the box ``actions`` (N, 6) name a segment whose beam meets the part
    at its nominal pose and whose two ends the closed-form inverse kinematics reaches within
    the joint ranges (the motion's collisions are not checked)."""
    sc = env_scenario.scenario
    T_world_wp = sc.workpiece.T_world_workpiece_nominal
    model = env_scenario.nominal.model
    lo, hi = model.jnt_range[:6, 0], model.jnt_range[:6, 1]
    poses, owner = [], []
    for i, a in enumerate(actions):
        view = decode_action(a, env_scenario.geometry)
        c = segment_centre(view, T_world_wp, env_scenario.workpiece, env_scenario.geometry)
        if c is not None:
            poses += list(sensor_line(view, c, length_m))
            owner += [i, i]
    ok = np.zeros(len(actions), dtype=bool)
    if not poses:
        return ok
    T_base_flange = inv_pose(sc.T_world_base) @ np.array(poses) @ inv_pose(sc.sensor.T_flange_sensor)
    sol = ur_inverse(T_base_flange, UR5E_DH)
    reached = (sol.valid & np.all((sol.q >= lo) & (sol.q <= hi), axis=-1)).any(axis=1)
    both = np.ones(len(actions), dtype=bool)
    np.logical_and.at(both, np.array(owner), reached)
    ok[np.unique(owner)] = both[np.unique(owner)]
    return ok


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
    """Choose the next laser scan segment to pin a clamped part down fastest.

    ## Description

    A UR5e with a laser displacement sensor on its flange stands before a part clamped near
    its nominal pose; where exactly, only the simulator knows. Each step the agent names one
    short scan line; the arm drives it in the true cell at 1 ms (MuJoCo, mink), the sensor
    measures with the scenario's error model, and the part is re-localized on every point so
    far, starting from the fixture's placement prior. The episode is won when every rotation
    and translation of the pose is known within the tolerances, by a fit that new points
    confirm. ``env.unwrapped.episode`` holds the running state for model-based baselines
    (:mod:`twin.env.policies`); a learning agent needs only the observation.

    ## Action Space

    ``actions="box"`` (default): ``Box(-1, 1, (6,), float32)``, mapped linearly
    (:func:`twin.env.views.decode_action`; values outside are clipped, ``info["clipped"]``):

    | index | component | range |
    |---|---|---|
    | 0 | azimuth of the view (direction from the part to the sensor) | [-180, 180] deg about world z |
    | 1 | elevation of the view | [20, 90] deg above the table |
    | 2 | stand-off | the sensor's measuring window |
    | 3 | line direction | [0, 180] deg from the azimuth tangent |
    | 4, 5 | aim offsets in the plane normal to the view | [-R, R], R the part's bounding radius |

    ``actions="views"``: ``Discrete(200)``, an index into ``view_table`` (20 view directions,
    elevations 90, 60 and 35 deg; 5 aim offsets; 2 line directions; mid-window:
    :func:`twin.env.views.view_table`). ``info["action_mask"]`` and ``action_masks()`` say which
    views the arm reaches at the part's nominal pose (closed-form inverse kinematics at both ends
    of the line, the beam meeting the part).

    ## Observation Space

    ``Dict`` of float32 boxes (:mod:`twin.env.observation` has the formulas);
    ``gymnasium.wrappers.FlattenObservation`` makes it one vector of 66:

    | key | size | bounds | meaning |
    |---|---|---|---|
    | pose | 6 | [-1, 1] | estimate relative to the nominal pose, in prior sigmas (tanh) |
    | std | 6 | [-1, 1] | posterior standard deviation of each pose component: 1 prior, 0 tolerance (log scale) |
    | correlation | 15 | [-1, 1] | posterior correlations (upper triangle), workpiece frame |
    | worst_std | 2 | [-1, 1] | the stopping rule's worst rotation and translation deviation, scaled as std |
    | coverage | 14 | [0, 1] | points measured per surface-normal direction (workpiece frame) |
    | surface | 14 | [0, 1] | the part's area per surface-normal direction |
    | joints | 6 | [-1, 1] | the arm's joints over their ranges |
    | progress | 3 | [0, 1] | steps left, last information gain, points so far |

    ## Rewards

    | term | value |
    |---|---|
    | information gain | the increase of ``log det`` of the posterior pose information [nats] |
    | motion | ``-time_cost_per_s`` per second of motion |
    | a view that misses the part, is out of reach or measures nothing | ``-unreachable_penalty`` |
    | a collision of the arm or sensor | ``-collision_penalty`` (the episode ends) |

    ## Starting State

    ``reset(seed=...)`` draws, from that seed alone, the scenario (one of ``scenarios``), the
    part's true pose (the nominal pose moved by a Gaussian twist of ``placement_sigma_m`` and
    ``placement_sigma_deg`` per axis: the prior the information starts from) and the seed of
    every random stream of the cell (sensor, encoders, kinematic errors). The arm starts at the
    scenario's home pose, nothing measured, the estimate at the nominal pose. The same seed and
    actions give the same episode, bit for bit.

    ## Episode End

    Terminated when the worst rotation and translation standard deviations (directions the
    part's shape cannot fix excepted) are within ``tolerance_deg`` and ``tolerance_m``, for a
    trusted fit that the next segment's points confirm (``info["is_success"]``), or on a
    collision. Truncated after ``max_steps`` steps (30; the registration's ``max_episode_steps``
    is the same, so ``gymnasium.make`` adds a ``TimeLimit`` that agrees).

    ## Arguments

    Args:
        scenarios: a scenario file, a :class:`Scenario`, or a list of them (names resolve in
            the project's ``scenarios/`` folder); each episode draws one.
        tolerance_m: the translation standard deviation that ends an episode [m].
        tolerance_deg: the rotation standard deviation that ends an episode [deg].
        max_steps: the step budget (truncation; ``gymnasium.make`` also wraps the environment
            in ``TimeLimit`` at the registration's 30: pass ``max_episode_steps`` with another).
        segment_length_m: length of each scan line [m].
        retract_m: how far the sensor backs off along its beam between lines [m].
        time_cost_per_s: reward lost per second of motion.
        unreachable_penalty: reward lost by a view that misses the part or is out of reach.
        collision_penalty: reward lost by a collision (the episode ends).
        placement_sigma_m: the fixture's placement scatter per axis [m] (the prior's standard
            deviation), or a (low, high) range each episode draws its scatter from,
            log-uniformly (a variety of clamps for training).
        placement_sigma_deg: the same for the rotations [deg].
        points_per_segment: a line's valid 1 ms samples are thinned to at most this many,
            evenly spaced, before localization (the white noise then still counts for less
            than the linearity error: thinning 600 samples to 100 changes a line's
            information little and the fit's cost a lot).
        actions: ``"box"`` or ``"views"`` (Action Space).
        render_mode: None or ``"rgb_array"`` (the cell from behind the part, the points drawn;
            without a display MuJoCo's EGL, else OSMesa, is chosen: :mod:`twin.env`); width,
            height: the rendered image [pixels].
    """

    action_size = ACTION_SIZE

    def __init__(self, scenarios: ScenarioChoice = DEFAULT_SCENARIOS, tolerance_m: float = 10e-6,
                 tolerance_deg: float = 0.01,
                 max_steps: int = DEFAULT_MAX_STEPS, segment_length_m: float = 0.03, retract_m: float = 0.03,
                 time_cost_per_s: float = 0.5, unreachable_penalty: float = 1.0, collision_penalty: float = 10.0,
                 placement_sigma_m: float | tuple[float, float] = 1e-3,
                 placement_sigma_deg: float | tuple[float, float] = 0.5, points_per_segment: int = 100,
                 actions: str = "box", render_mode: str | None = None, width: int = 640, height: int = 480):
        self.segment_length_m = segment_length_m   # the views' reach check needs it (checked below)
        super().__init__(scenarios, tolerance_m=tolerance_m, tolerance_deg=tolerance_deg, max_steps=max_steps,
                         time_cost_per_s=time_cost_per_s, unreachable_penalty=unreachable_penalty,
                         collision_penalty=collision_penalty, placement_sigma_m=placement_sigma_m,
                         placement_sigma_deg=placement_sigma_deg, render_mode=render_mode, width=width,
                         height=height, actions=actions, points_per_step=points_per_segment,
                         positive={"segment_length_m": segment_length_m},
                         nonnegative={"retract_m": retract_m}, counts={"points_per_segment": points_per_segment})
        self.points_per_segment = points_per_segment
        self.segment_length_m = float(segment_length_m)
        self.retract_m = float(retract_m)

    def _check_scenario(self, es: EnvScenario) -> None:
        if es.scenario.sensor.kind != "point":
            raise ValueError(f"scenario {es.scenario.name!r}: ActiveScan-v0 takes a laser point sensor "
                             f"(sensor.kind = 'point'), got {es.scenario.sensor.kind!r}")
        if not reachable_views(es, _check_actions(), 0.0).any():
            raise ValueError(f"scenario {es.scenario.name!r}: the arm reaches none of {len(_CHECK_VIEWS)} "
                             f"views of the part (elevations 90, 60 and 35 deg, every 30 deg of azimuth); "
                             f"move the part or the robot base")

    def _view_table(self) -> np.ndarray:
        return view_table()

    def _view_mask(self, es: EnvScenario, table: np.ndarray) -> np.ndarray:
        return reachable_views(es, table, float(self.segment_length_m))

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

"""What the active-localization environments share: episodes, the estimate, the stopping rule.

An environment of this family places a part near its nominal pose, lets the agent choose one
measurement per step with some sensor on the arm, re-localizes the part on every point so far
(maximum a posteriori with the fixture's placement prior,
:func:`algorithms.registration.bayes.localize_map`) and pays the information gained less the
time spent. :class:`ActiveLocalizationEnv` holds all of that; a subclass supplies the sensor:

- ``_start_episode``: the episode's measuring device (an arm in the true cell, ...);
- ``_measure``: one action measured: the new points, their durations and contacts;
- ``_append``: what the localization needs of the new points besides the points themselves;
- ``_localize``: the ``localize_map`` call on every point so far;
- ``_innovations``: the normalised innovations of new points at the current estimate;
- ``_point_sigma_m``, ``_joints``, ``_render_scene``.

Observation: a ``Dict`` of float32 arrays, each bounded, described in
:mod:`twin.env.observation` (the estimate, its covariance as standard deviations and
correlations in the workpiece frame, the stopping rule's worst deviations, which surface
directions have been measured and which the part has, the arm's joints, steps left, the last
gain, the points so far).

Actions: ``actions="box"`` (the default) takes the subclass's ``action_size`` numbers in
[-1, 1] (float32); ``actions="views"`` takes an index into the subclass's fixed table of
views (``view_table``, a ``Discrete`` space), with ``info["action_mask"]`` (and
``action_masks()``) saying which of them the arm reaches at the part's nominal pose.

Termination: the worst rotation and translation standard deviations (directions the shape
cannot fix excepted) under the tolerances, for a fit that is trusted (``_fit_verdict``) and
confirmed by new points it had not seen (``_confirm``); or a collision. Truncation after
``max_steps`` steps (``DEFAULT_MAX_STEPS``, also the registration's ``max_episode_steps``: for
another budget pass both to ``gymnasium.make``, the environment's observation counts down to
``max_steps``). Episodes are drawn from the ``reset`` seed alone (scenario, placement twist,
seeds of the cell's random streams): the same seed and actions give the same episode.
"""

from __future__ import annotations

import importlib
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces

from algorithms.geometry.edges import SharpEdges
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import exp_se3, inv_pose, log_se3
from algorithms.registration.bayes import MapResult
from algorithms.registration.fit_check import poor_fit_reason
from twin.cell import Cell, build_cell
from twin.env.information import log_det, model_free_directions, prior_information, worst_std
from twin.env.observation import (
    GAIN_SCALE_NATS,
    NORMAL_BINS,
    POSE_SIGMAS,
    as_float32,
    covariance_features,
    coverage,
    normal_bins,
    observation_space,
    scaled_joints,
    scaled_std,
    surface_shares,
)
from twin.env.views import Geometry
from twin.errors import TwinError
from twin.evaluate import pose_errors
from twin.realize import Realized, Streams, Workpiece, draw_truth, load_workpiece_mesh
from twin.replay import HeightField, height_field
from twin.robot import GROUP_ARM
from twin.scenario import Scenario, load_scenario

SCENARIOS_DIR = Path(__file__).resolve().parents[2] / "scenarios"
#: The step budget by default (and the registrations' ``max_episode_steps``).
DEFAULT_MAX_STEPS = 30
#: What an action may be: numbers in [-1, 1], or the index of one of the subclass's views.
ACTION_KINDS = ("box", "views")
#: The rendering camera looks at the part from this many part sizes plus this distance [m].
RENDER_DISTANCE_PARTS, RENDER_DISTANCE_M = 3.0, 0.25
#: ... from this elevation [deg] (negative: looking down), the arm drawn with this opacity.
RENDER_ELEVATION_DEG = -65.0
RENDER_ARM_ALPHA = 0.3
#: An estimate farther than this from the nominal pose, in prior standard deviations
#: (sqrt of the Mahalanobis form; chi-square 6 DOF: 99.9 % below 4.74), is not trusted.
PRIOR_MAHALANOBIS_MAX = 4.74
#: The RMS normalised innovation of a new segment under which it confirms the estimate.
INNOVATION_GATE = 3.0
#: Points nearer a sharp edge of the model than this many standard deviations of the
#: estimate's position (at the part's size), and at least EDGE_BAND_MIN_M, are left out of
#: the fit: their face is unsure (algorithms.geometry.edges).
EDGE_BAND_SIGMAS = 3.0
EDGE_BAND_MIN_M = 20e-6
#: A fit that calls more of the points outliers is not trusted (the cell's sensor model
#: gives no outliers on the part itself: its only misses are invalid readings).
MAX_OUTLIER_FRACTION = 0.01


@dataclass(frozen=True)
class EnvScenario:
    """A scenario prepared once for many episodes: its mesh, index, nominal cell and views."""

    scenario: Scenario
    workpiece: Workpiece
    nominal: Cell
    geometry: Geometry
    free_directions: np.ndarray
    length_m: float
    hfield: HeightField
    edges: SharpEdges
    surface: np.ndarray   # (14,) the share of the part's area per normal bin (twin.env.observation)


#: What names an environment's scenarios: a file, a loaded scenario, or a sequence of them.
ScenarioChoice = str | Path | Scenario | Sequence[str | Path | Scenario]


def as_scenarios(scenarios: ScenarioChoice) -> list[Scenario]:
    """The scenarios named by a file, a :class:`Scenario` or a list of them (names resolve in
    the project's ``scenarios/`` folder)."""
    if isinstance(scenarios, (str, Path, Scenario)):
        scenarios = [scenarios]
    out = []
    for s in scenarios:
        if isinstance(s, Scenario):
            out.append(s)
            continue
        path = Path(s)
        if not path.is_file() and (SCENARIOS_DIR / path).is_file():
            path = SCENARIOS_DIR / path
        out.append(load_scenario(path, machine="arm"))
    if not out:
        raise ValueError("scenarios must name at least one scenario file")
    return out


def seed_realized(scenario: Scenario, workpiece: Workpiece) -> Realized:
    """The scenario as its own seed realizes it (the cells and streams prepared once per
    scenario, e.g. the probe's qualification, the scan arm's clearance cell)."""
    streams = Streams(scenario.seed)
    return Realized(scenario, workpiece, draw_truth(scenario, streams), streams)


def prepare(scenario: Scenario) -> EnvScenario:
    """Mesh, index, nominal cell and view geometry of a scenario (once per environment)."""
    mesh = load_workpiece_mesh(scenario)
    workpiece = Workpiece(mesh, MeshIndex(mesh))
    realized = Realized(scenario, workpiece, draw_truth(scenario, Streams(scenario.seed)),
                        Streams(scenario.seed))
    nominal = build_cell(realized, "nominal")
    s = scenario.sensor
    geometry = Geometry.of(workpiece, s.window_m, s.max_incidence_deg)
    extent = mesh.bounds[1] - mesh.bounds[0]
    return EnvScenario(scenario, workpiece, nominal, geometry, model_free_directions(workpiece),
                       float(np.linalg.norm(extent) / 2), height_field(mesh), SharpEdges(mesh.vertices, mesh.faces),
                       surface_shares(mesh.face_normals, mesh.area_faces))


def _check_options(positive: dict, nonnegative: dict, counts: dict) -> None:
    for name, v in positive.items():
        if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be a finite number > 0, got {v!r}")
    for name, v in nonnegative.items():
        if not (isinstance(v, (int, float)) and np.isfinite(v) and v >= 0):
            raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
    for name, v in counts.items():
        if not (isinstance(v, int) and not isinstance(v, bool) and v >= 1):
            raise ValueError(f"{name} must be an integer >= 1, got {v!r}")


def _sigma_range(name: str, value) -> tuple[float, float]:
    """(low, high) of a placement scatter given as a number or a (low, high) pair, both finite
    and > 0 (ValueError otherwise)."""
    pair = tuple(value) if isinstance(value, (tuple, list)) else (value, value)
    if len(pair) != 2 or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) and v > 0
                                 for v in pair) or pair[0] > pair[1]:
        raise ValueError(f"{name} must be a finite number > 0 or a pair (low, high) of them with low <= high, "
                         f"got {value!r}")
    return float(pair[0]), float(pair[1])


def _draw_sigma(rng: np.random.Generator, bounds: tuple[float, float]) -> float:
    """A placement scatter for one episode: log-uniform between the bounds (no draw for one
    value, so that a fixed scatter's episodes do not depend on the ranges' draws)."""
    low, high = bounds
    return low if low == high else float(np.exp(rng.uniform(np.log(low), np.log(high))))


def headless_gl_context():
    """The OpenGL context class to render with when no display is reachable and ``MUJOCO_GL``
    is not set: MuJoCo's EGL, else OSMesa (None: leave MuJoCo's own choice)."""
    if os.environ.get("MUJOCO_GL") or os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY") or \
            sys.platform != "linux":
        return None
    for backend in ("egl", "osmesa"):
        try:
            return importlib.import_module(f"mujoco.{backend}").GLContext
        except (ImportError, AttributeError, OSError):
            continue
    return None


def _renderer(model: mujoco.MjModel, height: int, width: int) -> mujoco.Renderer:
    """A MuJoCo renderer, on :func:`headless_gl_context` when there is no display."""
    from mujoco.rendering.classic import gl_context

    context = headless_gl_context()
    if context is None:
        return mujoco.Renderer(model, height, width)
    chosen = gl_context.GLContext
    gl_context.GLContext = context   # mujoco.Renderer reads it when it is created
    try:
        return mujoco.Renderer(model, height, width)
    finally:
        gl_context.GLContext = chosen


class ActiveLocalizationEnv(gym.Env):
    """Active localization with some sensor on the arm (module docstring); subclasses set
    ``action_size`` and implement the hooks.

    Args:
        scenarios: a scenario file, a :class:`Scenario`, or a list of them (names resolve in
            the project's ``scenarios/`` folder); each episode draws one.
        tolerance_m: the translation standard deviation that ends an episode [m].
        tolerance_deg: the rotation standard deviation that ends an episode [deg].
        max_steps: the step budget (truncation).
        time_cost_per_s: reward lost per second of motion.
        unreachable_penalty: reward lost by a measurement that finds nothing or is out of reach.
        collision_penalty: reward lost by a collision (the episode ends).
        placement_sigma_m: the fixture's placement scatter per axis [m] (the prior's standard
            deviation), or a (low, high) range each episode draws its scatter from,
            log-uniformly (a variety of clamps for training).
        placement_sigma_deg: the same for the rotations [deg].
        render_mode: None or ``"rgb_array"``; width, height: the rendered image [pixels].
        points_per_step: the most points one step adds (bounds the observation's point count).
        positive, nonnegative, counts: the subclass's own options to check, by name: numbers
            > 0 (checked after the tolerances), numbers >= 0 (before the costs) and integers
            >= 1 (after ``max_steps``).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 2}
    #: The number of values of an action (each in [-1, 1]).
    action_size: int = 0
    #: Set in ``__init__``: a box or the views' ``Discrete``; the observation's ``Dict``.
    action_space: spaces.Box | spaces.Discrete
    observation_space: spaces.Dict

    def __init__(self, scenarios, *, tolerance_m: float, tolerance_deg: float, max_steps: int,
                 time_cost_per_s: float, unreachable_penalty: float, collision_penalty: float,
                 placement_sigma_m: float | tuple[float, float], placement_sigma_deg: float | tuple[float, float],
                 render_mode: str | None, width: int, height: int, actions: str = "box", points_per_step: int = 1,
                 positive: dict | None = None, nonnegative: dict | None = None, counts: dict | None = None):
        self.placement_range_m = _sigma_range("placement_sigma_m", placement_sigma_m)
        self.placement_range_deg = _sigma_range("placement_sigma_deg", placement_sigma_deg)
        _check_options(
            {"tolerance_m": tolerance_m, "tolerance_deg": tolerance_deg, **(positive or {})},
            {**(nonnegative or {}), "time_cost_per_s": time_cost_per_s, "unreachable_penalty": unreachable_penalty,
             "collision_penalty": collision_penalty},
            {"max_steps": max_steps, **(counts or {})})
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        if actions not in ACTION_KINDS:
            raise ValueError(f"actions must be one of {', '.join(map(repr, ACTION_KINDS))}, got {actions!r}")
        self.tolerance_m = float(tolerance_m)
        self.tolerance_rad = float(np.radians(tolerance_deg))
        self.max_steps = max_steps
        self.time_cost_per_s = float(time_cost_per_s)
        self.unreachable_penalty = float(unreachable_penalty)
        self.collision_penalty = float(collision_penalty)
        # the placement scatter of the running episode (the ranges' upper ends before the first)
        self.placement_sigma_m = self.placement_range_m[1]
        self.placement_sigma_rad = float(np.radians(self.placement_range_deg[1]))
        self.render_mode = render_mode
        self.width, self.height = int(width), int(height)
        self.points_per_step = points_per_step
        try:
            self.scenarios = [self._prepare(s) for s in as_scenarios(scenarios)]
        except TwinError as exc:
            raise ValueError(str(exc)) from None
        for es in self.scenarios:
            self._check_scenario(es)
        self.actions = actions
        self.view_table = self._view_table() if actions == "views" else None
        self._view_masks = [self._view_mask(es, self.view_table) for es in self.scenarios] \
            if self.view_table is not None else None
        self.action_space = spaces.Discrete(len(self.view_table)) if self.view_table is not None else \
            spaces.Box(-1.0, 1.0, (self.action_size,), dtype=np.float32)
        self.observation_space = observation_space()
        ranges = np.array([es.nominal.model.jnt_range[:6] for es in self.scenarios])
        self.joint_low, self.joint_high = ranges[:, :, 0].min(axis=0), ranges[:, :, 1].max(axis=0)
        self.prior = prior_information(self.placement_sigma_m, self.placement_sigma_rad)
        self._renderer: mujoco.Renderer | None = None
        self._episode: dict | None = None

    @property
    def budget(self) -> int:
        """The step budget (``max_steps``): the steps-left feature counts down to it."""
        return self.max_steps

    # ------------------------------------------------------------------ hooks
    def _prepare(self, scenario: Scenario) -> EnvScenario:
        """The scenario prepared for many episodes (may raise ValueError or TwinError)."""
        return prepare(scenario)

    def _check_scenario(self, es: EnvScenario) -> None:
        """Raise ValueError, with the reason, for a scenario this environment cannot run."""

    def _view_table(self) -> np.ndarray:
        """(N, action_size) the box actions ``actions="views"`` indexes."""
        raise NotImplementedError

    def _view_mask(self, es: EnvScenario, table: np.ndarray) -> np.ndarray:
        """(N,) bool: which of ``table``'s views the arm reaches on ``es``'s part at its nominal
        pose (all, unless a subclass knows better)."""
        return np.ones(len(table), dtype=bool)

    def _start_episode(self, es: EnvScenario, realized: Realized) -> dict:
        """The episode's measuring device and per-point stores (merged into ``episode``)."""
        raise NotImplementedError

    def _measure(self, action: np.ndarray, events: dict):
        """Measure one action (clipped to [-1, 1]) in the true cell.

        Returns None when nothing moved (``events["unreachable"]`` says why), else an object
        with ``points_base`` (M, 3) the new points [m] (robot base frame), ``duration_s`` the
        motion's duration [s] and ``contacts`` (ContactRecord) the collisions found; a motion
        that measured nothing sets ``events["unreachable"]`` too (its points are not used).
        """
        raise NotImplementedError

    def _append(self, result) -> None:
        """Keep what the localization needs of ``result``'s points besides the points."""

    def _localize(self, init: np.ndarray | None) -> MapResult:
        """Localize on every point so far from ``init`` (None: the prior mean)."""
        raise NotImplementedError

    def _innovations(self, result) -> np.ndarray:
        """(M,) normalised innovations of ``result``'s points at the current estimate."""
        raise NotImplementedError

    def _point_sigma_m(self) -> float:
        """A point's noise [m] (the fit's quality is judged against it)."""
        raise NotImplementedError

    def _joints(self) -> np.ndarray:
        """(6,) the arm's true joint positions now [rad]."""
        raise NotImplementedError

    def _render_scene(self) -> tuple[Cell, np.ndarray]:
        """The true cell and its full physics state now."""
        raise NotImplementedError

    def _info_totals(self) -> dict:
        """The subclass's own episode totals for ``info``."""
        return {}

    # ------------------------------------------------------------------ episodes
    def _draw_episode(self) -> tuple[int, Realized]:
        """The index of the episode's scenario and its realization, from ``np_random``."""
        rng = self.np_random
        k = int(rng.integers(len(self.scenarios)))
        es = self.scenarios[k]
        self.placement_sigma_m = _draw_sigma(rng, self.placement_range_m)
        self.placement_sigma_rad = float(np.radians(_draw_sigma(rng, self.placement_range_deg)))
        self.prior = prior_information(self.placement_sigma_m, self.placement_sigma_rad)
        xi = np.concatenate([rng.normal(0.0, self.placement_sigma_rad, 3), rng.normal(0.0, self.placement_sigma_m, 3)])
        seed = int(rng.integers(2**31 - 1))
        sc = es.scenario
        T_true = sc.workpiece.T_world_workpiece_nominal @ exp_se3(xi)
        sc = replace(sc, seed=seed, workpiece=replace(sc.workpiece, T_world_workpiece_true=T_true))
        streams = Streams(seed)
        return k, Realized(sc, es.workpiece, draw_truth(sc, streams), streams)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        k, realized = self._draw_episode()
        es = self.scenarios[k]
        self._episode = {
            "es": es, "scenario_index": k, "realized": realized,
            "T_base_est": realized.T_base_workpiece_nominal.copy(),
            "points": np.zeros((0, 3)),
            "F": np.zeros((6, 6)), "last_gain": 0.0,
            "was_within": False, "confirmed": False,
            "steps": 0, "motion_s": 0.0, "unreachable": 0, "collisions": 0,
            "normal_counts": np.zeros(len(NORMAL_BINS)),
        }
        self._episode.update(self._start_episode(es, realized))
        return self._observation(), self._info({})

    @property
    def episode(self) -> dict:
        """The running episode's state (for policies and evaluation); reset() first."""
        if self._episode is None:
            raise RuntimeError("call reset() before step()")
        return self._episode

    # ------------------------------------------------------------------ steps
    def action_masks(self) -> np.ndarray:
        """(N,) bool: the views of ``view_table`` the arm reaches on this episode's part (at its
        nominal pose); all True for box actions."""
        if self._view_masks is None:
            return np.ones(self.action_size, dtype=bool)
        return self._view_masks[self.episode["scenario_index"]].copy()

    def _decode(self, action) -> tuple[np.ndarray, bool]:
        """The box action an action names, clipped to [-1, 1], and whether it was clipped;
        ValueError for an action of the wrong shape, type or range."""
        if self.view_table is not None:
            k = np.asarray(action)
            if k.shape not in ((), (1,)) or not np.issubdtype(k.dtype, np.integer) or \
                    not 0 <= int(k.reshape(-1)[0]) < len(self.view_table):
                raise ValueError(f"action must be one integer index of a view, 0 to {len(self.view_table) - 1}, "
                                 f"got {k.tolist()!r}")
            return self.view_table[int(k.reshape(-1)[0])].copy(), False
        n = self.action_size
        a = np.asarray(action, dtype=np.float64)
        if a.shape != (n,) or not np.all(np.isfinite(a)):
            raise ValueError(f"action must be {n} finite numbers (values outside [-1, 1] are clipped), "
                             f"got {np.asarray(action).tolist()!r}")
        return np.clip(a, -1.0, 1.0), bool(np.any(np.abs(a) > 1.0))

    def step(self, action):
        ep = self.episode
        a, clipped = self._decode(action)
        ep["steps"] += 1
        events: dict = {"clipped": clipped}
        reward = 0.0
        terminated = False
        result = self._measure(a, events)
        if result is not None:
            ep["motion_s"] += result.duration_s
            reward -= self.time_cost_per_s * result.duration_s
            if result.contacts:
                ep["collisions"] += 1
                c = result.contacts[0]
                events["collision"] = f"{c.geom} touched {c.other} at t = {c.first_t_s:.3f} s"
                reward -= self.collision_penalty
                terminated = True
            if "unreachable" not in events:
                self._confirm(result, events)
                ep["points"] = np.vstack([ep["points"], result.points_base])
                self._append(result)
                gain = self._update_estimate(events)
                self._count_normals(result.points_base)
                reward += gain
        if "unreachable" in events:
            ep["unreachable"] += 1
            ep["last_gain"] = 0.0
            reward -= self.unreachable_penalty
        within = self._within_tolerance()
        success = within and ep["confirmed"]
        ep["was_within"] = within
        terminated = terminated or success
        truncated = (not terminated) and ep["steps"] >= self.budget
        events["is_success"] = bool(success and "collision" not in events)
        return self._observation(), float(reward), bool(terminated), bool(truncated), self._info(events)

    def _within_tolerance(self) -> bool:
        """A trusted fit whose every standard deviation is within the tolerances."""
        ep = self.episode
        if "fit" not in ep or self._fit_verdict(ep["fit"]) != "ok":
            return False
        std_rot, std_trans = self._worst_std()
        return std_rot <= self.tolerance_rad and std_trans <= self.tolerance_m

    def _confirm(self, result, events: dict) -> None:
        """Whether an estimate already within the tolerances predicted this step's new points
        (RMS normalised innovation at most ``INNOVATION_GATE``): points it had not seen
        confirm it. Any later step that it fails to predict withdraws the confirmation."""
        ep = self.episode
        if not ep["was_within"] or len(result.points_base) == 0:
            ep["confirmed"] = False
            return
        z = self._innovations(result)
        rms = float(np.sqrt(np.mean(z**2)))
        events["innovation_rms"] = rms
        ep["confirmed"] = rms <= INNOVATION_GATE

    def _update_estimate(self, events: dict) -> float:
        """Re-localize on every point so far (maximum a posteriori with the placement prior,
        from the current estimate); keep the points' information at the estimate; return the
        information gain."""
        ep = self.episode
        res = self._localize(ep["T_base_est"])
        if self._fit_verdict(res) != "ok":
            # the last estimate slid along directions the earlier points left weak: start over
            # from the prior mean and keep the better of the two
            again = self._localize(None)
            if again.objective < res.objective:
                res = again
        ep["T_base_est"] = res.T_world_workpiece
        ep["fit"] = res
        events["localization"] = self._fit_verdict(res)
        before = log_det(self.prior + ep["F"])
        ep["F"] = res.information
        gain = log_det(self.prior + res.information) - before
        ep["last_gain"] = gain
        return gain

    def _count_normals(self, points_base: np.ndarray) -> None:
        """Count new points by the normal bin of their nearest model face at the estimate."""
        ep = self.episode
        if len(points_base) == 0:
            return
        T_wp_base = inv_pose(ep["T_base_est"])
        cp = ep["es"].workpiece.index.query(points_base @ T_wp_base[:3, :3].T + T_wp_base[:3, 3])
        bins = normal_bins(ep["es"].workpiece.mesh.face_normals[cp.face])
        ep["normal_counts"] += np.bincount(bins, minlength=len(NORMAL_BINS))

    def edge_band_m(self) -> float:
        """How near a sharp edge a point may lie and still enter the fit [m] (EDGE_BAND_SIGMAS)."""
        std_rot, std_trans = self._worst_std()
        return max(EDGE_BAND_SIGMAS * (std_trans + self.episode["es"].length_m * std_rot), EDGE_BAND_MIN_M)

    def _fit_verdict(self, res: MapResult) -> str:
        """"ok", or why the estimate cannot be trusted whatever its information says."""
        ep = self.episode
        sigma = self._point_sigma_m()
        if len(ep["points"]) == 0:
            return "no points yet"
        if not res.converged:
            return f"not converged in {res.iterations} iterations"
        usable = int(len(ep["points"]) - res.near_edge.sum())
        if usable < 6:
            return f"only {usable} points away from the model's sharp edges"
        poor = poor_fit_reason(res.rmse_m, int(res.inliers.sum()), usable, ep["es"].workpiece.index.extent, sigma,
                               np.nan)
        if poor is not None:
            return f"poor fit: {poor}"
        shed = 1.0 - res.inliers.sum() / usable
        if shed > MAX_OUTLIER_FRACTION:
            return (f"{shed:.1%} of the points are outliers (more than {MAX_OUTLIER_FRACTION:.0%}): a minimum that "
                    f"sheds the points it cannot fit")
        if res.prior_mahalanobis > PRIOR_MAHALANOBIS_MAX:
            return (f"the estimate lies {res.prior_mahalanobis:.1f} prior sigmas from the nominal pose "
                    f"(more than {PRIOR_MAHALANOBIS_MAX:g}): a wrong minimum, or a part placed off its fixture")
        return "ok"

    def _worst_std(self) -> tuple[float, float]:
        ep = self.episode
        return worst_std(self.prior + ep["F"], ep["es"].free_directions, ep["es"].length_m)

    # ------------------------------------------------------------------ observation
    def _observation(self) -> dict:
        """The observation (:mod:`twin.env.observation`)."""
        ep = self.episode
        prior_std = np.array([self.placement_sigma_rad] * 3 + [self.placement_sigma_m] * 3)
        tolerance = np.array([self.tolerance_rad] * 3 + [self.tolerance_m] * 3)
        xi = log_se3(inv_pose(ep["realized"].T_base_workpiece_nominal) @ ep["T_base_est"])
        std, corr = covariance_features(np.linalg.inv(self.prior + ep["F"]), prior_std, tolerance)
        worst = scaled_std(np.array(self._worst_std()), prior_std[[0, 3]], tolerance[[0, 3]])
        most_points = self.budget * self.points_per_step
        progress = [1.0 - ep["steps"] / self.budget, max(np.tanh(ep["last_gain"] / GAIN_SCALE_NATS), 0.0),
                    np.log1p(len(ep["points"])) / np.log1p(most_points)]
        return as_float32({
            "pose": np.tanh(xi / (POSE_SIGMAS * prior_std)), "std": std, "correlation": corr, "worst_std": worst,
            "coverage": coverage(ep["normal_counts"]), "surface": ep["es"].surface,
            "joints": scaled_joints(self._joints(), self.joint_low, self.joint_high), "progress": progress})

    def _info(self, events: dict) -> dict:
        """What happened this step, the episode's totals and its errors against the truth
        (for evaluation: not part of the observation)."""
        ep = self.episode
        err = pose_errors(ep["T_base_est"], ep["realized"])
        std_rot, std_trans = self._worst_std()
        info = {
            "scenario": ep["realized"].scenario.name,
            "steps": ep["steps"], "motion_time_s": ep["motion_s"], "points": int(len(ep["points"])),
            "unreachable_total": ep["unreachable"], "collisions_total": ep["collisions"],
            "std_rotation_deg": float(np.degrees(std_rot)), "std_translation_m": std_trans,
            "rotation_error_deg": float(np.degrees(err.rotation_rad)), "translation_error_m": err.translation_m,
        }
        info.update(self._info_totals())
        if self._view_masks is not None:
            info["action_mask"] = self.action_masks()
        info.update(events)
        return info

    # ------------------------------------------------------------------ rendering
    def render(self):
        if self.render_mode != "rgb_array":
            return None
        ep = self.episode
        cell, state = self._render_scene()
        if self._renderer is None or self._renderer_model is not cell.model:
            if self._renderer is not None:
                self._renderer.close()
            self._renderer = _renderer(cell.model, self.height, self.width)
            self._renderer_model = cell.model
        mujoco.mj_setState(cell.model, cell.data, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        mujoco.mj_forward(cell.model, cell.data)
        camera = mujoco.MjvCamera()
        camera.lookat[:] = cell.T_world_workpiece[:3, 3]
        camera.distance = RENDER_DISTANCE_PARTS * ep["es"].length_m + RENDER_DISTANCE_M
        # from the far side of the part, looking towards the robot: the arm reaches over the
        # part from behind it instead of standing between the camera and the part
        to_base = cell.T_world_base[:3, 3] - cell.T_world_workpiece[:3, 3]
        camera.azimuth = float(np.degrees(np.arctan2(to_base[1], to_base[0])))
        camera.elevation = RENDER_ELEVATION_DEG
        option = mujoco.MjvOption()
        option.geomgroup[:] = 1   # the workpiece and fixtures sit in groups the default hides
        option.flags[mujoco.mjtVisFlag.mjVIS_RANGEFINDER] = 0   # its marker would hide the part
        self._renderer.update_scene(cell.data, camera, scene_option=option)
        scene = self._renderer.scene
        for g in scene.geoms[: scene.ngeom]:   # the arm see-through: it must not hide the part
            if g.objtype == mujoco.mjtObj.mjOBJ_GEOM and cell.model.geom_group[g.objid] == GROUP_ARM:
                g.rgba[3] = RENDER_ARM_ALPHA
        pts = ep["points"] @ cell.T_world_base[:3, :3].T + cell.T_world_base[:3, 3]
        step = max(1, -(-len(pts) // max(scene.maxgeom - scene.ngeom, 1)))
        for p in pts[::step]:
            if scene.ngeom >= scene.maxgeom:
                break
            mujoco.mjv_initGeom(scene.geoms[scene.ngeom], mujoco.mjtGeom.mjGEOM_SPHERE, [0.0015, 0, 0], p,
                                np.eye(3).ravel(), np.array([0.1, 0.5, 1.0, 1.0], dtype=np.float32))
            scene.ngeom += 1
        return self._renderer.render()

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

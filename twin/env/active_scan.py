"""``twin/ActiveScan-v0``: choose the next laser scan segment to pin the part down fastest.

Each step the agent names a short scan segment (:mod:`twin.env.views`); the environment
solves the joints with mink, simulates the motion and the line in the true cell at 1 ms with
the scenario's sensor model and arm (:mod:`twin.env.arm`), adds the points and re-localizes
(Hong-Tan, from the current estimate). The estimate moves only when the points fix every
direction the part's shape can fix (before that, localization would wander along the free
directions); the information is counted from the first segment on.

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
and of any translation under ``tolerance_m`` (directions the shape cannot fix excepted), or
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

from dataclasses import dataclass, replace
from pathlib import Path

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces

from algorithms.geometry.edges import SharpEdges
from algorithms.geometry.kinematics import ur_inverse
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import exp_se3, inv_pose, log_se3
from algorithms.registration.bayes import MapResult, localize_map, normalized_innovations
from algorithms.registration.fit_check import poor_fit_reason
from twin.cell import Cell, build_cell
from twin.env.arm import ScanArm, build_scan_cell
from twin.env.information import (
    log_det,
    log_eigenvalues,
    model_free_directions,
    prior_information,
    worst_std,
)
from twin.env.views import ACTION_SIZE, Geometry, View, decode_action, segment_centre, sensor_line
from twin.errors import TwinError
from twin.evaluate import pose_errors
from twin.realize import Realized, Streams, Workpiece, draw_truth, load_workpiece_mesh
from twin.replay import HeightField, height_field
from twin.robot import UR5E_DH
from twin.scenario import NoiseSpec, Scenario, SensorSpec, load_scenario

SCENARIOS_DIR = Path(__file__).resolve().parents[2] / "scenarios"
DEFAULT_SCENARIOS = ("bracket.toml",)
OBSERVATION_LAYOUT = {"pose": slice(0, 6), "log_eigenvalues": slice(6, 12), "points": slice(12, 13),
                      "last_gain": slice(13, 14), "joints": slice(14, 20)}
OBSERVATION_SIZE = 20
#: An estimate farther than this from the nominal pose, in prior standard deviations
#: (sqrt of the Mahalanobis form; chi-square 6 DOF: 99.9 % below 4.74), is not trusted.
PRIOR_MAHALANOBIS_MAX = 4.74
#: The RMS normalised innovation of a new segment under which it confirms the estimate.
INNOVATION_GATE = 3.0
#: The linearity error is estimated as one offset per bin of readings this wide [m] (the
#: IL-065's +/-10 um curve over its 50 mm window changes by about 1.3 um across 1 mm).
LINEARITY_BIN_M = 0.001
#: Points nearer a sharp edge of the model than this many standard deviations of the
#: estimate's position (at the part's size), and at least EDGE_BAND_MIN_M, are left out of
#: the fit: their face is unsure (algorithms.geometry.edges).
EDGE_BAND_SIGMAS = 3.0
EDGE_BAND_MIN_M = 20e-6
#: A fit that calls more of the points outliers is not trusted (the cell's sensor model
#: gives no outliers on the part itself: its only misses are invalid readings).
MAX_OUTLIER_FRACTION = 0.01
#: Views tried at construction to check that the arm reaches the part at all.
_CHECK_VIEWS = [(az, el) for el in (90.0, 60.0, 35.0) for az in range(-180, 180, 30)]


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


def _as_scenarios(scenarios) -> list[Scenario]:
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
        out.append(load_scenario(path))
    if not out:
        raise ValueError("scenarios must name at least one scenario file")
    return out


def prepare(scenario: Scenario) -> EnvScenario:
    """Mesh, index, nominal cell and view geometry of a scenario (once per environment)."""
    mesh = load_workpiece_mesh(scenario)
    workpiece = Workpiece(mesh, MeshIndex(mesh))
    realized = Realized(scenario, workpiece, draw_truth(scenario, Streams(scenario.seed).generator("kinematics")),
                        Streams(scenario.seed))
    nominal = build_cell(realized, "nominal")
    s = scenario.sensor
    geometry = Geometry.of(workpiece, s.window_m, s.max_incidence_deg)
    extent = mesh.bounds[1] - mesh.bounds[0]
    return EnvScenario(scenario, workpiece, nominal, geometry, model_free_directions(workpiece),
                       float(np.linalg.norm(extent) / 2), height_field(mesh), SharpEdges(mesh.vertices, mesh.faces))


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


class ActiveScanEnv(gym.Env):
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

    metadata = {"render_modes": ["rgb_array"], "render_fps": 2}

    def __init__(self, scenarios=DEFAULT_SCENARIOS, tolerance_m: float = 10e-6, tolerance_deg: float = 0.01,
                 max_steps: int = 30, segment_length_m: float = 0.03, retract_m: float = 0.03,
                 time_cost_per_s: float = 0.5, unreachable_penalty: float = 1.0, collision_penalty: float = 10.0,
                 placement_sigma_m: float = 1e-3, placement_sigma_deg: float = 0.5, points_per_segment: int = 100,
                 render_mode: str | None = None, width: int = 640, height: int = 480):
        for name, v in (("tolerance_m", tolerance_m), ("tolerance_deg", tolerance_deg),
                        ("segment_length_m", segment_length_m), ("placement_sigma_m", placement_sigma_m),
                        ("placement_sigma_deg", placement_sigma_deg)):
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {v!r}")
        for name, v in (("retract_m", retract_m), ("time_cost_per_s", time_cost_per_s),
                        ("unreachable_penalty", unreachable_penalty), ("collision_penalty", collision_penalty)):
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
        for name, v in (("max_steps", max_steps), ("points_per_segment", points_per_segment)):
            if not (isinstance(v, int) and not isinstance(v, bool) and v >= 1):
                raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
        self.points_per_segment = points_per_segment
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.tolerance_m = float(tolerance_m)
        self.tolerance_rad = float(np.radians(tolerance_deg))
        self.max_steps = max_steps
        self.segment_length_m = float(segment_length_m)
        self.retract_m = float(retract_m)
        self.time_cost_per_s = float(time_cost_per_s)
        self.unreachable_penalty = float(unreachable_penalty)
        self.collision_penalty = float(collision_penalty)
        self.placement_sigma_m = float(placement_sigma_m)
        self.placement_sigma_rad = float(np.radians(placement_sigma_deg))
        self.render_mode = render_mode
        self.width, self.height = int(width), int(height)
        try:
            self.scenarios = [prepare(s) for s in _as_scenarios(scenarios)]
        except TwinError as exc:
            raise ValueError(str(exc)) from None
        for es in self.scenarios:
            if es.scenario.sensor.kind != "point":
                raise ValueError(f"scenario {es.scenario.name!r}: ActiveScan-v0 takes a laser point sensor "
                                 f"(sensor.kind = 'point'), got {es.scenario.sensor.kind!r}")
            if _reachable_views(es) == 0:
                raise ValueError(f"scenario {es.scenario.name!r}: the arm reaches none of {len(_CHECK_VIEWS)} "
                                 f"views of the part (elevations 90, 60 and 35 deg, every 30 deg of azimuth); "
                                 f"move the part or the robot base")
        self.action_space = spaces.Box(-1.0, 1.0, (ACTION_SIZE,), dtype=np.float64)
        low = np.full(OBSERVATION_SIZE, -np.inf)
        high = np.full(OBSERVATION_SIZE, np.inf)
        low[OBSERVATION_LAYOUT["points"]] = 0.0
        self.observation_space = spaces.Box(low, high, (OBSERVATION_SIZE,), dtype=np.float64)
        self.prior = prior_information(self.placement_sigma_m, self.placement_sigma_rad)
        self._renderer: mujoco.Renderer | None = None
        self._episode: dict | None = None

    # ------------------------------------------------------------------ episodes
    def _draw_episode(self) -> tuple[EnvScenario, Realized]:
        rng = self.np_random
        es = self.scenarios[int(rng.integers(len(self.scenarios)))]
        xi = np.concatenate([rng.normal(0.0, self.placement_sigma_rad, 3), rng.normal(0.0, self.placement_sigma_m, 3)])
        seed = int(rng.integers(2**31 - 1))
        sc = es.scenario
        T_true = sc.workpiece.T_world_workpiece_nominal @ exp_se3(xi)
        sc = replace(sc, seed=seed, workpiece=replace(sc.workpiece, T_world_workpiece_true=T_true))
        streams = Streams(seed)
        return es, Realized(sc, es.workpiece, draw_truth(sc, streams.generator("kinematics")), streams)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        es, realized = self._draw_episode()
        true_cell = build_scan_cell(realized, es.hfield)
        arm = ScanArm(realized, es.nominal, true_cell, realized.scenario.scan.speed_m_s, self.retract_m)
        self._episode = {
            "es": es, "realized": realized, "arm": arm,
            "T_base_est": realized.T_base_workpiece_nominal.copy(),
            "points": np.zeros((0, 3)), "readings": np.zeros(0), "beams": np.zeros((0, 3)),
            "F": np.zeros((6, 6)), "last_gain": 0.0,
            "was_within": False, "confirmed": False,
            "steps": 0, "motion_s": 0.0, "unreachable": 0, "collisions": 0,
        }
        return self._observation(), self._info({})

    @property
    def episode(self) -> dict:
        """The running episode's state (for policies and evaluation); reset() first."""
        if self._episode is None:
            raise RuntimeError("call reset() before step()")
        return self._episode

    # ------------------------------------------------------------------ steps
    def step(self, action):
        ep = self.episode
        a = np.asarray(action, dtype=np.float64)
        if a.shape != (ACTION_SIZE,) or not np.all(np.isfinite(a)):
            raise ValueError(f"action must be {ACTION_SIZE} finite numbers (values outside [-1, 1] are clipped), "
                             f"got {np.asarray(action).tolist()!r}")
        clipped = bool(np.any(np.abs(a) > 1.0))
        a = np.clip(a, -1.0, 1.0)
        es, realized, arm = ep["es"], ep["realized"], ep["arm"]
        ep["steps"] += 1
        view = decode_action(a, es.geometry)
        T_world_est = realized.scenario.T_world_base @ ep["T_base_est"]
        centre = segment_centre(view, T_world_est, es.workpiece, es.geometry)
        events: dict = {"clipped": clipped}
        reward = 0.0
        terminated = False
        if centre is None:
            events["unreachable"] = "the beam misses the part"
        else:
            motion = arm.plan(*sensor_line(view, centre, self.segment_length_m))
            if isinstance(motion, str):
                events["unreachable"] = motion
            else:
                result = arm.execute(motion)
                ep["motion_s"] += result.duration_s
                reward -= self.time_cost_per_s * result.duration_s
                events["segment_points"] = len(result.points_base)
                events["duration_s"] = result.duration_s
                if result.contacts:
                    ep["collisions"] += 1
                    c = result.contacts[0]
                    events["collision"] = f"{c.geom} touched {c.other} at t = {c.first_t_s:.3f} s"
                    reward -= self.collision_penalty
                    terminated = True
                result = result.decimated(self.points_per_segment)
                self._confirm(result, events)
                ep["points"] = np.vstack([ep["points"], result.points_base])
                ep["readings"] = np.concatenate([ep["readings"], result.readings_m])
                ep["beams"] = np.vstack([ep["beams"], np.repeat(result.beam_base[None], len(result.points_base), 0)])
                gain = self._update_estimate(events)
                reward += gain
        if "unreachable" in events:
            ep["unreachable"] += 1
            ep["last_gain"] = 0.0
            reward -= self.unreachable_penalty
        within = self._within_tolerance()
        success = within and ep["confirmed"]
        ep["was_within"] = within
        terminated = terminated or success
        truncated = (not terminated) and ep["steps"] >= self.max_steps
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
        """Whether an estimate already within the tolerances predicted this segment's new points
        (RMS normalised innovation at most ``INNOVATION_GATE``): a segment it had not seen
        confirms it. Any later segment that it fails to predict withdraws the confirmation."""
        ep = self.episode
        if not ep["was_within"] or len(result.points_base) == 0:
            ep["confirmed"] = False
            return
        sensor, noise = ep["realized"].scenario.sensor, ep["realized"].scenario.noise
        z = normalized_innovations(result.points_base, np.repeat(result.beam_base[None], len(result.points_base), 0),
                                   ep["es"].workpiece.index, ep["T_base_est"], ep["fit"].covariance,
                                   point_sigma_m(sensor, noise), bias_sigma_m(sensor, noise), noise.incidence)
        rms = float(np.sqrt(np.mean(z**2)))
        events["innovation_rms"] = rms
        ep["confirmed"] = rms <= INNOVATION_GATE

    def _update_estimate(self, events: dict) -> float:
        """Re-localize on every point so far (maximum a posteriori with the placement prior and
        one linearity offset per line, from the current estimate); keep the points' information
        at the estimate; return the information gain."""
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

    def _localize(self, init: np.ndarray | None) -> MapResult:
        ep = self.episode
        sensor, noise = ep["realized"].scenario.sensor, ep["realized"].scenario.noise
        bins = np.floor((ep["readings"] - sensor.window_m[0]) / LINEARITY_BIN_M).astype(np.int64)
        std_rot, std_trans = self._worst_std()
        band = max(EDGE_BAND_SIGMAS * (std_trans + ep["es"].length_m * std_rot), EDGE_BAND_MIN_M)
        return localize_map(ep["points"], ep["es"].workpiece.index, ep["realized"].T_base_workpiece_nominal,
                            self.prior, point_sigma_m(sensor, noise), init=init, groups=np.clip(bins, 0, None),
                            beams=ep["beams"], bias_sigma_m=bias_sigma_m(sensor, noise),
                            incidence_noise=noise.incidence, edges=ep["es"].edges, edge_band_m=band)

    def _fit_verdict(self, res: MapResult) -> str:
        """"ok", or why the estimate cannot be trusted whatever its information says."""
        ep = self.episode
        sigma = point_sigma_m(ep["realized"].scenario.sensor, ep["realized"].scenario.noise)
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
    def _observation(self) -> np.ndarray:
        ep = self.episode
        obs = np.empty(OBSERVATION_SIZE)
        obs[OBSERVATION_LAYOUT["pose"]] = log_se3(inv_pose(ep["realized"].T_base_workpiece_nominal) @ ep["T_base_est"])
        obs[OBSERVATION_LAYOUT["log_eigenvalues"]] = log_eigenvalues(self.prior + ep["F"], ep["es"].length_m)
        obs[OBSERVATION_LAYOUT["points"]] = len(ep["points"])
        obs[OBSERVATION_LAYOUT["last_gain"]] = ep["last_gain"]
        obs[OBSERVATION_LAYOUT["joints"]] = ep["arm"].joints()
        return obs

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
        info.update(events)
        return info

    # ------------------------------------------------------------------ rendering
    def render(self):
        if self.render_mode != "rgb_array":
            return None
        ep = self.episode
        cell = ep["arm"].cell
        if self._renderer is None or self._renderer_model is not cell.model:
            if self._renderer is not None:
                self._renderer.close()
            self._renderer = mujoco.Renderer(cell.model, self.height, self.width)
            self._renderer_model = cell.model
        mujoco.mj_setState(cell.model, cell.data, ep["arm"].state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        mujoco.mj_forward(cell.model, cell.data)
        camera = mujoco.MjvCamera()
        camera.lookat[:] = cell.T_world_workpiece[:3, 3]
        camera.distance, camera.azimuth, camera.elevation = 1.1, 200.0, -30.0
        self._renderer.update_scene(cell.data, camera)
        scene = self._renderer.scene
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

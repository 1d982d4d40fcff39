"""Baseline policies for ``twin/ActiveScan-v0``: random, raster and greedy information gain.

Each policy is called once per step with the observation and returns an action; ``reset``
is called after every ``env.reset``. The raster and greedy policies read the running
episode's state from the environment (``env.unwrapped.episode``): the scenario's scan plan,
the CAD model, the current estimate and its information, the arm's joints. Never the truth.
"""

from __future__ import annotations

import numpy as np

from algorithms.geometry.kinematics import ur_inverse
from algorithms.geometry.se3 import inv_pose
from twin.env.active_scan import LINEARITY_BIN_M, ActiveScanEnv, bias_sigma_m, point_sigma_m
from twin.env.information import log_det, segment_information
from twin.env.views import ACTION_SIZE, View, encode_view, predict_segments, sensor_line
from twin.plan import plan_scan
from twin.robot import UR5E_DH
from twin.trajectory import joint_move

#: The greedy policy's candidate views: elevations [deg] and azimuths every AZIMUTH_STEP_DEG
#: (four azimuths looking straight down), aim offsets and line directions per view.
GREEDY_ELEVATIONS_DEG = (90.0, 65.0, 40.0)
GREEDY_AZIMUTH_STEP_DEG = 30.0
GREEDY_AIM_OFFSETS = (-0.5, 0.0, 0.5)
GREEDY_LINE_ACTIONS = (-1.0, 0.0)   # 0 and 90 deg from the azimuth tangent


class RandomPolicy:
    """Uniform actions from its own seeded stream."""

    name = "random"

    def __init__(self, env, seed: int = 0):
        self.rng = np.random.default_rng(seed)

    def reset(self) -> None:
        pass

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        return self.rng.uniform(-1.0, 1.0, ACTION_SIZE)


class RasterPolicy:
    """The scenario's own scan plan (what ``twin scan`` would do), its lines cut into
    segments of the environment's length, in the plan's order (then again from the start)."""

    name = "raster"

    def __init__(self, env, seed: int = 0):
        self.env: ActiveScanEnv = env.unwrapped
        self.actions: list[np.ndarray] = []
        self.k = 0
        self._plans: dict[str, list] = {}

    def reset(self) -> None:
        ep = self.env.episode
        es = ep["es"]
        name = es.scenario.name
        if name not in self._plans:
            self._plans[name] = _raster_segments(es, self.env.segment_length_m)
        T_world_nominal = es.scenario.workpiece.T_world_workpiece_nominal
        self.actions = [encode_view(-Tc[:3, 2], Tc[:3, 3], w, es.scenario.sensor.reference_m, T_world_nominal,
                                    es.geometry) for Tc, w in self._plans[name]]
        self.k = 0

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        a = self.actions[self.k % len(self.actions)]
        self.k += 1
        return a


def _raster_segments(es, length_m: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """(sensor pose at the segment's centre, travel direction) of every segment of the plan."""
    plan = plan_scan(es.nominal)
    out = []
    for line in np.unique(plan.line[plan.line >= 0]):
        T = plan.T_world_sensor[plan.line == line]
        p = T[:, :3, 3]
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
        n = max(1, int(round(s[-1] / length_m)))
        for k in range(n):
            i = int(np.searchsorted(s, (k + 0.5) * s[-1] / n))
            i = min(i, len(T) - 1)
            w = p[-1] - p[0]
            out.append((T[i], w / max(np.linalg.norm(w), 1e-12)))
    return out


class GreedyInformationPolicy:
    """The candidate view with the best predicted information gain less the cost of its
    motion time (the reward the environment will pay), predicted on the CAD model at the
    current estimate (:func:`twin.env.views.predict_segments`,
    :func:`twin.env.information.segment_information`); views the closed-form inverse
    kinematics cannot reach within the joint ranges with the links off the table are skipped."""

    name = "greedy"

    def __init__(self, env, seed: int = 0):
        self.env: ActiveScanEnv = env.unwrapped
        self.candidates = _candidate_actions()

    def reset(self) -> None:
        pass

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        scores = self.scores()
        return self.candidates[int(np.argmax(scores))].copy()

    def scores(self) -> np.ndarray:
        """(C,) predicted reward of every candidate (-inf where out of reach or blind)."""
        env = self.env
        ep = env.episode
        es, sc, arm = ep["es"], ep["realized"].scenario, ep["arm"]
        T_world_est = sc.T_world_base @ ep["T_base_est"]
        R_wp_world = T_world_est[:3, :3].T
        sigma, bias, inc = point_sigma_m(sc.sensor, sc.noise), bias_sigma_m(sc.sensor, sc.noise), sc.noise.incidence
        base = log_det(env.prior + ep["F"])
        scores = np.full(len(self.candidates), -np.inf)
        for idx in _by_direction(self.candidates):
            views = [_decode(self.candidates[i], es) for i in idx]
            centres = _centres(views, T_world_est, es)
            ends, keep = [], []
            for i, v, c in zip(idx, views, centres, strict=True):
                if c is not None:
                    ends.append(sensor_line(v, c, env.segment_length_m))
                    keep.append(i)
            if not keep:
                continue
            time_s = [self._motion_time(Ta, Tb, arm) for Ta, Tb in ends]
            preds = predict_segments(ends, T_world_est, es.workpiece, es.geometry)
            beam_wp = R_wp_world @ ends[0][0][:3, 2]
            for i, t, pr in zip(keep, time_s, preds, strict=True):
                if t is None or len(pr.feet_wp) == 0:
                    continue
                normals = es.workpiece.index.smooth_normals(pr.faces, pr.feet_wp)
                dF = segment_information(pr.feet_wp, normals, beam_wp, pr.readings_m, sigma, bias, inc,
                                         LINEARITY_BIN_M)
                scores[i] = log_det(env.prior + ep["F"] + dF) - base - env.time_cost_per_s * t
        return scores

    def _motion_time(self, T_start: np.ndarray, T_end: np.ndarray, arm) -> float | None:
        """Predicted seconds of the motion to scan a line (retract and transit by the nearest
        closed-form solution, the line at scan speed), or None when out of reach."""
        T_in = T_start.copy()
        T_in[:3, 3] -= arm.retract_m * T_start[:3, 2]
        q = []
        for T in (T_in, T_end):
            T_base_flange = arm.T_base_world @ T @ arm.T_sensor_flange
            sol = ur_inverse(T_base_flange, UR5E_DH)
            seeds = sol.q[0][sol.valid[0]]
            lo, hi = arm.joint_range[:, 0], arm.joint_range[:, 1]
            seeds = seeds[np.all((seeds >= lo) & (seeds <= hi), axis=1)]
            if not len(seeds):
                return None
            best = seeds[np.argmin(np.linalg.norm(seeds - arm.q, axis=1))]
            if arm.table.nearest(best) is not None:
                return None
            q.append(best)
        transit = len(joint_move(arm.q, q[0], 0.01)[0]) * 0.01
        length = float(np.linalg.norm(T_end[:3, 3] - T_start[:3, 3]))
        v = arm.speed_m_s
        return transit + length / v + v / 0.5 + 2 * arm.retract_m / 0.1


def _candidate_actions() -> np.ndarray:
    el_min = 20.0
    out = []
    for el in GREEDY_ELEVATIONS_DEG:
        a1 = 2 * (el - el_min) / (90.0 - el_min) - 1
        azimuths = np.arange(-180.0, 180.0, 90.0 if el == 90.0 else GREEDY_AZIMUTH_STEP_DEG)
        for az in azimuths:
            for line in GREEDY_LINE_ACTIONS:
                for o1 in GREEDY_AIM_OFFSETS:
                    for o2 in GREEDY_AIM_OFFSETS:
                        out.append([az / 180.0, a1, 0.0, line, o1, o2])
    return np.array(out)


def _by_direction(candidates: np.ndarray) -> list[np.ndarray]:
    """Candidate indices grouped by view direction and line direction (one ray cast each)."""
    _, inverse = np.unique(candidates[:, [0, 1, 3]], axis=0, return_inverse=True)
    return [np.flatnonzero(inverse == k) for k in range(inverse.max() + 1)]


def _decode(action: np.ndarray, es) -> View:
    from twin.env.views import decode_action

    return decode_action(action, es.geometry)


def _centres(views: list[View], T_world_workpiece: np.ndarray, es) -> list:
    """Where each view's beam meets the model (one ray cast for views of one direction)."""
    from algorithms.geometry.raycast import raycast_parallel

    u, e1, e2 = views[0].basis()
    c = T_world_workpiece[:3, :3] @ es.geometry.centre_wp + T_world_workpiece[:3, 3]
    aims = np.array([c + v.aim_offset_m[0] * e1 + v.aim_offset_m[1] * e2 for v in views])
    T_wp_world = inv_pose(T_world_workpiece)
    o = (aims + 2.0 * es.geometry.radius_m * u) @ T_wp_world[:3, :3].T + T_wp_world[:3, 3]
    hit, p, _ = raycast_parallel(es.workpiece.mesh.vertices, es.workpiece.mesh.faces, o, T_wp_world[:3, :3] @ -u)
    pw = p @ T_world_workpiece[:3, :3].T + T_world_workpiece[:3, 3]
    return [pw[k] if hit[k] else None for k in range(len(views))]


POLICIES = {"random": RandomPolicy, "raster": RasterPolicy, "greedy": GreedyInformationPolicy}

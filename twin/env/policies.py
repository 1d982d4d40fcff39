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
from twin.env.views import ACTION_SIZE, View, decode_action, encode_view, predict_segments, sensor_line
from twin.plan import ACCELERATION_M_S2, plan_scan
from twin.robot import UR5E_DH
from twin.trajectory import joint_move

#: The greedy policy's candidate views: elevations [deg] and azimuths every AZIMUTH_STEP_DEG
#: (four azimuths looking straight down), aim offsets and line directions per view.
GREEDY_ELEVATIONS_DEG = (90.0, 65.0, 40.0)
GREEDY_AZIMUTH_STEP_DEG = 30.0
GREEDY_AIM_OFFSETS = (-0.5, 0.0, 0.5)
GREEDY_LINE_ACTIONS = (-1.0, 0.0)   # 0 and 90 deg from the azimuth tangent
#: A candidate whose segment gained less than this fraction of its predicted information is
#: not chosen again in the episode.
GAIN_SHORTFALL = 0.1


class RandomPolicy:
    """Uniform actions from its own seeded stream."""

    name = "random"

    def __init__(self, env, seed: int = 0):
        self.rng = np.random.default_rng(seed)

    def reset(self) -> None:
        pass

    def __call__(self, observation: dict) -> np.ndarray:
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

    def __call__(self, observation: dict) -> np.ndarray:
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
    kinematics cannot reach within the joint ranges, or only with a link near the table or the
    part, are passed over, and so are those that measured nothing earlier in the episode. The
    motion time is an estimate (the arm's retract and approach legs are joint moves, taken here
    at scan speed)."""

    name = "greedy"

    def __init__(self, env, seed: int = 0):
        self.env: ActiveScanEnv = env.unwrapped
        self.candidates = _candidate_actions()
        self.reset()

    def reset(self) -> None:
        # candidates that measured nothing this episode (out of reach, blind) or gained far
        # less than predicted: their score would hardly change, and they would be chosen again
        # and again
        self.failed: set[int] = set()
        self.last: tuple[int, int, float] | None = None   # (candidate, points before it, predicted gain)

    def __call__(self, observation: dict) -> np.ndarray:
        ep = self.env.episode
        points = len(ep["points"])
        if self.last is not None and (points == self.last[1] or ep["last_gain"] < GAIN_SHORTFALL * self.last[2]):
            self.failed.add(self.last[0])
        scores, q, gain = self.scores()
        scores[list(self.failed)] = -np.inf
        clearance = self.env.episode["arm"].clearance
        best = int(np.argmax(scores))
        for i in np.argsort(-scores):
            if not np.isfinite(scores[i]):
                break
            if clearance.nearest(q[i, 0]) is None and clearance.nearest(q[i, 1]) is None:
                best = int(i)
                break
        self.last = (best, points, float(gain[best]))
        return self.candidates[best].copy()

    def scores(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(C,) predicted reward of every candidate (-inf where out of reach or blind),
        (C, 2, 6) the joints of the nearest closed-form solutions at its approach and end, and
        (C,) the predicted information gain [nats]. Predicted points within the environment's
        edge band of a sharp edge are left out, as the fit will leave them out."""
        env = self.env
        ep = env.episode
        es, sc, arm = ep["es"], ep["realized"].scenario, ep["arm"]
        T_world_est = sc.T_world_base @ ep["T_base_est"]
        R_wp_world = T_world_est[:3, :3].T
        sigma, bias, inc = point_sigma_m(sc.sensor, sc.noise), bias_sigma_m(sc.sensor, sc.noise), sc.noise.incidence
        base = log_det(env.prior + ep["F"])
        band_m = env.edge_band_m()
        n = len(self.candidates)
        gain = np.full(n, -np.inf)
        ends = np.zeros((n, 2, 4, 4))
        for idx in _by_direction(self.candidates):
            views = [decode_action(self.candidates[i], es.geometry) for i in idx]
            centres = _centres(views, T_world_est, es)
            keep = [(i, v, c) for i, v, c in zip(idx, views, centres, strict=True) if c is not None]
            if not keep:
                continue
            lines = [sensor_line(v, c, env.segment_length_m) for _, v, c in keep]
            preds = predict_segments(lines, T_world_est, es.workpiece, es.geometry)
            beam_wp = R_wp_world @ lines[0][0][:3, 2]
            for (i, _, _), line, pr in zip(keep, lines, preds, strict=True):
                ends[i] = line
                usable = es.edges.distance(pr.feet_wp) > band_m
                if usable.any():
                    feet = pr.feet_wp[usable]
                    normals = es.workpiece.index.smooth_normals(pr.faces[usable], feet)
                    dF = segment_information(feet, normals, beam_wp, pr.readings_m[usable], sigma, bias, inc,
                                             LINEARITY_BIN_M)
                    gain[i] = log_det(env.prior + ep["F"] + dF) - base
        time_s, q = _motion_times(ends, np.isfinite(gain), arm)
        return gain - env.time_cost_per_s * time_s, q, gain


def _motion_times(ends: np.ndarray, wanted: np.ndarray, arm) -> tuple[np.ndarray, np.ndarray]:
    """Predicted seconds of each motion (retract and transit by the nearest closed-form
    solution within the joint ranges, the line at scan speed; inf out of reach) and the
    joints at its approach and end, for the ``wanted`` candidates of ``ends`` (C, 2, 4, 4)."""
    n = len(ends)
    time_s = np.full(n, np.inf)
    q = np.zeros((n, 2, 6))
    idx = np.flatnonzero(wanted)
    if not len(idx):
        return time_s, q
    T_in = ends[idx, 0].copy()
    T_in[:, :3, 3] -= arm.retract_m * T_in[:, :3, 2]
    poses = np.concatenate([T_in, ends[idx, 1]])
    sol = ur_inverse(arm.T_base_world @ poses @ arm.T_sensor_flange, UR5E_DH)
    lo, hi = arm.joint_range[:, 0], arm.joint_range[:, 1]
    ok = sol.valid & np.all((sol.q >= lo) & (sol.q <= hi), axis=-1)
    dist = np.where(ok, np.linalg.norm(sol.q - arm.q, axis=-1), np.inf)
    best = np.argmin(dist, axis=1)
    reach = np.isfinite(dist[np.arange(len(poses)), best])
    q_best = sol.q[np.arange(len(poses)), best]
    m = len(idx)
    v = arm.speed_m_s
    for k, i in enumerate(idx):
        if not (reach[k] and reach[m + k]):
            continue
        q[i] = q_best[k], q_best[m + k]
        transit = (len(joint_move(arm.q, q_best[k], 0.01)[0]) - 1) * 0.01
        length = float(np.linalg.norm(ends[i, 1, :3, 3] - ends[i, 0, :3, 3]))
        time_s[i] = transit + length / v + v / ACCELERATION_M_S2 + 2 * arm.retract_m / v
    return time_s, q


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


# ---------------------------------------------------------------------- twin/ActiveProbe-v0
#: The greedy probe policy's candidates: elevations [deg], azimuths every
#: PROBE_AZIMUTH_STEP_DEG (four looking straight down) and aim offsets per view.
PROBE_ELEVATIONS_DEG = (90.0, 65.0, 40.0)
PROBE_AZIMUTH_STEP_DEG = 30.0
PROBE_AIM_OFFSETS = (-0.5, 0.0, 0.5)
#: Candidates checked for feasibility and reach per step, best predicted gain first.
PROBE_MAX_CHECKS = 20


class RandomProbePolicy:
    """Uniform actions for ``twin/ActiveProbe-v0`` from its own seeded stream."""

    name = "random"

    def __init__(self, env, seed: int = 0):
        self.rng = np.random.default_rng(seed)
        self.size = int(env.unwrapped.action_space.shape[0])

    def reset(self) -> None:
        pass

    def __call__(self, observation: dict) -> np.ndarray:
        return self.rng.uniform(-1.0, 1.0, self.size)


class GreedyProbePolicy:
    """For ``twin/ActiveProbe-v0``: the candidate target with the best predicted information
    gain, ``log(1 + g^T (P + F)^-1 g / sigma^2)`` with ``g = [p x n, n]`` at the point the line
    of sight meets the CAD model at the current estimate (smooth normal), ``sigma`` the probe's
    (:func:`twin.qualification.probe_sigma_m`). The best ``PROBE_MAX_CHECKS`` are checked in that
    order as the environment checks a target (:func:`twin.env.active_probe.probe_target`:
    feasibility, the table, the arm's reach); the first that passes is taken. The motion time
    is left out (every probing move takes a few seconds)."""

    name = "greedy"

    def __init__(self, env, seed: int = 0):
        self.env = env.unwrapped
        self.candidates = _probe_candidate_actions()

    def reset(self) -> None:
        pass

    def __call__(self, observation: dict) -> np.ndarray:
        from twin.env.active_probe import probe_target

        ep = self.env.episode
        es = ep["es"]
        gain = self.gains()
        for i in np.argsort(-gain)[:PROBE_MAX_CHECKS]:
            if not np.isfinite(gain[i]):
                break
            if not isinstance(probe_target(self.candidates[i], es, es.reach, ep["T_base_est"]), str):
                return self.candidates[i].copy()
        return self.candidates[int(np.argmax(gain))].copy()

    def gains(self) -> np.ndarray:
        """(C,) predicted information gain of each candidate [nats] (-inf where the line of
        sight misses the part)."""
        from twin.env.active_probe import view_action
        from twin.qualification import probe_sigma_m

        env = self.env
        ep = env.episode
        es, realized = ep["es"], ep["realized"]
        T_world_est = realized.scenario.T_world_base @ ep["T_base_est"]
        C = np.linalg.inv(env.prior + ep["F"])
        sigma = probe_sigma_m(realized)
        band = env.edge_band_m()
        gain = np.full(len(self.candidates), -np.inf)
        for idx in _by_direction(np.column_stack([self.candidates[:, :2], np.zeros((len(self.candidates), 2))])):
            views = [decode_action(view_action(self.candidates[i]), es.geometry) for i in idx]
            hits = [(i, c) for i, c in zip(idx, _centres(views, T_world_est, es), strict=True) if c is not None]
            if not hits:
                continue
            p_world = np.array([c for _, c in hits])
            p_wp = (p_world - T_world_est[:3, 3]) @ T_world_est[:3, :3]
            cp = es.workpiece.index.query(p_wp)
            n_wp = es.workpiece.index.smooth_normals(cp.face, cp.foot)
            g = np.hstack([np.cross(cp.foot, n_wp), n_wp])
            # a point in the band around a sharp edge is left out of the fit: it brings nothing
            kept = es.edges.distance(cp.foot) > band
            gain[[i for i, _ in hits]] = np.where(kept, np.log1p(np.einsum("ij,jk,ik->i", g, C, g) / sigma**2), 0.0)
        return gain


def _probe_candidate_actions() -> np.ndarray:
    from twin.env.views import ELEVATION_MIN_DEG

    out = []
    for el in PROBE_ELEVATIONS_DEG:
        a1 = 2 * (el - ELEVATION_MIN_DEG) / (90.0 - ELEVATION_MIN_DEG) - 1
        for az in np.arange(-180.0, 180.0, 90.0 if el == 90.0 else PROBE_AZIMUTH_STEP_DEG):
            for o1 in PROBE_AIM_OFFSETS:
                for o2 in PROBE_AIM_OFFSETS:
                    out.append([az / 180.0, a1, o1, o2])
    return np.array(out)


PROBE_POLICIES = {"random": RandomProbePolicy, "greedy": GreedyProbePolicy}

"""One trial of a study: a pure function of (study, cell, trial) returning a flat dict of metrics.

Randomness comes only from ``np.random.SeedSequence(study.seed, spawn_key=(cell, trial))``
(never the scenario's own seed streams), so a trial's result does not depend on the worker
that runs it, the order, or a resume. Its first child draws the initial pose (the truth moved
by a rotation of ``init_angle_deg`` about a random axis and a translation of ``init_distance_m``
in a random direction, workpiece frame); the second the sensor and encoder errors (fast) or the
scenario's seed (full).

Kinds:

* ``fast``: the noise-free scan geometry of a cell's scenario (the ideal rays, the encoder
  readings, the plan) is simulated once per worker process and cached by the scenario's
  content; each trial redraws the sensor's errors from the ideal rays (the sensor's
  ``measure``), the encoder noise and time skew, rebuilds the points with the nominal
  kinematics and hand-eye, and localizes from the trial's initial pose
  (:func:`algorithms.registration.localize`, sigma :func:`twin.pipeline.sensor_sigma_m`).
  Robot-side errors drawn once per scenario (kinematics, hand-eye) stay those of the cached scan.
* ``full``: :func:`twin.pipeline.run` on the scenario with its seed replaced by one drawn from
  the trial's stream; the localization is the loop's own (from the nominal pose).
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from algorithms.errors import AlgorithmError
from algorithms.geometry.se3 import make_pose, rotation_error_rad, translation_error_m
from algorithms.registration import localize
from algorithms.registration.uncertainty import pose_error_twist
from twin.cell import build_cell
from twin.errors import TwinError
from twin.pipeline import run as run_loop
from twin.pipeline import sensor_sigma_m
from twin.plan import ScanPlan, plan_scan
from twin.realize import Realized, realize
from twin.robot import JOINT_NAMES, UR5E_DH
from twin.scan import solve_joint_references
from twin.scenario import Scenario, load_scenario, merge_tables
from twin.sensors.base import RawRays, sensor_slice
from twin.sim import simulate
from twin.studies.spec import Study

#: The metric columns of a trial, in order (units in :mod:`twin.studies.runner`'s docstring).
TWIST_COLUMNS = ("omega_x_urad", "omega_y_urad", "omega_z_urad", "v_x_um", "v_y_um", "v_z_um")
METRIC_COLUMNS = TWIST_COLUMNS + ("rotation_error_deg", "translation_error_um", "rmse_um", "iterations", "status",
                                  "time_s", "n_points")


@dataclass(frozen=True)
class NoiseFreeScan:
    """A cell's scan without sensor or encoder errors, simulated once per worker.

    Attributes:
        realized: the realized scenario (truth, mesh index).
        rays: the ideal ray results, (N, B) leading shape.
        q_enc: (N, 6) encoder readings before encoder noise and time skew [rad].
        plan: the planned sensor poses (``plan.t`` the sample times [s], ``plan.line`` the lines).
        model: the true cell's model (occlusion rays); sensor: its sensor.
    """

    realized: Realized
    rays: RawRays
    q_enc: np.ndarray
    plan: ScanPlan
    model: object
    sensor: object


_CACHE: dict[str, NoiseFreeScan] = {}
_CACHE_SIZE = 8


def scenario_key(scenario: Scenario) -> str:
    """A key of the scenario's content (its merged tables and where relative paths resolve)."""
    canon = json.dumps({"raw": scenario.raw, "source": scenario.source}, sort_keys=True, default=str)
    return hashlib.sha256(canon.encode()).hexdigest()


def noise_free_scan(scenario: Scenario) -> NoiseFreeScan:
    """The cached noise-free scan of ``scenario`` (simulated on first use in this process),
    mirroring :func:`twin.scan.run_scan` up to the sensor model."""
    key = scenario_key(scenario)
    hit = _CACHE.get(key)
    if hit is not None:
        return hit
    realized = realize(scenario)
    nominal, true_cell = build_cell(realized, "nominal"), build_cell(realized, "true")
    plan = plan_scan(nominal)
    q_ref, qd_ref = solve_joint_references(nominal, plan)
    sensor, model = true_cell.sensor, true_cell.model
    n, b = len(q_ref), sensor.beams
    dist = np.empty((n, b))
    origin, direction, normal, receiver = (np.empty((n, b, 3)) for _ in range(4))
    q_enc = np.empty((n, 6))
    enc_cols = [sensor_slice(model, f"enc_{j}").start for j in JOINT_NAMES]

    def on_chunk(i0, sens, q_before):
        i1 = i0 + len(sens)
        q_enc[i0:i1] = sens[:, enc_cols]
        r = sensor.decode(model, sens)
        dist[i0:i1], origin[i0:i1], direction[i0:i1] = r.dist, r.origin, r.direction
        normal[i0:i1], receiver[i0:i1] = r.normal, r.receiver

    simulate(true_cell, q_ref, qd_ref, on_chunk)
    out = NoiseFreeScan(realized, RawRays(dist, origin, direction, normal, receiver), q_enc, plan, model, sensor)
    if len(_CACHE) >= _CACHE_SIZE:
        _CACHE.pop(next(iter(_CACHE)))
    _CACHE[key] = out
    return out


def trial_streams(seed: int, cell: int, trial: int) -> tuple[np.random.Generator, ...]:
    """(initial pose stream, error stream, point subset stream) of one trial (the first two are
    the same children whether or not the third is used)."""
    return tuple(np.random.default_rng(c) for c in np.random.SeedSequence(seed, spawn_key=(cell, trial)).spawn(3))


def initial_pose(T_true: np.ndarray, angle_rad: float, distance_m: float, rng: np.random.Generator) -> np.ndarray:
    """``T_true`` moved by a rotation of ``angle_rad`` about a random axis and a translation of
    ``distance_m`` in a random direction, both in the workpiece frame; (4, 4)."""
    axis = rng.standard_normal(3)
    axis /= np.linalg.norm(axis)
    u = rng.standard_normal(3)
    u /= np.linalg.norm(u)
    dT = make_pose(Rotation.from_rotvec(angle_rad * axis).as_matrix(), distance_m * u)
    return T_true @ dT


def _metrics(T_est: np.ndarray, T_true: np.ndarray, rmse_m: float, iterations: int, status: str, time_s: float,
             n_points: int) -> dict:
    xi = pose_error_twist(T_est, T_true)
    out = {name: float(v * 1e6) for name, v in zip(TWIST_COLUMNS, xi, strict=True)}
    out.update(rotation_error_deg=float(np.degrees(rotation_error_rad(T_est, T_true))),
               translation_error_um=float(translation_error_m(T_est, T_true) * 1e6), rmse_um=float(rmse_m * 1e6),
               iterations=int(iterations), status=status, time_s=float(time_s), n_points=int(n_points))
    return out


def _failed(status: str, n_points: int = 0, time_s: float = 0.0) -> dict:
    out = {name: float("nan") for name in TWIST_COLUMNS}
    out.update(rotation_error_deg=float("nan"), translation_error_um=float("nan"), rmse_um=float("nan"),
               iterations=0, status=status, time_s=float(time_s), n_points=int(n_points))
    return out


def run_trial(study: Study, cell: int, trial: int) -> dict:
    """One trial (module docstring): ``{"cell", "trial", *METRIC_COLUMNS}``."""
    out = fast_trial(study, cell, trial) if study.kind == "fast" else full_trial(study, cell, trial)
    return {"cell": int(cell), "trial": int(trial), **out}


def fast_trial(study: Study, cell: int, trial: int) -> dict:
    over, loc = study.cell_settings(cell)
    scenario = load_scenario(study.scenario_path, over, machine="arm")
    geo = noise_free_scan(scenario)
    rng_init, rng_err, rng_subset = trial_streams(study.seed, cell, trial)
    T_true = geo.realized.T_base_workpiece_true
    T_init = initial_pose(T_true, np.radians(loc["init_angle_deg"]), loc["init_distance_m"], rng_init)
    meas = geo.sensor.measure(geo.rays, rng_err, geo.model)
    t, q_log = geo.plan.t, geo.q_enc
    noise = scenario.noise
    if noise.time_skew_s != 0.0:
        ts = np.clip(t - noise.time_skew_s, t[0], t[-1])
        q_log = np.column_stack([np.interp(ts, t, q_log[:, j]) for j in range(6)])
    if noise.encoder_sigma_rad > 0:
        q_log = q_log + rng_err.normal(0.0, noise.encoder_sigma_rad, q_log.shape)
    points = geo.sensor.reconstruct(q_log, meas.d, UR5E_DH, scenario.sensor.T_flange_sensor)
    pts = points[meas.valid & (geo.plan.line >= 0)[:, None]]
    if 0 < loc["points"] < len(pts):  # a random subset of the valid points, drawn per trial
        pts = pts[np.sort(rng_subset.choice(len(pts), loc["points"], replace=False))]
    t0 = time.perf_counter()
    try:
        res = localize(pts, geo.realized.workpiece.mesh, method=loc["method"], init=T_init,
                       sigma=sensor_sigma_m(scenario) or None, index=geo.realized.workpiece.index)
    except AlgorithmError:
        return _failed("error", len(pts), time.perf_counter() - t0)
    return _metrics(res.T_world_workpiece, T_true, res.rmse_m, res.iterations, res.status.value,
                    res.time_s, len(pts))


def full_trial(study: Study, cell: int, trial: int) -> dict:
    over, _ = study.cell_settings(cell)
    _, rng_err, _ = trial_streams(study.seed, cell, trial)
    seed = int(rng_err.integers(0, 2**63 - 1))
    scenario = load_scenario(study.scenario_path, merge_tables(over, {"seed": seed}), machine="arm")
    realized = realize(scenario)
    try:
        result = run_loop(realized)
    except TwinError:
        return _failed("error")
    loc = result.localization
    if loc is None:
        return _failed(f"failed_{result.failure[0]}" if result.failure else "failed")
    n = len(result.scan.line_points_base) if result.scan is not None else 0
    out = _metrics(loc.T_world_workpiece, realized.T_base_workpiece_true, loc.rmse_m, loc.iterations,
                   loc.status.value, result.timings_s.get("localize_s", loc.time_s), n)
    return out

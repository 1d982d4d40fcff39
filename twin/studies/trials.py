"""The pose trials of a study (``fast``, ``full``, ``points``): each a pure function of
(study, cell, trial) returning a flat dict of metrics.

Randomness comes only from ``np.random.SeedSequence(study.seed, spawn_key=(cell, trial))``
(never the scenario's own seed streams), so a trial's result does not depend on the worker
that runs it, the order, or a resume. Its first child draws the initial pose (the truth moved
by a rotation of ``init_angle_deg`` about a random axis and a translation of ``init_distance_m``
in a random direction, workpiece frame; with ``init_position = "mean"`` the translation instead
puts the model's centroid at the points' mean, document 000's ``p0 = mean(y)``); the second the
sensor and encoder errors (fast), the scenario's seed (full) or the noise (points); the third
the point subset (fast) or the point set (points); the fourth the method's own randomness
(GA, PSO, multistart perturbations); the fifth the systematic effects drawn per trial
(:mod:`twin.studies.inputs`: the linearity curve, the time skew, the robot-side errors).

Kinds:

* ``fast``: the noise-free scan geometry of a cell's scenario (the ideal rays, the encoder
  readings, the plan) is simulated once per worker process and cached by the scenario's
  content; each trial redraws the sensor's errors from the ideal rays (the sensor's
  ``measure``), the encoder noise and time skew, rebuilds the points with the nominal
  kinematics and hand-eye, and localizes from the trial's initial pose
  (:func:`algorithms.registration.localize`, sigma :func:`twin.scan_uncertainty.reading_sigma_m`:
  the sensor's and the encoders' noise). The sensor-side systematic effects the study draws per
  trial (``[inputs]``, by default every one the scenario has on) are redrawn: the linearity
  curve (a sensor unit per trial) and the time skew. Robot-side errors (kinematics, hand-eye)
  are those of the cached scan: a study declares them ``fixed``.
* ``full``: the loop of ``twin run`` up to the compensated CAD path (:mod:`twin.studies.full_trials`)
  on the scenario with its seed replaced by one drawn from the trial's stream (the per-reading
  noise) and the trial's systematic draws put into the scenario (the time skew, which only the
  simulation reads) and the truth (the sensor unit's linearity curve, the kinematic and
  hand-eye errors, the part's placement), a ``fixed`` one kept at the scenario's value
  (kinematic errors: the draw of the scenario's own seed); the localization is the loop's own
  (from the nominal pose), with the data sheet's band.
* ``points``: document 000's simulation (:mod:`twin.studies.point_sets`): model points on the
  scenario's part, the known transform (the scenario's true placement), the noise; localized
  by ``localize.method`` (:mod:`twin.studies.methods`), after the subsampling rule.

Every kind also reports the Cramer-Rao bound of its point set at the truth (smooth normals of
the model; the white reading noise: the sensor's repeatability and quantisation and the
encoders' noise, :func:`twin.scan_uncertainty.white_reading_sigma_m`, without the linearity
curve, a systematic error no number of points averages out; for points trials the points'
sigma), so that it is a bound: the root of the trace of its rotation and
translation blocks, and the squared Mahalanobis distance ``xi^T C^-1 xi`` of the pose error
(mean 6 at the bound), NaN where the points do not fix all six directions. A full trial also
reports ``path_error_max_um``, how far the CAD path compensated with the estimate lies from
the same path on the true part (NaN for the other kinds).
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass, replace
from typing import Any

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from algorithms.errors import AlgorithmError
from algorithms.geometry.parametric import ParametricModel
from algorithms.geometry.se3 import inv_pose, make_pose, rotation_error_rad, transform_points, translation_error_m
from algorithms.registration.global_search.multistart import model_centroid
from algorithms.registration.uncertainty import crlb, observability, pose_error_twist
from twin import evaluate
from twin.cell import build_cell
from twin.errors import TwinError
from twin.parts.exact import exact_surfaces
from twin.plan import ScanPlan, plan_scan
from twin.realize import Realized, realize
from twin.robot import UR5E_DH
from twin.scan import SampleLog, solve_joint_references
from twin.scan_uncertainty import (
    beam_directions_base,
    linearity_covariance,
    reading_sigma_m,
    white_reading_sigma_m,
)
from twin.scenario import Scenario, load_scenario
from twin.sensors.base import Measurement, RawRays, RaySensor
from twin.sim import simulate
from twin.studies.inputs import AMPLITUDE_SECOND_MOMENT, Draw, Resolved, draw
from twin.studies.methods import Outcome, run_method
from twin.studies.point_sets import Design, make_design, measured_points, model_points
from twin.studies.spec import Study

#: The metric columns of a trial, in order (units in :mod:`twin.studies.runner`'s docstring).
TWIST_COLUMNS = ("omega_x_urad", "omega_y_urad", "omega_z_urad", "v_x_um", "v_y_um", "v_z_um")
#: Per twist component, the standard uncertainty of the Cramer-Rao bound of the white reading noise
#: and the GUM law of propagation's (fast trials: that bound and the linearity curve propagated as
#: a Type B effect; NaN for the other kinds).
CRLB_COLUMNS = tuple(f"u_crlb_{c}" for c in TWIST_COLUMNS)
LPU_COLUMNS = tuple(f"u_lpu_{c}" for c in TWIST_COLUMNS)
METRIC_COLUMNS = TWIST_COLUMNS + ("rotation_error_deg", "translation_error_um", "rmse_um", "iterations", "status",
                                  "time_s", "n_points", "crlb_rotation_urad", "crlb_translation_um", "mahalanobis2",
                                  "path_error_max_um") + CRLB_COLUMNS + LPU_COLUMNS


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
    model: mujoco.MjModel
    sensor: RaySensor


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
    log = SampleLog(true_cell, len(q_ref))
    simulate(true_cell, q_ref, qd_ref, log.on_chunk)
    out = NoiseFreeScan(realized, log.rays(), log.q_enc, plan, true_cell.model, true_cell.sensor)
    if len(_CACHE) >= _CACHE_SIZE:
        _CACHE.pop(next(iter(_CACHE)))
    _CACHE[key] = out
    return out


def trial_streams(seed: int, cell: int, trial: int) -> tuple[np.random.Generator, ...]:
    """(initial pose, errors, points, method) streams of one trial: the children 0-3 of its
    ``SeedSequence`` (a child is the same whether or not the later ones are used)."""
    return tuple(np.random.default_rng(c) for c in np.random.SeedSequence(seed, spawn_key=(cell, trial)).spawn(4))


def systematic_stream(seed: int, cell: int, trial: int) -> np.random.Generator:
    """The fifth child of the trial's ``SeedSequence``: its systematic effects drawn per trial."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(cell, trial)).spawn(5)[4])


def initial_pose(T_true: np.ndarray, angle_rad: float, distance_m: float, rng: np.random.Generator) -> np.ndarray:
    """``T_true`` moved by a rotation of ``angle_rad`` about a random axis and a translation of
    ``distance_m`` in a random direction, both in the workpiece frame; (4, 4)."""
    axis = rng.standard_normal(3)
    axis /= np.linalg.norm(axis)
    u = rng.standard_normal(3)
    u /= np.linalg.norm(u)
    dT = make_pose(Rotation.from_rotvec(angle_rad * axis).as_matrix(), distance_m * u)
    return T_true @ dT


def start_pose(T_true: np.ndarray, loc: dict, points: np.ndarray, mesh, rng: np.random.Generator) -> np.ndarray:
    """The trial's initial pose (module docstring): ``initial_pose``, then with
    ``init_position = "mean"`` the translation that puts the model centroid at the points' mean."""
    T = initial_pose(T_true, np.radians(loc["init_angle_deg"]), loc["init_distance_m"], rng)
    if loc["init_position"] == "mean":
        T[:3, 3] = points.mean(axis=0) - T[:3, :3] @ model_centroid(mesh)
    return T


def bound(points: np.ndarray, T_true: np.ndarray, index, sigma_m: float | None) -> np.ndarray | None:
    """The Cramer-Rao bound (6, 6) of ``points`` (world frame) at the truth, or None where the
    points do not fix all six directions or no sigma is known."""
    if not sigma_m or len(points) < 6:
        return None
    cp = index.query(transform_points(inv_pose(T_true), points))
    normals = index.smooth_normals(cp.face, cp.foot)
    if not observability(cp.foot, normals).observable:
        return None
    return crlb(cp.foot, normals, sigma_m)


def _metrics(out: Outcome, T_true: np.ndarray, n_points: int, C: np.ndarray | None) -> dict:
    T_est = out.T_world_workpiece
    xi = pose_error_twist(T_est, T_true)
    m: dict[str, Any] = {name: float(v * 1e6) for name, v in zip(TWIST_COLUMNS, xi, strict=True)}
    m.update(rotation_error_deg=float(np.degrees(rotation_error_rad(T_est, T_true))),
             translation_error_um=float(translation_error_m(T_est, T_true) * 1e6), rmse_um=float(out.rmse_m * 1e6),
             iterations=int(out.iterations), status=out.status, time_s=float(out.time_s), n_points=int(n_points),
             path_error_max_um=float("nan"), **_bound_columns(C, xi), **_lpu_columns(C, None))
    return m


def _bound_columns(C: np.ndarray | None, xi: np.ndarray | None) -> dict:
    if C is None:
        return {"crlb_rotation_urad": float("nan"), "crlb_translation_um": float("nan"), "mahalanobis2": float("nan")}
    m2 = float(xi @ np.linalg.solve(C, xi)) if xi is not None else float("nan")
    return {"crlb_rotation_urad": float(np.sqrt(np.trace(C[:3, :3])) * 1e6),
            "crlb_translation_um": float(np.sqrt(np.trace(C[3:, 3:])) * 1e6), "mahalanobis2": m2}


def _lpu_columns(C_white: np.ndarray | None, C_total: np.ndarray | None) -> dict:
    """The standard uncertainties (urad, um) of the twist components of the white noise's bound
    and of the law of propagation's covariance."""
    out = {}
    for names, C in ((CRLB_COLUMNS, C_white), (LPU_COLUMNS, C_total)):
        u = np.full(6, np.nan) if C is None else np.sqrt(np.clip(np.diag(C), 0.0, None)) * 1e6
        out.update({name: float(v) for name, v in zip(names, u, strict=True)})
    return out


def _failed(status: str, n_points: int = 0, time_s: float = 0.0, C: np.ndarray | None = None) -> dict:
    out: dict[str, Any] = {name: float("nan") for name in TWIST_COLUMNS}
    out.update(rotation_error_deg=float("nan"), translation_error_um=float("nan"), rmse_um=float("nan"),
               iterations=0, status=status, time_s=float(time_s), n_points=int(n_points),
               path_error_max_um=float("nan"), **_bound_columns(C, None), **_lpu_columns(None, None))
    return out


def _localize(loc: dict, pts: np.ndarray, workpiece, T_true: np.ndarray, T_init: np.ndarray, sigma_m: float | None,
              rng: np.random.Generator, C: np.ndarray | None, feet: ParametricModel | None = None) -> dict:
    """Localize by ``loc["method"]`` (its fit check with ``sigma_m``, every random and systematic
    effect of a reading) and measure against the truth (the metric columns), with ``C`` the
    Cramer-Rao bound of the white reading noise (:func:`bound`)."""
    t0 = time.perf_counter()
    try:
        out = run_method(loc["method"], pts, workpiece, T_init, sigma_m, rng, loc["init_distance_m"], loc["variant"],
                         {"mutation": loc["ga_mutation"], "rotation_range_deg": loc["ga_rotation_range_deg"]},
                         loc["tolerance"] or None, feet)
    except AlgorithmError:
        return _failed("error", len(pts), time.perf_counter() - t0, C)
    if isinstance(out, str):
        return _failed(out, len(pts), 0.0, C)
    return _metrics(out, T_true, len(pts), C)


def scan_measurement(scenario: Scenario, geo: NoiseFreeScan, rng: np.random.Generator,
                     sys: Draw | None = None) -> tuple[Measurement, np.ndarray]:
    """The scan redrawn: the sensor's errors on the ideal rays (this trial's sensor unit where
    ``sys`` draws the linearity curve; without ``sys``, a unit of phase drawn from ``rng`` where
    the scenario's phase is "random"), encoder noise and time skew (``sys``'s, else the
    scenario's) on the joint log; (the measurement, (N, 6) the joint log [rad])."""
    sensor = geo.sensor
    if sys is not None and sys.linearity_phase_deg is not None and sys.linearity_m is not None:
        sensor = sensor.with_settings(replace(sensor.spec, linearity_phase_deg=sys.linearity_phase_deg,
                                              linearity_m=sys.linearity_m), sensor.noise)
    elif sys is None and scenario.sensor.linearity_phase_deg is None:
        sensor = sensor.with_settings(replace(sensor.spec, linearity_phase_deg=float(rng.uniform(0.0, 360.0))),
                                      sensor.noise)
    meas = sensor.measure(geo.rays, rng, geo.model)
    t, q_log = geo.plan.t, geo.q_enc
    noise = scenario.noise
    skew = sys.time_skew_s if sys is not None and sys.time_skew_s is not None else noise.time_skew_s
    if skew != 0.0:
        ts = np.clip(t - skew, t[0], t[-1])
        q_log = np.column_stack([np.interp(ts, t, q_log[:, j]) for j in range(6)])
    if noise.encoder_sigma_rad > 0:
        q_log = q_log + rng.normal(0.0, noise.encoder_sigma_rad, q_log.shape)
    return meas, q_log


def scan_points(scenario: Scenario, geo: NoiseFreeScan,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`scan_measurement` with the points rebuilt with the nominal kinematics and hand-eye
    (eq. 2); ((N, B, 3) points in the robot base frame [m], (N, B) valid, (N, 6) the joint log)."""
    meas, q_log = scan_measurement(scenario, geo, rng)
    return geo.sensor.reconstruct(q_log, meas.d, UR5E_DH, scenario.sensor.T_flange_sensor), meas.valid, q_log


def fast_trial(study: Study, cell: int, trial: int) -> dict:
    settings = study.cell_settings(cell)
    loc = settings.localize
    scenario = load_scenario(settings.scenario_path, settings.overrides, machine="arm")
    geo = noise_free_scan(scenario)
    rng_init, rng_err, rng_subset, rng_method = trial_streams(study.seed, cell, trial)
    inputs = study.cell_inputs(cell, scenario)
    sys = draw(inputs, scenario.sensor.linearity_m, systematic_stream(study.seed, cell, trial))
    T_true = evaluate.Evaluation(geo.realized).T_base_workpiece
    T_fs = scenario.sensor.T_flange_sensor
    meas, q_log = scan_measurement(scenario, geo, rng_err, sys)
    mask = meas.valid & (geo.plan.line >= 0)[:, None]
    pts = geo.sensor.reconstruct(q_log, meas.d, UR5E_DH, T_fs)[mask]
    q_pts = np.broadcast_to(q_log[:, None, :], (*mask.shape, 6))[mask]
    d_pts = meas.d[mask]
    beams = beam_directions_base(q_log, geo.sensor.beam_dirs_sensor(), T_fs)[mask]
    if 0 < loc["points"] < len(pts):  # a random subset of the valid points, drawn per trial
        keep = np.sort(rng_subset.choice(len(pts), loc["points"], replace=False))
        pts, q_pts, d_pts, beams = pts[keep], q_pts[keep], d_pts[keep], beams[keep]
    workpiece = geo.realized.workpiece
    T_init = start_pose(T_true, loc, pts, workpiece.mesh, rng_init)
    T_nominal = geo.realized.T_base_workpiece_nominal
    sigma = reading_sigma_m(scenario, q_pts, pts, T_nominal, workpiece.index)
    white = white_reading_sigma_m(scenario, q_pts, pts, T_nominal, workpiece.index)
    C = bound(pts, T_true, workpiece.index, white or None)
    row = _localize(loc, pts, workpiece, T_true, T_init, sigma or None, rng_method, C)
    if C is not None:
        lin = _linearity_part(scenario, inputs["linearity"], d_pts, beams, pts, T_true, workpiece.index)
        row.update(_lpu_columns(C, C + lin))
    return row


def _linearity_part(scenario: Scenario, linearity: Resolved, d: np.ndarray, beams: np.ndarray, pts: np.ndarray,
                    T_true: np.ndarray, index) -> np.ndarray:
    """The pose covariance (6, 6) the sensor's linearity curve causes, propagated by the GUM's law
    of propagation at the truth (:func:`twin.scan_uncertainty.linearity_covariance`, scaled by the
    amplitude law's ``E[A^2] / band^2``); zero unless the study draws the curve per trial (a
    fixed curve is a bias, not an uncertainty)."""
    if linearity.treatment != "per_trial" or scenario.sensor.linearity_m == 0.0:
        return np.zeros((6, 6))
    return AMPLITUDE_SECOND_MOMENT[linearity.amplitude] * linearity_covariance(
        scenario.sensor, d, beams, pts, T_true, np.eye(6), index)


_PARTS: dict[str, tuple[Realized, dict]] = {}


def part_design(scenario: Scenario, points: dict) -> tuple[Realized, Design]:
    """The realized scenario (part, truth) and the design of its point sets, cached per process."""
    key = scenario_key(scenario)
    if key not in _PARTS:
        if len(_PARTS) >= _CACHE_SIZE:
            _PARTS.pop(next(iter(_PARTS)))
        _PARTS[key] = (realize(scenario), {})
    realized, designs = _PARTS[key]
    dkey = json.dumps({k: points[k] for k in ("region", "layout", "grid_rows", "grid_cols")}, sort_keys=True)
    if dkey not in designs:
        designs[dkey] = make_design(realized.workpiece.mesh, points)
    return realized, designs[dkey]


def points_trial(study: Study, cell: int, trial: int) -> dict:
    settings = study.cell_settings(cell)
    loc, spec = settings.localize, settings.points
    scenario = load_scenario(settings.scenario_path, settings.overrides, machine="arm")
    realized, design = part_design(scenario, spec)
    rng_init, rng_err, rng_points, rng_method = trial_streams(study.seed, cell, trial)
    workpiece, T_true = realized.workpiece, evaluate.Evaluation(realized).T_base_workpiece
    exact = exact_model(scenario, workpiece) if spec["truth"] == "exact" or loc["foot_points"] == "newton" else None
    x = model_points(workpiece.mesh, design, spec, loc["subsample"], rng_points)
    if exact is not None and spec["truth"] == "exact":
        x, normals = on_exact_surfaces(x, exact)
    else:
        cp = workpiece.index.query(x)
        normals = workpiece.index.smooth_normals(cp.face, cp.foot)
    pts = measured_points(x, normals, T_true, spec, rng_err)
    T_init = start_pose(T_true, loc, pts, workpiece.mesh, rng_init)
    sigma = spec["noise_sigma_m"]
    feet = exact if loc["foot_points"] == "newton" else None
    return _localize(loc, pts, workpiece, T_true, T_init, sigma, rng_method, bound(pts, T_true, workpiece.index, sigma),
                     feet)


#: A point sampled on the CAD mesh lies this close to its exact surface (the chord tolerance of
#: the generated parts, 10 um, with room); farther, the region samples a face the model lacks.
EXACT_MAX_GAP_M = 1e-4
_EXACT: dict[str, ParametricModel] = {}


def exact_model(scenario: Scenario, workpiece) -> ParametricModel:
    """The part's exact surfaces (:mod:`twin.parts.exact`), cached per process."""
    key = scenario_key(scenario)
    if key not in _EXACT:
        wp = scenario.workpiece
        surfaces = exact_surfaces(wp.shape, **wp.params) if wp.shape is not None else None
        if surfaces is None:
            raise TwinError(f"points.truth = 'exact' and localize.foot_points = 'newton' need a part with exact "
                            f"surfaces (hemisphere_punch, bottle_punch), not {wp.shape or wp.mesh!r}")
        if len(_EXACT) >= _CACHE_SIZE:
            _EXACT.pop(next(iter(_EXACT)))
        _EXACT[key] = ParametricModel(surfaces, workpiece.index.extent)
    return _EXACT[key]


def on_exact_surfaces(x: np.ndarray, exact: ParametricModel) -> tuple[np.ndarray, np.ndarray]:
    """Points sampled on the CAD mesh moved onto the exact surface (their feet there), with its normals."""
    cp = exact.query(x)
    if np.max(cp.distance) > EXACT_MAX_GAP_M:
        raise TwinError(f"points.truth = 'exact': points.region samples a face the part's exact surfaces lack "
                        f"({np.max(cp.distance) * 1e3:.2f} mm from every one)")
    return cp.foot, cp.normal

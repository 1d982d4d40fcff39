"""Full trials: the loop of ``twin run`` up to what a study reports, sharing what a trial's draw
does not change.

A full trial scans the part in the trial's true cell, localizes the scan from the nominal pose
(:func:`twin.workflows.loop.localize_scan`) and moves the CAD path by the estimate: the numbers a
study reports are the localization's errors against the truth, its Cramer-Rao bound, and the
compensated CAD path's largest error (``path_error_max_um``) over every point of the process
region the scan determines. The process paths' IK and their replays, which no study column
reads, are not run.

Shared, once per worker process (the numbers are those of :func:`twin.workflows.loop.run` on the
same realization: ``tests/test_full_trials.py``):

* per part and plan (the scenario's tables but its seed and its ``[noise]``): the part's mesh and
  its index, the nominal cell's scan plan and joint references, the CAD raster of the process
  region. None of them reads the truth or an error source;
* per truth (the arm's link errors, the true hand-eye transform and placement): the true cell and
  the 1 ms rollout of the scan's references in it. Physics is deterministic, so a truth shared by
  trials (every cell that draws no robot-side effect per trial) is simulated once. The sensor
  unit's linearity curve, the time skew and every per-reading noise act after the rollout, in the
  sensor model, with this trial's sensor and streams.

The trial's realization itself follows :func:`twin.studies.trials` (its seed from the trial's
error stream, its systematic draws in the truth).
"""

from __future__ import annotations

import hashlib
import json
import time
from collections import OrderedDict
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from algorithms.errors import AlgorithmError
from algorithms.geometry.se3 import transform_points
from twin import evaluate
from twin.cell import Cell, build_cell, true_cell_content
from twin.errors import TwinError
from twin.plan import ScanPlan, plan_scan
from twin.process_paths import cad_path_lines, check_process_region
from twin.realize import LinkError, Realized, Streams, Workpiece, draw_truth, realize, with_truth
from twin.scan import SampleLog, scan_from_log, solve_joint_references
from twin.scan_uncertainty import scan_reading_sigma_m
from twin.scenario import Scenario, load_scenario, merge_tables
from twin.sensors.laser import LaserSensor
from twin.sim import simulate
from twin.stages import StageFailed
from twin.studies.inputs import Draw, Resolved, draw
from twin.studies.methods import Outcome
from twin.studies.spec import Study
from twin.studies.trials import _failed, _metrics, bound, systematic_stream, trial_streams
from twin.workflows.loop import determined_cad_lines, localize_scan

_CACHE_SIZE = 8


@dataclass(frozen=True)
class Nominal:
    """What every trial of a part and plan shares (module docstring).

    Attributes:
        workpiece: the part's mesh and closest-point index.
        plan: the scan's planned sensor poses; q_ref, qd_ref: (K, 6) its joint references.
        cad_lines: the CAD raster's contact lines and normals (workpiece frame).
    """

    workpiece: Workpiece
    plan: ScanPlan
    q_ref: np.ndarray
    qd_ref: np.ndarray
    cad_lines: tuple[list, list]


@dataclass(frozen=True)
class TrueRollout:
    """A truth's true cell and the rollout of the scan's references in it."""

    cell: Cell
    log: SampleLog


class _Lru(OrderedDict):
    """A small least-recently-used cache (``_CACHE_SIZE`` entries)."""

    def get_or_make(self, key: str, make):
        if key in self:
            self.move_to_end(key)
            return self[key]
        value = make()
        self[key] = value
        if len(self) > _CACHE_SIZE:
            self.popitem(last=False)
        return value


_NOMINALS = _Lru()
_ROLLOUTS = _Lru()


def _digest(*parts: Any) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()


def nominal_key(scenario: Scenario) -> str:
    """The content of the scenario's tables but its seed and ``[noise]`` (the error sources),
    and where its relative paths resolve."""
    raw = {k: v for k, v in scenario.raw.items() if k not in ("seed", "noise")}
    return _digest(raw, scenario.source)


def truth_key(realized: Realized) -> str:
    """The nominal key and the truth the true cell is built from (:func:`twin.cell.true_cell_content`)."""
    return _digest(nominal_key(realized.scenario), true_cell_content(realized))


def _make_nominal(realized: Realized) -> Nominal:
    """Raises TwinError where the scan is unreachable."""
    nominal = build_cell(realized, "nominal")
    plan = plan_scan(nominal)
    q_ref, qd_ref = solve_joint_references(nominal, plan)
    return Nominal(realized.workpiece, plan, q_ref, qd_ref, cad_path_lines(realized))


def _make_rollout(realized: Realized, nominal: Nominal) -> TrueRollout:
    cell = build_cell(realized, "true")
    log = SampleLog(cell, len(nominal.q_ref))
    simulate(cell, nominal.q_ref, nominal.qd_ref, log.on_chunk)
    if isinstance(cell.sensor, LaserSensor):   # its ray casters (the part's Embree scene), shared by every trial's unit
        cell.sensor.cell_rays(cell.model)
    return TrueRollout(cell, log)


def _workpiece(scenario: Scenario) -> Workpiece:
    key = nominal_key(scenario)
    return _NOMINALS[key].workpiece if key in _NOMINALS else realize(scenario).workpiece


def full_trial(study: Study, cell: int, trial: int) -> dict:
    settings = study.cell_settings(cell)
    _, rng_err, _, _ = trial_streams(study.seed, cell, trial)
    seed = int(rng_err.integers(0, 2**63 - 1))
    base = load_scenario(settings.scenario_path, settings.overrides, machine="arm")
    inputs = study.cell_inputs(cell, base)
    sys = draw(inputs, base.sensor.linearity_m, systematic_stream(study.seed, cell, trial))
    scenario = load_scenario(settings.scenario_path, merge_tables(settings.overrides, {"seed": seed,
                                                                                      **_drawn_tables(sys)}),
                             machine="arm")
    realized = _with_drawn_truth(realize(scenario, workpiece=_workpiece(scenario)), base, inputs, sys)
    try:
        check_process_region(realized)
    except TwinError:
        return _failed("error")
    try:
        nominal = _NOMINALS.get_or_make(nominal_key(scenario), lambda: _make_nominal(realized))
    except TwinError:   # the scan is unreachable
        return _failed("failed_scan")
    return _measured(realized, nominal)


def _measured(realized: Realized, nominal: Nominal) -> dict:
    """Scan (the truth's shared rollout, this trial's sensor model), localize, compensate the CAD
    path; the trial's metric columns."""
    rollout = _ROLLOUTS.get_or_make(truth_key(realized), lambda: _make_rollout(realized, nominal))
    true_cell = replace(rollout.cell, scenario=realized.scenario,
                        sensor=rollout.cell.sensor.with_settings(realized.sensor, realized.scenario.noise))
    scan = scan_from_log(realized, true_cell, nominal.plan, nominal.q_ref, rollout.log)
    index = realized.workpiece.index
    t0 = time.perf_counter()
    try:
        loc = localize_scan(realized, scan)
    except (AlgorithmError, TwinError):
        return _failed("failed_localize")
    time_s = time.perf_counter() - t0
    pts = scan.line_points_base
    T_true = evaluate.Evaluation(realized).T_base_workpiece
    out = Outcome(loc.T_world_workpiece, loc.rmse_m, loc.iterations, loc.status.value, time_s)
    m = _metrics(out, T_true, len(pts), bound(pts, T_true, index, scan_reading_sigma_m(scan, index, white_only=True)))
    try:
        contact = np.concatenate(determined_cad_lines(nominal.cad_lines, loc, index)[0])
    except StageFailed:
        contact = None
    m["path_error_max_um"] = path_error_max_um(contact, loc.T_world_workpiece, T_true)
    return m


def _drawn_tables(sys: Draw) -> dict:
    """The scenario table that puts a trial's time skew into its scenario (only the simulation
    reads it)."""
    return {"noise": {"time_skew_s": sys.time_skew_s}} if sys.time_skew_s is not None else {}


def _with_drawn_truth(realized: Realized, base: Scenario, inputs: dict[str, Resolved], sys: Draw) -> Realized:
    """The realized trial with its systematic effects in the truth: drawn (``sys``: the sensor
    unit's curve, the robot-side errors, the placement), or fixed at the scenario's (the kinematic
    errors its own seed draws, not the trial's). The scenario, what the estimator reads, keeps the
    data sheet's band and the nominal values."""
    changes: dict[str, Any] = {}
    if sys.linearity_phase_deg is not None:
        changes.update(linearity_phase_deg=sys.linearity_phase_deg, linearity_m=sys.linearity_m)
    if sys.link_errors is not None:
        changes["link_errors"] = tuple(LinkError(b, p, R) for b, p, R in sys.link_errors)
    elif inputs["kinematics"].treatment == "fixed":
        changes["link_errors"] = draw_truth(base, Streams(base.seed)).link_errors
    if sys.T_hand_eye_error is not None:
        changes["T_flange_sensor"] = base.sensor.T_flange_sensor @ sys.T_hand_eye_error
    if sys.T_part_error is not None:
        changes["T_world_workpiece"] = base.workpiece.T_world_workpiece_true @ sys.T_part_error
    return with_truth(realized, **changes)


def path_error_max_um(contact: np.ndarray | None, T_est: np.ndarray, T_true: np.ndarray) -> float:
    """How far the CAD path compensated with the estimate lies from the same path on the true
    part: the largest ``|T_est x - T_true x|`` over its contact points ``x`` (workpiece frame)
    [um] (NaN: no path)."""
    if contact is None:
        return float("nan")
    x = contact[np.all(np.isfinite(contact), axis=1)]
    if len(x) == 0:
        return float("nan")
    return float(np.max(np.linalg.norm(transform_points(T_est, x) - transform_points(T_true, x), axis=1)) * 1e6)

"""Full trials share what a trial's draw does not change (the part, the plan and its joint
references, the CAD raster, a truth's rollout): the shared path gives the numbers of the plain
one, :func:`twin.workflows.loop.run` on each trial's own realization, for the same seeds."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.helpers import ROOT
from twin import evaluate
from twin.realize import realize
from twin.scan_uncertainty import scan_reading_sigma_m
from twin.scenario import load_scenario, merge_tables
from twin.studies import full_trials
from twin.studies.full_trials import _drawn_tables, _with_drawn_truth, full_trial, path_error_max_um
from twin.studies.inputs import draw
from twin.studies.methods import Outcome
from twin.studies.spec import load_study
from twin.studies.trials import _metrics, bound, systematic_stream, trial_streams
from twin.workflows.loop import run as run_loop

STUDY = ROOT / "studies" / "robot_errors.toml"


def plain_full_trial(study, cell: int, trial: int) -> dict:
    """The trial as the whole loop of ``twin run`` on its own realization (cells compiled, scan
    planned, solved and simulated, paths solved and replayed): nothing shared. The realization
    is made here as the trial makes it, on purpose written out again: the plain path owes the
    shared one nothing."""
    settings = study.cell_settings(cell)
    _, rng_err, _, _ = trial_streams(study.seed, cell, trial)
    seed = int(rng_err.integers(0, 2**63 - 1))
    base = load_scenario(settings.scenario_path, settings.overrides, machine="arm")
    inputs = study.cell_inputs(cell, base)
    sys = draw(inputs, base.sensor.linearity_m, systematic_stream(study.seed, cell, trial))
    scenario = load_scenario(settings.scenario_path, merge_tables(settings.overrides, {"seed": seed,
                                                                                      **_drawn_tables(sys)}),
                             machine="arm")
    realized = _with_drawn_truth(realize(scenario), base, inputs, sys)
    result = run_loop(realized)
    loc, index = result.localization, realized.workpiece.index
    pts = result.scan.line_points_base
    T_true = evaluate.Evaluation(realized).T_base_workpiece
    out = Outcome(loc.T_world_workpiece, loc.rmse_m, loc.iterations, loc.status.value, 0.0)
    m = _metrics(out, T_true, len(pts), bound(pts, T_true, index, scan_reading_sigma_m(result.scan, index,
                                                                                       white_only=True)))
    m["path_error_max_um"] = path_error_max_um(result.cad_path_workpiece.contact, loc.T_world_workpiece, T_true)
    return m


def _same(shared: dict, plain: dict) -> None:
    for k, v in plain.items():
        if k == "time_s":
            continue
        if isinstance(v, float) and not math.isnan(v):
            # the path's points: built in the workpiece frame here, mapped back from the base frame there
            tol = 1e-6 if k == "path_error_max_um" else 0.0
            assert shared[k] == pytest.approx(v, rel=0, abs=tol), k
        else:
            assert shared[k] == v or (isinstance(v, float) and math.isnan(shared[k])), k


def test_a_shared_rollout_gives_the_plain_trials_numbers():
    """Cell 0 (no robot-side draw): trial 1 reuses trial 0's rollout (one truth) and gives what the
    whole loop gives on its own realization."""
    study = load_study(STUDY)
    full_trials._ROLLOUTS.clear()
    full_trial(study, 0, 0)
    assert len(full_trials._ROLLOUTS) == 1
    shared = full_trial(study, 0, 1)
    assert len(full_trials._ROLLOUTS) == 1          # the same truth: simulated once
    _same(shared, plain_full_trial(study, 0, 1))


@pytest.mark.slow
@pytest.mark.parametrize("cell", [1, 2, 3, 4])
def test_every_error_source_gives_the_plain_trials_numbers(cell):
    """Encoder noise, time skew (sensor model on a shared rollout), kinematic and hand-eye errors
    drawn per trial (a true cell and a rollout per trial, the nominal shared)."""
    study = load_study(STUDY)
    full_trial(study, 0, 0)
    _same(full_trial(study, cell, 2), plain_full_trial(study, cell, 2))
    assert np.isfinite(full_trial(study, cell, 3)["rotation_error_deg"])

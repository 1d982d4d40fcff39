"""A study's Monte Carlo result as JCGM 101 states it: coverage intervals (symmetric and
shortest), Monte Carlo standard errors, values to their numerical tolerance, every trial counted;
a Cramer-Rao bound of the white noise; studies that extend and resume to the same rows."""

import math
import shutil

import numpy as np
import pyarrow.parquet as pq
import pytest

from tests.helpers import run_cli
from tests.test_study import assert_same_table
from tests.test_study_kinds import A_REGION, points_study
from twin.studies import jcgm101
from twin.studies.runner import BATCH_DIR, RESULTS, run_study

POINTS = '[points]\ncount = 150\nnoise_sigma_m = 5e-6\nnoise_direction = "normal"\n' + A_REGION + "\n"


# --- the statistics ----------------------------------------------------------------------------


def test_intervals_of_a_gaussian_sample_are_its_2_5_and_97_5_percent_points():
    y = np.random.default_rng(1).normal(0.0, 1.0, 10_000)
    lo, hi = jcgm101.symmetric_interval(y)
    s = np.sort(y)
    assert (lo, hi) == (s[249], s[9749])  # JCGM 101 7.7.1: q = 9500, r = 250 (1-based)
    assert abs(lo + 1.96) < 0.06 and abs(hi - 1.96) < 0.06
    short = jcgm101.shortest_interval(y)
    assert short[1] - short[0] <= hi - lo + 1e-12
    assert np.mean((y >= short[0]) & (y <= short[1])) >= 0.95


def test_the_shortest_interval_of_a_skewed_quantity_is_shorter_and_shifted():
    y = np.random.default_rng(2).exponential(1.0, 20_000)
    sym, short = jcgm101.symmetric_interval(y), jcgm101.shortest_interval(y)
    assert short[0] < sym[0] and short[1] < sym[1]
    assert short[1] - short[0] < 0.85 * (sym[1] - sym[0])  # exact: 2.996 against 3.664


def test_monte_carlo_standard_error_of_the_mean_is_sigma_over_root_m():
    outputs = [jcgm101.summarize(np.random.default_rng(k).normal(5.0, 2.0, 1000)) for k in range(40)]
    se_mean = np.array([o.mc_se[0] for o in outputs])
    assert 0.05 < np.median(se_mean) < 0.08  # 2 / sqrt(1000) = 0.063
    spread = np.std([o.values[0] for o in outputs])  # the estimates' actual scatter
    assert 0.6 < np.median(se_mean) / spread < 1.6


def test_too_few_values_give_no_standard_error_and_are_indicative():
    o = jcgm101.summarize(np.arange(39.0))
    assert np.all(np.isnan(o.mc_se)) and not o.stable and o.indicative
    assert np.isnan(jcgm101.symmetric_interval(np.arange(3.0))[0])  # q = 3 of 3 values: no interval


def test_values_are_given_to_the_two_digits_of_u():
    assert jcgm101.decimals(0.0123) == 3 and jcgm101.decimals(8.0) == 1 and jcgm101.decimals(37.0) == 0
    assert jcgm101.fmt(3.14159, jcgm101.decimals(0.0123)) == "3.142"
    assert jcgm101.fmt(-0.0004, 1) == "0.0" and jcgm101.fmt(-0.06, 1) == "-0.1"
    o = jcgm101.summarize(np.random.default_rng(3).normal(0.0, 0.0123, 10_000))
    assert math.isclose(o.tolerance, 0.0005)  # half a unit in the last of u's two digits


# --- the report ---------------------------------------------------------------------------------


def test_report_gives_each_quantity_s_jcgm_101_outputs_and_counts_every_trial(tmp_path):
    study = points_study(tmp_path, POINTS, trials=40)  # no grid factor
    run_study(study, tmp_path / "out")
    report = (tmp_path / "out" / "report.md").read_text()
    table = [line for line in report.splitlines() if line.startswith("| cell ") or line.startswith("| 0 |")]
    assert len({line.count("|") for line in table}) == 1  # header and row have as many cells
    assert "95 % interval, symmetric (indicative)" in report and "95 % interval, shortest" in report
    assert "40 trials (ok 40)" in report and "40 of 40 (100 %)" in report
    row = next(line for line in report.splitlines() if line.startswith("| v_x_um |"))
    assert "too few" not in row and row.count("[") == 2  # both intervals, standard errors from 2 batches
    from PIL import Image

    for name in ("histogram_cell0.png", "convergence_cell0.png"):
        assert (tmp_path / "out" / name).stat().st_size > 10_000 and f"({name})" in report
        with Image.open(tmp_path / "out" / name) as image:
            assert image.mode == "P"  # a palette PNG: committed reports stay small


@pytest.mark.slow  # the default suite's five minutes
def test_report_counts_trials_that_are_not_ok(tmp_path):
    """A start far from the truth: some trials fail; they are counted, and the magnitudes over
    every trial that returned a pose say how far the not-ok ones were."""
    body = POINTS + '[localize]\ninit_angle_deg = 120.0\n'
    study = points_study(tmp_path, body, trials=12)
    run_study(study, tmp_path / "out")
    report = (tmp_path / "out" / "report.md").read_text()
    table = pq.read_table(tmp_path / "out" / RESULTS)
    n_ok = table.column("status").to_pylist().count("ok")
    assert f"ok {n_ok}" in report
    if n_ok < 12:
        assert "not `ok` included" in report


# --- the Cramer-Rao bound ---------------------------------------------------------------------


def test_the_bound_is_taken_with_the_white_noise_only():
    from tests.helpers import scenario
    from twin.realize import realize
    from twin.scan_uncertainty import reading_sigma_m, white_reading_sigma_m

    sc = scenario("s_surface")
    realized = realize(sc)
    pts = np.array([[0.45, 0.0, 0.03], [0.46, 0.01, 0.03]])
    q = np.zeros((2, 6))
    T, idx = realized.T_base_workpiece_nominal, realized.workpiece.index
    white = white_reading_sigma_m(sc, q, pts, T, idx)
    assert math.isclose(white, math.hypot(sc.sensor.sigma_m, sc.sensor.resolution_m / math.sqrt(12)))
    assert reading_sigma_m(sc, q, pts, T, idx) > 2 * white  # the linearity band is the larger part


# --- extend and resume --------------------------------------------------------------------------


@pytest.mark.slow  # the default suite's five minutes
def test_raising_trials_extends_a_study_to_what_a_fresh_run_gives(tmp_path):
    small = points_study(tmp_path, POINTS, trials=6, name="small.toml")
    big = points_study(tmp_path, POINTS, trials=12, name="big.toml")
    run_study(small, tmp_path / "ext")
    extended = run_study(big, tmp_path / "ext", resume=True)
    assert extended["trials_resumed"] == 6 and extended["trials_run"] == 6
    run_study(big, tmp_path / "fresh")
    assert_same_table(pq.read_table(tmp_path / "ext" / RESULTS), pq.read_table(tmp_path / "fresh" / RESULTS))
    # and back: fewer trials reuse the first ones, the others stay in the batch files
    again = run_study(small, tmp_path / "ext", resume=True)
    assert again["trials"] == 6 and again["trials_run"] == 0


def _adaptive(tmp_path, name="a.toml", digits=1):
    body = POINTS + f'[adaptive]\ndigits = {digits}\nbatch = 10\n[grid]\n"points.noise_sigma_m" = [5e-6, 2e-5]\n'
    return points_study(tmp_path, body, trials=60, name=name)


@pytest.mark.slow
def test_an_adaptive_study_stopped_mid_run_and_resumed_equals_an_uninterrupted_one(tmp_path):
    study = _adaptive(tmp_path)
    whole = run_study(study, tmp_path / "whole")
    # A run stopped after its first rounds: the batch files of the later trials are not there yet.
    shutil.copytree(tmp_path / "whole", tmp_path / "cut")
    batches = sorted((tmp_path / "cut" / BATCH_DIR).iterdir())
    for p in batches[len(batches) // 2:]:
        p.unlink()
    (tmp_path / "cut" / RESULTS).unlink()
    resumed = run_study(study, tmp_path / "cut", resume=True)
    assert resumed["adaptive"] == whole["adaptive"]
    assert_same_table(pq.read_table(tmp_path / "cut" / RESULTS), pq.read_table(tmp_path / "whole" / RESULTS))


@pytest.mark.slow  # the default suite's five minutes
def test_an_adaptive_rule_not_met_exits_3_and_names_the_quantities(tmp_path):
    study_file = tmp_path / "a.toml"
    _adaptive(tmp_path, name="a.toml", digits=3)
    done = run_cli("study", study_file, "--out", tmp_path / "out", "--quiet")
    code, out, err = done.returncode, done.stdout, done.stderr
    assert code == 3, (out, err)
    assert "adaptive rule" in out and "NOT met" in out and "cell 0 after 60 trials" in out
    assert "warning: [adaptive] batch = 10" in err
    assert "**Warning**: 10 trials per batch" in (tmp_path / "out" / "report.md").read_text()


# --- the law of propagation beside the Monte Carlo ----------------------------------------------


def _fast_study(tmp_path, trials: int, extra: str = "", name: str = "f.toml"):
    from tests.helpers import SCENARIOS
    from twin.studies import load_study

    p = tmp_path / name
    p.write_text(f'name = "gum"\nseed = 21\nscenario = "{SCENARIOS / "s_surface.toml"}"\ntrials = {trials}\n'
                 'kind = "fast"\n[overrides.scan]\nmax_lines = 4\n[overrides.sensor]\n'
                 f'linearity_phase_deg = "random"\n{extra}')
    return load_study(p)


def test_fast_trials_carry_the_bound_and_the_law_of_propagation(tmp_path):
    from twin.studies.kinds import run_trial
    from twin.studies.trials import CRLB_COLUMNS, LPU_COLUMNS

    study = _fast_study(tmp_path, 2)
    rows = [run_trial(study, 0, t) for t in range(2)]
    for r in rows:
        crlb = np.array([r[c] for c in CRLB_COLUMNS])
        lpu = np.array([r[c] for c in LPU_COLUMNS])
        assert np.all(np.isfinite(lpu)) and np.all(lpu >= crlb - 1e-9)
        assert lpu[5] > 10 * crlb[5]  # v_z: the linearity curve's common offset dominates
    off = _fast_study(tmp_path, 1, "[overrides.noise]\nlinearity = false\n", name="off.toml")
    r = run_trial(off, 0, 0)
    np.testing.assert_allclose([r[c] for c in LPU_COLUMNS], [r[c] for c in CRLB_COLUMNS], rtol=1e-12)


@pytest.mark.slow
def test_with_the_linearity_drawn_per_trial_the_monte_carlo_agrees_with_the_law_of_propagation(tmp_path):
    """Every systematic effect of the scenario drawn per trial: the Monte Carlo u of each twist
    component matches the GUM law of propagation's, and the mean error is within 3 Monte Carlo
    standard errors of zero (no bias left when the effect is drawn, not fixed)."""
    from twin.studies.report import cell_stats
    from twin.studies.trials import TWIST_COLUMNS

    study = _fast_study(tmp_path, 200)
    run_study(study, tmp_path / "out", workers=2)
    s = cell_stats(pq.read_table(tmp_path / "out" / RESULTS), 0)
    for c in TWIST_COLUMNS:
        o = s["outputs"][c]
        assert abs(o.values[1] / s["u_lpu_"][c] - 1.0) < 0.2, (c, o.values[1], s["u_lpu_"][c])
        assert abs(o.values[0]) <= 3 * o.mc_se[0], (c, o.values[0], o.mc_se[0])
    report = (tmp_path / "out" / "report.md").read_text()
    assert "drawn per trial: a sensor unit" in report and "GUM validated (8)" in report


@pytest.mark.slow
def test_an_adaptive_study_killed_with_sigkill_and_resumed_equals_an_uninterrupted_one(tmp_path):
    """A real SIGKILL of ``twin study --workers 2`` while its adaptive rounds run (the rule not
    met before the maximum, so it runs long enough to be killed), then ``--resume``: the same
    table and the same adaptive verdict as one uninterrupted run."""
    import signal

    from tests.test_study import kill_after_batches
    from twin.studies.runner import batch_files

    study = _adaptive(tmp_path, name="k.toml", digits=3)
    whole = run_study(study, tmp_path / "whole")
    out = tmp_path / "killed"
    assert kill_after_batches(tmp_path / "k.toml", out, 2, "--workers", "2") == -signal.SIGKILL
    assert batch_files(out) and not (out / RESULTS).exists(), "the kill must land mid-run"
    done_before = sum(pq.read_table(p).num_rows for p in batch_files(out))
    assert 0 < done_before < pq.read_table(tmp_path / "whole" / RESULTS).num_rows
    resumed = run_study(study, out, resume=True)
    assert resumed["trials_resumed"] >= done_before
    assert resumed["adaptive"] == whole["adaptive"]
    assert_same_table(pq.read_table(out / RESULTS), pq.read_table(tmp_path / "whole" / RESULTS))


@pytest.mark.slow
def test_independent_studies_intervals_and_means_hold_within_their_monte_carlo_standard_errors():
    """The Bar's repeated studies, small: six independent runs of the shipped GUM study (every
    systematic effect drawn per trial) of 100 trials each, against their pooled trials. Their
    interval ends lie within 3 of their own Monte Carlo standard errors of the pooled 2.5 / 97.5 %
    points and their mean errors within 3 of zero, mostly (5 batches: a t of 4 degrees of freedom
    puts 96 % within 3); with the curve held fixed the mean is a bias far outside (the check's power)."""
    from benchmarks.bench_mc_coverage import run, standardized, within
    from tests.helpers import ROOT

    drawn, _ = run(ROOT / "studies" / "s_surface_gum.toml", 6, 100, 2)
    result = standardized(drawn)
    z_ends = np.concatenate([r["z_ends"] for r in result["components"].values()])
    z_mean = np.concatenate([r["z_mean"] for r in result["components"].values()])
    assert result["not_ok"] == 0
    assert within(z_ends, 3.0) >= 0.85 and within(z_mean, 3.0) >= 0.85, (z_ends, z_mean)
    assert 0.5 < np.std(z_ends) < 2.0


@pytest.mark.slow
def test_a_linearity_curve_held_fixed_shows_as_a_bias_of_the_mean(tmp_path):
    from benchmarks.bench_mc_coverage import run, standardized
    from tests.helpers import ROOT

    text = (ROOT / "studies" / "s_surface_gum.toml").read_text().replace(
        'linearity = { treatment = "per_trial", amplitude = "uniform" }', 'linearity = "fixed"')
    assert 'linearity = "fixed"' in text
    fixed = tmp_path / "fixed.toml"
    fixed.write_text(text.replace('"../scenarios/', f'"{ROOT / "scenarios"}/'))
    result = standardized(run(fixed, 2, 60, 2)[0])
    z = np.array([r["z_mean"] for r in result["components"].values()])  # (component, study)
    assert np.all(np.max(np.abs(z), axis=0) > 10.0), z  # phase 0: v_x, v_y and omega_z biased


def test_the_gum_validation_is_yes_no_or_undecided_by_the_monte_carlo_standard_error():
    from twin.studies.report import gum_validation

    o = jcgm101.summarize(np.random.default_rng(4).normal(0.0, 1.0, 400))
    tol, se_low = o.tolerance, o.mc_se[2]
    assert gum_validation(tol / 2, tol / 2, o) == "yes"
    assert gum_validation(tol + 3 * se_low, 0.0, o) == "no"
    assert gum_validation(tol + se_low, 0.0, o).startswith("undecided")


def test_the_mean_is_not_called_zero_without_standard_errors():
    from twin.studies.report import _bias_line
    from twin.studies.trials import TWIST_COLUMNS

    few = {"outputs": {c: jcgm101.summarize(np.full(12, 5.0) + np.arange(12)) for c in TWIST_COLUMNS}}
    assert "not tested" in _bias_line(few)[0]
    many = {"outputs": {c: jcgm101.summarize(np.random.default_rng(5).normal(3.0, 1.0, 200)) for c in TWIST_COLUMNS}}
    assert "beyond 3 Monte Carlo standard errors" in _bias_line(many)[0]

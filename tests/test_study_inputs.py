"""The uncertain inputs of a study (``[inputs]``): every error source per reading, drawn per trial
or fixed, its distribution checked, a robot-side draw fast trials cannot make refused, a value
never both fixed and drawn; the draws reproducible and of the stated width."""

import numpy as np
import pytest

from tests.helpers import SCENARIOS, run_cli
from twin.errors import TwinError
from twin.studies import inputs, load_study

S_SURFACE = SCENARIOS / "s_surface.toml"


def _study(tmp_path, body: str = "", kind: str = "fast", name: str = "s.toml"):
    p = tmp_path / name
    p.write_text(f'name = "inputs"\nseed = 5\nscenario = "{S_SURFACE}"\ntrials = 2\nkind = "{kind}"\n'
                 f"[overrides.scan]\nmax_lines = 4\n{body}")
    return p


# --- refused before any trial: one line, exit 2, nothing written -------------------------------


@pytest.mark.parametrize(("body", "words"), [
    ('[inputs]\ntime_skew = { treatment = "per_trial", width_s = -1e-3 }\n', "width is a number >= 0"),
    ('[inputs]\ntime_skew = { treatment = "per_trial", distribution = "gaussian" }\n', "not a known distribution"),
    ('[inputs]\nthermal = "per_trial"\n', "unknown input 'thermal'"),
    ('[inputs]\nlinearity = "per_reading"\n', "is one of per_trial, fixed, off"),
    ('[inputs]\nrepeatability = "per_trial"\n', "is one of per_reading, off"),
    ('[inputs]\nlinearity = { treatment = "per_trial", amplitude = "half" }\n', "one of uniform, band"),
    ('[inputs]\ntime_skew = { treatment = "fixed", width_s = 1e-3 }\n', "describe a per-trial draw"),
    ('[inputs]\nhand_eye = { treatment = "per_trial", width_deg = 1.0 }\n', "unknown key(s) inputs.hand_eye.width_deg"),
    # a factor both fixed and drawn
    ('[overrides.sensor]\nlinearity_phase_deg = 30.0\n', "both fixed and drawn"),
    ('[inputs]\nlinearity = "per_trial"\n[grid]\n"sensor.linearity_phase_deg" = [0.0, 90.0]\n',
     "both fixed and drawn"),
    ('[inputs]\ntime_skew = { treatment = "per_trial", width_s = 1e-3 }\n[grid]\n"noise.time_skew_s" = [0.0, 0.002]\n',
     "both fixed and drawn"),
    ('[overrides.sensor]\nlinearity_phase_deg = "random"\n[inputs]\nlinearity = "fixed"\n', "draws its phase"),
    # what a fast trial cannot draw, declared or by default
    ('[overrides.noise]\nkinematic_sigma_m = 1e-4\n', "the default for an unknown systematic effect"),
    ('[overrides.noise]\nhand_eye_error = { xyz = [0.0002, 0.0, 0.0], rpy_deg = [0.0, 0.0, 0.0] }\n'
     '[inputs]\nhand_eye = "per_trial"\n', "cannot draw the hand-eye error per trial"),
    ('[inputs]\npart_pose = "per_trial"\n', "cannot draw the part placement"),
])
def test_a_bad_input_is_refused_in_one_line_with_exit_2_and_nothing_written(tmp_path, body, words):
    study = _study(tmp_path, body)
    with pytest.raises(TwinError, match=None) as err:
        load_study(study)
    assert words in str(err.value) and "\n" not in str(err.value)
    done = run_cli("study", study, "--out", tmp_path / "out")
    assert done.returncode == 2 and words in done.stderr and "Traceback" not in done.stderr
    assert not (tmp_path / "out").exists()


def test_inputs_need_a_kind_with_error_sources(tmp_path):
    from tests.test_study_gum import POINTS
    from tests.test_study_kinds import points_study

    with pytest.raises(TwinError, match=r"\[inputs\] needs kind = 'fast' or 'full'"):
        points_study(tmp_path, POINTS + '[inputs]\nlinearity = "per_trial"\n')


# --- what a study's trials draw -----------------------------------------------------------------


def test_every_source_defaults_to_what_the_scenario_has_on_and_systematic_ones_are_drawn(tmp_path):
    study = load_study(_study(tmp_path, "[overrides.noise]\nencoder_sigma_rad = 1e-5\ntime_skew_s = 0.002\n"))
    r = study.cell_inputs(0)
    assert {k: v.treatment for k, v in r.items()} == {
        "repeatability": "per_reading", "quantization": "per_reading", "incidence": "per_reading",
        "encoder_noise": "per_reading", "linearity": "per_trial", "time_skew": "per_trial", "kinematics": "off",
        "hand_eye": "off", "part_pose": "fixed"}
    assert r["time_skew"].widths == (0.002,) and r["time_skew"].distribution == "uniform"
    assert r["linearity"].amplitude == "uniform"


def test_off_switches_the_source_off_in_the_cells_scenario(tmp_path):
    study = load_study(_study(tmp_path, '[inputs]\nlinearity = "off"\nquantization = "off"\n'))
    sc = study.cell_scenario(0)
    assert not sc.noise.linearity and not sc.noise.quantization and sc.noise.gaussian


def test_a_robot_side_effect_fixed_in_fast_trials_is_named_a_bias_in_the_report(tmp_path):
    from twin.studies.report import _inputs

    study = load_study(_study(tmp_path, '[overrides.noise]\nkinematic_sigma_m = 1e-4\n'
                                        '[inputs]\nkinematics = "fixed"\nlinearity = "fixed"\n'))
    text = "\n".join(_inputs(study))
    assert "| kinematic (link) errors | fixed (one draw for the study" in text
    assert "| linearity curve | fixed (phase 0 deg, amplitude the band)" in text
    assert "the correction is minus the estimate" in text


@pytest.mark.parametrize(("name", "std"), [("normal", 1.0), ("uniform", 1 / np.sqrt(3)), ("arcsine", 1 / np.sqrt(2)),
                                           ("triangular", 1 / np.sqrt(6))])
def test_each_distribution_has_mean_zero_and_the_standard_deviation_of_its_width(name, std):
    x = inputs.unit_draw(name, np.random.default_rng(3), 40_000)
    assert abs(np.mean(x)) < 0.02 and abs(np.std(x) / std - 1.0) < 0.02
    assert name == "normal" or np.max(np.abs(x)) <= 1.0


def test_a_trials_draw_is_reproducible_and_each_source_its_own(tmp_path):
    from twin.studies.trials import systematic_stream

    study = load_study(_study(tmp_path, '[inputs]\ntime_skew = { treatment = "per_trial", width_s = 0.001 }\n'
                                        'linearity = { treatment = "per_trial", amplitude = "band" }\n'))
    r = study.cell_inputs(0)
    a = inputs.draw(r, 1e-5, systematic_stream(5, 0, 3))
    b = inputs.draw(r, 1e-5, systematic_stream(5, 0, 3))
    c = inputs.draw(r, 1e-5, systematic_stream(5, 0, 4))
    assert a == b and a.linearity_phase_deg != c.linearity_phase_deg
    assert a.linearity_m == 1e-5 and abs(a.time_skew_s) <= 0.001 and a.link_errors is None
    draws = [inputs.draw(r, 1e-5, systematic_stream(5, 0, t)) for t in range(400)]
    phases = np.array([d.linearity_phase_deg for d in draws])
    assert 0.0 <= phases.min() < 30.0 and 330.0 < phases.max() < 360.0


def test_fast_trials_draw_the_curve_per_trial_and_the_propagation_follows_the_amplitude_law(tmp_path):
    """The LPU's linearity share is E[A^2] = band^2 / 3 of the band's edge when the amplitude is
    uniform on [0, band]; a fixed curve is a bias, not in the propagated uncertainty."""
    from twin.studies.kinds import run_trial
    from twin.studies.trials import CRLB_COLUMNS, LPU_COLUMNS

    def share(amplitude: str, treatment: str = "per_trial") -> tuple[np.ndarray, dict]:
        table = f'{{ treatment = "{treatment}", amplitude = "{amplitude}" }}' if treatment == "per_trial" \
            else f'"{treatment}"'
        st = load_study(_study(tmp_path, f"[inputs]\nlinearity = {table}\n", name=f"{amplitude}{treatment}.toml"))
        row = run_trial(st, 0, 0)
        lpu, crlb = np.array([row[c] for c in LPU_COLUMNS]), np.array([row[c] for c in CRLB_COLUMNS])
        return lpu**2 - crlb**2, row

    band, row_band = share("band")
    uniform, row_uniform = share("uniform")
    np.testing.assert_allclose(uniform, band / 3.0, rtol=2e-3)  # at each unit's own measured distances
    fixed, row_fixed = share("band", "fixed")
    np.testing.assert_allclose(fixed, 0.0, atol=1e-9)
    assert row_band["v_z_um"] != row_uniform["v_z_um"] != row_fixed["v_z_um"]  # different sensor units


def test_full_trials_put_the_robot_side_draws_into_the_truth(tmp_path):
    """Without running the loop: the truth of a full trial with the kinematic and hand-eye errors
    drawn per trial differs between trials; fixed, it is the scenario's (its own seed's draw)."""
    from twin.realize import realize
    from twin.scenario import load_scenario
    from twin.studies.full_trials import _with_drawn_truth
    from twin.studies.trials import systematic_stream

    body = ('[overrides.noise]\nkinematic_sigma_m = 1e-4\nkinematic_sigma_rad = 2e-4\n'
            'hand_eye_error = { xyz = [0.0002, 0.0, 0.0], rpy_deg = [0.1, 0.0, 0.0] }\n')
    drawn = load_study(_study(tmp_path, body, kind="full", name="d.toml"))
    fixed = load_study(_study(tmp_path, body + '[inputs]\nkinematics = "fixed"\nhand_eye = "fixed"\n', kind="full",
                              name="f.toml"))
    base = drawn.cell_scenario(0)
    realized = realize(base)

    def truth(study, trial):
        r = study.cell_inputs(0, base)
        sys = inputs.draw(r, base.sensor.linearity_m, systematic_stream(study.seed, 0, trial))
        other_seed = realize(load_scenario(study.cell_settings(0).scenario_path,
                                           {**study.cell_settings(0).overrides, "seed": 1000 + trial},
                                           machine="arm"), realized.workpiece.mesh)
        return _with_drawn_truth(other_seed, base, r, sys).truth

    t0, t1 = truth(drawn, 0), truth(drawn, 1)
    assert not np.allclose(t0.T_flange_sensor, t1.T_flange_sensor)
    # the sensor unit's curve is in the truth; the scenario, what the estimator reads, keeps the band
    assert t0.linearity_m < base.sensor.linearity_m and t0.linearity_phase_deg != t1.linearity_phase_deg
    assert not np.allclose(t0.link_errors[0].dpos_m, t1.link_errors[0].dpos_m)
    f0, f1 = truth(fixed, 0), truth(fixed, 1)
    np.testing.assert_array_equal(f0.T_flange_sensor, realized.truth.T_flange_sensor)
    np.testing.assert_array_equal(f1.link_errors[2].dpos_m, realized.truth.link_errors[2].dpos_m)


def test_the_report_says_what_each_cell_draws_where_it_differs_from_cell_0(tmp_path):
    from twin.studies.report import _inputs

    study = load_study(_study(tmp_path, '[grid]\noverrides = [{}, { noise = { time_skew_s = 0.002 } }]\n', kind="full"))
    text = "\n".join(_inputs(study))
    assert "Cell 1: time skew: drawn per trial: uniform, width 0.002 s." in text
    assert "Off: encoder noise, time skew" in text

"""Every random source of a reading in the fit check's sigma (twin.scan_uncertainty): the
encoders' noise propagated through the arm to each point along its normal, so a correct fit
under that noise is ``ok`` and within its covariance (it used to be 20/20 ``poor_fit``)."""

from __future__ import annotations

import numpy as np
import pyarrow.parquet as pq
import pytest

from algorithms.geometry.kinematics import dh_forward
from tests.helpers import SCENARIOS, scenario
from twin.robot import UR5E_DH
from twin.scan_uncertainty import encoder_variance_m2
from twin.studies import load_study
from twin.studies.runner import RESULTS, run_study

ENCODER_SIGMA_RAD = 5e-5   # about 28 um at the S-surface's points: 4.5 times the sensor's 6.1 um


def test_encoder_variance_matches_a_monte_carlo():
    """The propagated variance along a normal against 4,000 draws of joint noise through the
    true kinematics (points fixed to the flange, as a scan's are)."""
    rng = np.random.default_rng(4)
    q = np.array([[0.3, -1.2, 1.5, -1.9, -1.57, 0.2], [-0.5, -1.0, 1.2, -1.6, -1.5, 1.0]])
    p = np.array([[0.45, 0.12, 0.01], [0.40, -0.05, 0.02]])
    n = rng.normal(size=(2, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    predicted = np.sqrt(encoder_variance_m2(q, p, n, ENCODER_SIGMA_RAD))
    for i in range(2):
        F = dh_forward(q[i], UR5E_DH)
        p_flange = np.linalg.solve(F, np.append(p[i], 1.0))
        dq = rng.normal(0.0, ENCODER_SIGMA_RAD, (4000, 6))
        moved = dh_forward(q[i] + dq, UR5E_DH) @ p_flange
        along = (moved[:, :3] - p[i]) @ n[i]
        assert abs(np.std(along) / predicted[i] - 1.0) < 0.05, (np.std(along), predicted[i])


def test_a_fast_study_cell_with_encoder_noise_is_ok(tmp_path):
    study = tmp_path / "enc.toml"
    study.write_text(f"""
name = "encoder"
seed = 5
scenario = "{SCENARIOS / 's_surface.toml'}"
trials = 3
kind = "fast"
[overrides.scan]
max_lines = 4
[inputs]
linearity = "fixed"
[grid]
"noise.encoder_sigma_rad" = [{ENCODER_SIGMA_RAD}]
""")  # the linearity curve fixed (phase 0): the encoders' noise is what the test is about
    run_study(load_study(study), tmp_path / "out")
    rows = pq.read_table(tmp_path / "out" / RESULTS).to_pylist()
    assert [r["status"] for r in rows] == ["ok"] * 3
    # the residuals are the encoders' (about 28 um), the pose within its Cramer-Rao bound
    assert all(r["rmse_um"] > 20 for r in rows)
    assert all(r["mahalanobis2"] < 22.5 for r in rows)   # chi-square(6) at 99.9 %


@pytest.mark.slow  # the default suite's five minutes (issue 31): CI's slow tier runs it
def test_the_loop_under_encoder_noise_is_ok_and_within_its_covariance(tmp_path):
    from twin.cli.run import run_and_report
    from twin.io.output import Staged

    sc = scenario("s_surface", scan={"max_lines": 3}, path={"line_spacing_m": 0.02},
                  noise={"encoder_sigma_rad": ENCODER_SIGMA_RAD})
    out = tmp_path / "out"
    with Staged(out) as stage:
        _, report = run_and_report(sc, stage, None)
        stage.commit()
    loc = report["localization"]
    assert loc["status"] == "ok" and loc["trusted"], loc["message"]
    assert loc["sigma_um"] > 4 * 6.1 and loc["max_error_sigmas"] <= 3.0

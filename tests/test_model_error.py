"""Model error in document 000's simulation: a form error field of the stated RMS, drawn only
where a study asks for one, and refused out of range."""

from __future__ import annotations

import numpy as np
import pytest

from tests.helpers import ROOT
from twin.errors import TwinError
from twin.studies import load_study
from twin.studies.point_sets import form_error_m, measured_points


def test_the_form_error_field_has_the_stated_rms_and_wavelength():
    rng = np.random.default_rng(1)
    x = rng.uniform(-0.1, 0.1, (20000, 3))
    rms = [np.sqrt(np.mean(form_error_m(x, 2e-5, 0.05, np.random.default_rng(s)) ** 2)) for s in range(200)]
    assert np.mean(np.square(rms)) == pytest.approx(4e-10, rel=0.1)   # E[f^2] = A^2 over parts
    # smooth: points 1 mm apart differ by far less than the amplitude (2 pi A / lambda per metre)
    f = form_error_m(x, 2e-5, 0.05, np.random.default_rng(3))
    g = form_error_m(x + [0.001, 0.0, 0.0], 2e-5, 0.05, np.random.default_rng(3))
    assert np.max(np.abs(f - g)) < 2e-5 * 2 * np.pi * 0.001 / 0.05 * np.sqrt(2 * 8)


def test_no_form_error_leaves_the_noise_stream_alone():
    x = np.random.default_rng(2).uniform(-0.05, 0.05, (50, 3))
    n = np.tile([0.0, 0.0, 1.0], (50, 1))
    spec = {"noise_mean_m": 0.0, "noise_sigma_m": 5e-6, "noise_direction": "isotropic", "form_error_m": 0.0,
            "form_wavelength_m": 0.05}
    a = measured_points(x, n, np.eye(4), spec, np.random.default_rng(9))
    b = np.eye(4)[:3, :3] @ x.T
    assert np.allclose(a, b.T + 5e-6 * np.random.default_rng(9).standard_normal(x.shape))
    moved = measured_points(x, n, np.eye(4), {**spec, "form_error_m": 1e-4}, np.random.default_rng(9))
    assert np.std(moved[:, 2] - x[:, 2]) > 2e-5


def test_a_negative_form_error_is_refused(tmp_path):
    text = (ROOT / "studies" / "doc000_model_error.toml").read_text().replace('"../scenarios/', f'"{ROOT}/scenarios/')
    path = tmp_path / "me.toml"
    path.write_text(text.replace('"points.form_error_m" = [0.0, 5e-6, 2e-5]', '"points.form_error_m" = [-1e-6]'))
    with pytest.raises(TwinError, match=r"form_error_m.*must be a number in \[0, 0.001\]"):
        load_study(path)

"""Fast trials stand for full trials where only sensor-side factors vary.

A fast trial redraws the laser's errors on a cached noise-free scan and localizes from the
truth moved by 1 deg / 1 mm; a full trial runs the whole loop of ``twin run`` (scan simulated
at 1 ms, its own noise streams from a redrawn scenario seed, the loop's symmetric-aware
localization from the nominal pose). On the S-surface scanned over four lines with the
scenario's sensor model and no robot-side error (the scenario's defaults), both must give the
same distribution of the pose error (the six twist components) and of the residual: a
Kolmogorov-Smirnov two-sample test per column (Bonferroni over the seven columns), the means
within four standard errors and the spreads within a factor two. The same tests must reject
fast trials whose sensor sigma is four times the scenario's (their power).

The slow tier runs 150 fast trials per sigma against 8 full trials (about 90 s with 2 workers
on the 2-core machine); ``pytest -m long`` runs 300 against 200.
"""

import numpy as np
import pyarrow.parquet as pq
import pytest
from scipy.stats import ks_2samp

from tests.helpers import SCENARIOS
from twin.studies import load_study
from twin.studies.runner import RESULTS, run_study

COLUMNS = ("omega_x_urad", "omega_y_urad", "omega_z_urad", "v_x_um", "v_y_um", "v_z_um", "rmse_um")
ALPHA = 0.01 / len(COLUMNS)


def _run(tmp_path, name: str, kind: str, trials: int, seed: int, grid: str = "") -> dict:
    p = tmp_path / f"{name}.toml"
    p.write_text(f'name = "{name}"\nseed = {seed}\nscenario = "{SCENARIOS / "s_surface.toml"}"\n'
                 f'trials = {trials}\nkind = "{kind}"\n[overrides.scan]\nmax_lines = 4\n' + grid)
    run_study(load_study(p), tmp_path / name, workers=2)
    t = pq.read_table(tmp_path / name / RESULTS)
    cell = np.asarray(t.column("cell").to_pylist())
    status = np.asarray(t.column("status").to_pylist())
    assert set(status) == {"ok"}, set(status)
    return {c: np.asarray(t.column(c).to_pylist(), dtype=np.float64) for c in COLUMNS} | {"cell": cell}


def _compare(fast: dict, full: dict, cell: int) -> dict:
    """Per column: (KS p-value, mean difference in standard errors, std ratio full / fast)."""
    out = {}
    for c in COLUMNS:
        x, y = fast[c][fast["cell"] == cell], full[c]
        z = (y.mean() - x.mean()) / np.hypot(x.std(ddof=1) / np.sqrt(len(x)), y.std(ddof=1) / np.sqrt(len(y)))
        out[c] = (ks_2samp(x, y).pvalue, z, y.std(ddof=1) / x.std(ddof=1))
    return out


def _check(tmp_path, n_fast: int, n_full: int) -> tuple[dict, dict]:
    fast = _run(tmp_path, "fast", "fast", n_fast, 31, '[grid]\n"sensor.sigma_m" = [2e-6, 8e-6]\n')
    full = _run(tmp_path, "full", "full", n_full, 32)
    same, wider = _compare(fast, full, 0), _compare(fast, full, 1)
    for c, (p, z, ratio) in same.items():
        assert p > ALPHA and abs(z) < 4.0 and 0.5 < ratio < 2.0, (c, p, z, ratio)
    # power: four times the sigma is seen in the residual and in the spread of the pose error
    assert wider["rmse_um"][0] < 1e-6
    assert all(wider[c][2] < 0.5 for c in ("omega_z_urad", "v_x_um", "v_y_um")), wider
    return same, wider


@pytest.mark.slow
def test_fast_trials_match_full_trials_for_sensor_factors(tmp_path):
    _check(tmp_path, 150, 8)


@pytest.mark.long
def test_fast_trials_match_full_trials_for_sensor_factors_many(tmp_path):
    _check(tmp_path, 300, 200)

"""``twin study`` beyond scan trials: document 000's simulated point sets (``kind = "points"``),
several scenarios and override variants in one grid, the global methods and stages, the
subsampling rules, the Cramer-Rao columns, the report's plots and the adaptive rule of JCGM 101."""

import math
import sys

import numpy as np
import pyarrow.parquet as pq
import pytest

from tests.helpers import SCENARIOS
from tests.test_study import assert_same_table
from twin.errors import TwinError
from twin.studies import load_study
from twin.studies.adaptive import is_stable, numerical_tolerance
from twin.studies.kinds import run_trial
from twin.studies.runner import RESULTS, run_study
from twin.studies.spec import parse_study
from twin.studies.trials import start_pose

A_REGION = """region = [
  { box_min_m = [-0.026, -0.036, 0.0201], box_max_m = [0.046, 0.036, 0.06] },
  { normal = [1.0, 0.0, 0.0], cone_deg = 1.0 },
  { normal = [0.0, -1.0, 0.0], cone_deg = 1.0 },
]"""


def points_study(tmp_path, body: str, trials: int = 4, name: str = "s.toml"):
    p = tmp_path / name
    p.write_text(f'name = "pts"\nseed = 3\nscenario = "{SCENARIOS / "hemisphere_punch.toml"}"\n'
                 f'trials = {trials}\nkind = "points"\n' + body)
    return load_study(p)


def test_points_trials_recover_the_known_transform_at_the_bound(tmp_path):
    """Hong-Tan on 150 points of workpiece A with normal noise: every trial ok, the pose error
    consistent with the Cramer-Rao bound of its own points (mean xi^T C^-1 xi near 6)."""
    study = points_study(tmp_path, f'[points]\ncount = 150\nnoise_sigma_m = 5e-6\nnoise_direction = "normal"\n'
                                   f'{A_REGION}\n', trials=30)
    rows = [run_trial(study, 0, t) for t in range(study.trials)]
    assert all(r["status"] == "ok" and r["n_points"] == 150 for r in rows)
    m2 = np.array([r["mahalanobis2"] for r in rows])
    assert 3.0 < m2.mean() < 10.0, m2.mean()  # chi-square with 6 dof: mean 6, std of the mean 0.6
    assert max(r["translation_error_um"] for r in rows) < 30.0


def test_grid_layout_and_algorithm_4_keep_a_third_of_each_row(tmp_path):
    study = points_study(tmp_path, f'[points]\nlayout = "grid"\ngrid_rows = 5\ngrid_cols = 10\n{A_REGION}\n'
                                   '[grid]\n"localize.subsample" = ["none", "hammersley", "uniform", "random"]\n',
                         trials=1)
    n = {study.cells[c]["localize.subsample"]: run_trial(study, c, 0)["n_points"] for c in range(4)}
    assert 100 < n["none"] <= 150  # three 5 x 10 grids; a few nodes of the hemisphere's box miss it
    for rule in ("hammersley", "uniform", "random"):  # 3 of 10 columns per row
        assert 0.2 * n["none"] < n[rule] <= 45, (rule, n)


def test_mean_start_puts_the_model_centroid_at_the_points_mean():
    from algorithms.registration.global_search.multistart import model_centroid
    from twin.parts import make_workpiece

    mesh = make_workpiece("hemisphere_punch")
    rng = np.random.default_rng(0)
    T_true = np.eye(4)
    T_true[:3, 3] = [0.4, 0.1, 0.05]
    points = rng.normal(size=(50, 3)) * 0.01 + [0.45, 0.1, 0.06]
    T = start_pose(T_true, {"init_angle_deg": 90.0, "init_distance_m": 0.0, "init_position": "mean"}, points, mesh,
                   np.random.default_rng(1))
    np.testing.assert_allclose(T[:3, :3] @ model_centroid(mesh) + T[:3, 3], points.mean(axis=0), atol=1e-12)
    assert math.degrees(math.acos((np.trace(T[:3, :3]) - 1) / 2)) == pytest.approx(90.0)


def test_stages_global_methods_and_missing_peers(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "small_gicp", None)  # an import of it fails, as where it is not installed
    study = points_study(tmp_path, '[points]\ncount = 150\nnoise_sigma_m = 5e-6\n'
                                   'region = [{ normal = [0.0, 0.0, 1.0], cone_deg = 90.5 }]\n'
                                   '[grid]\n"localize.method" = ["pso_alone", "multistart", "small_gicp"]\n', trials=1)
    rows = {study.cells[c]["localize.method"]: run_trial(study, c, 0) for c in range(3)}
    assert rows["pso_alone"]["status"] == "ok" and rows["pso_alone"]["translation_error_um"] < 200.0
    assert rows["multistart"]["status"] == "ok" and rows["multistart"]["translation_error_um"] < 50.0
    assert rows["small_gicp"]["status"] == "not_installed" and math.isnan(rows["small_gicp"]["translation_error_um"])


@pytest.mark.slow
def test_several_scenarios_and_override_variants_in_one_grid(tmp_path):
    p = tmp_path / "v.toml"
    p.write_text(f'scenario = "{SCENARIOS / "hemisphere_punch.toml"}"\nkind = "points"\ntrials = 1\n'
                 f'[grid]\nscenario = ["{SCENARIOS / "hemisphere_punch.toml"}", "{SCENARIOS / "bottle_punch.toml"}"]\n'
                 'overrides = [{}, { workpiece = { true_pose = { xyz = [0.5, 0.1, 0.0], rpy_deg = [0, 0, 30] } } }]\n')
    study = load_study(p)
    assert study.n_cells == 4
    out = tmp_path / "out"
    run_study(study, out)
    table = pq.read_table(out / RESULTS)
    assert table.column("overrides").to_pylist()[1].startswith("{")  # a table-valued factor as JSON text
    assert set(table.column("status").to_pylist()) == {"ok"}
    assert (out / "report.md").read_text().count("## Cell") == 4


@pytest.mark.parametrize("body, words", [
    ('[localize]\nsubsample = "hammersley"\n', "layout = 'grid'"),
    ('[points]\ncolour = 1\n', "points.colour"),
    ('[points]\nregion = [{ normal = [0, 0, 0], cone_deg = 5 }]\n', "points.region"),
    ('[points]\nregion = [{ normal = [0, 0, -1], cone_deg = 1, box_min_m = [0, 0, 0.5], box_max_m = [1, 1, 1] }]\n',
     "selects no face"),
    ('[points]\nlayout = "grid"\ngrid_rows = 12\ngrid_cols = 10\n', "M <= N"),
    ('[grid]\n"localize.method" = ["simplex"]\n', "localize.method"),
    ('[grid]\noverrides = [3]\n', "overrides"),
    ('[grid]\nscenario = ["missing.toml"]\n', "missing.toml"),
    ('[adaptive]\ndigits = 5\n', "adaptive.digits"),
    ('[success]\nangle_deg = 0\n', "success.angle_deg"),
])
def test_bad_points_studies_are_refused_naming_the_key(tmp_path, body, words):
    with pytest.raises(TwinError, match=None) as err:
        points_study(tmp_path, body)
    assert words in str(err.value) and "\n" not in str(err.value)


def test_points_key_needs_the_points_kind(tmp_path):
    p = tmp_path / "f.toml"
    p.write_text(f'scenario = "{SCENARIOS / "s_surface.toml"}"\n[points]\ncount = 10\n')
    with pytest.raises(TwinError, match="kind = 'points'"):
        load_study(p)


def test_numerical_tolerance_and_stability_rule():
    assert numerical_tolerance(0.0123, 2) == pytest.approx(0.0005)  # u = 12 x 10^-3: delta = 10^-3 / 2
    assert numerical_tolerance(3.7, 1) == pytest.approx(0.5)
    assert numerical_tolerance(0.998, 1) == pytest.approx(0.5)  # rounds to 1 x 10^0
    rng = np.random.default_rng(0)
    same = [rng.normal(0.0, 1.0, 1000) for _ in range(10)]
    assert is_stable(same, 1)  # u ~ 1: delta 0.5; 2 s of the percentiles ~ 0.06
    assert not is_stable(same[:1], 1)  # one batch: never stable
    drifting = [rng.normal(10.0 * k, 1.0, 1000) for k in range(10)]
    assert not is_stable(drifting, 1)


@pytest.mark.slow
def test_adaptive_study_stops_when_stable_and_is_deterministic(tmp_path):
    body = ('[points]\ncount = 60\nnoise_sigma_m = 5e-6\nnoise_direction = "normal"\n' + A_REGION +
            '\n[adaptive]\ndigits = 1\nbatch = 10\n[grid]\n"points.noise_sigma_m" = [5e-6, 2e-5]\n')
    study = points_study(tmp_path, body, trials=200)
    one = run_study(study, tmp_path / "one", workers=1)
    two = run_study(study, tmp_path / "two", workers=2)
    for summary in (one, two):
        rounds = summary["adaptive"]
        assert all(r["trials"] % 10 == 0 and 20 <= r["trials"] <= 200 for r in rounds)
    assert one["adaptive"] == two["adaptive"]
    assert_same_table(pq.read_table(tmp_path / "one" / RESULTS), pq.read_table(tmp_path / "two" / RESULTS))
    report = (tmp_path / "one" / "report.md").read_text()
    assert "adaptive (JCGM 101" in report and ("was met" in report or "was NOT met" in report)
    assert (tmp_path / "one" / "crlb.png").stat().st_size > 0  # a sigma factor: the Cramer-Rao plot


def test_parse_keeps_defaults_of_an_old_study(tmp_path):
    """A study file written before the new keys gets the old behaviour and hash."""
    raw = {"scenario": str(SCENARIOS / "s_surface.toml"), "trials": 2}
    study = parse_study(raw, tmp_path)
    assert study.localize["init_position"] == "truth" and study.localize["subsample"] == "none"
    assert study.adaptive is None and study.kind == "fast"


def test_normals_trials_reproduce_document_004_on_scan_lines(tmp_path):
    """Triangulation across lines is within a degree on the B-spline lines; PCA with 8
    neighbours, all on the point's own line, is off by tens of degrees (the document's point)."""
    p = tmp_path / "n.toml"
    p.write_text(f'scenario = "{SCENARIOS / "s_surface.toml"}"\nkind = "normals"\ntrials = 1\n'
                 '[overrides.scan]\nmax_lines = 3\n[normals]\ncloud = "bspline"\n'
                 '[grid]\nnormals = [{ method = "triangulation" }, { method = "pca", k = 8 }]\n')
    study = load_study(p)
    tri, pca = (run_trial(study, c, 0) for c in range(2))
    assert tri["status"] == pca["status"] == "ok" and tri["n_points"] > 100
    assert tri["angle_rms_deg"] < 1.0 and tri["over_5deg_share"] == 0.0
    assert pca["angle_rms_deg"] > 30.0
    out = tmp_path / "out"
    run_study(study, out)
    assert "RMS angle" in (out / "report.md").read_text() and (out / "normals.png").stat().st_size > 0


@pytest.mark.parametrize("text, words", [
    ('kind = "normals"\n[adaptive]\ndigits = 1\n', "[adaptive]"),
    ('kind = "fast"\n[normals]\nk = 8\n', "kind = 'normals'"),
    ('kind = "normals"\n[grid]\nnormals = [{ method = "sobel" }]\n', "normals"),
    ('kind = "normals"\n[grid]\n"localize.method" = ["icp"]\n', "localize.method"),
    ('kind = "normals"\n[overrides.sensor]\nkind = "line"\n', "point sensor"),
])
def test_bad_normals_studies_are_refused(tmp_path, text, words):
    p = tmp_path / "n.toml"
    p.write_text(f'scenario = "{SCENARIOS / "s_surface.toml"}"\n' + text)
    with pytest.raises(TwinError) as err:
        load_study(p)
    assert words in str(err.value)

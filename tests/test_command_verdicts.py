"""A command's verdict covers what the user asked for (``twin.verdicts``): a run that dropped
part of its process path, replayed off its path or into the part, or a locate that missed a
planned point or whose uncertainty exceeds the scenario's tolerance, exits 3 and names the
failed check; checks against the truth are shown and never decide."""

from __future__ import annotations

import json

import pytest

from tests.helpers import SCENARIOS, run_cli, with_path_keys
from twin.cli.common import EXIT_OK, EXIT_UNTRUSTED
from twin.cli.run import exit_code
from twin.errors import TwinError
from twin.scenario import ToleranceSpec, load_scenario
from twin.verdicts import locate_checks, passed, run_checks


def _path_block(kept: int, planned: int, deviation_mm: float = 0.1, penetration_mm: float = 0.05,
                contacts: int = 0) -> dict:
    return {"dropped": [{"line": 0, "points": planned - kept, "position_m": [0, 0, 0], "reason": "collision: x"}]
            if kept < planned else [],
            "planned_points": planned, "kept_points": kept, "coverage": kept / planned,
            "verification": {"max_deviation_mm": deviation_mm, "tip_penetration_max_mm": penetration_mm,
                             "unintended_contacts": contacts}}


def _run_report(**cad) -> dict:
    return {"complete": True, "trusted": True, "localization": {"message": "converged", "max_error_sigmas": 1.2},
            "scan_path": _path_block(100, 100), "cad_path": _path_block(**({"kept": 100, "planned": 100} | cad))}


DEFAULTS = ToleranceSpec()


def _failed(report: dict, tol: ToleranceSpec = DEFAULTS) -> list[str]:
    return [c.name for c in run_checks(report, tol) if c.decides and not c.passed]


def test_a_sound_run_passes():
    report = _run_report()
    checks = run_checks(report, ToleranceSpec())
    assert passed(checks) and _failed(report) == []
    report["passed"] = passed(checks)
    assert exit_code(report) == EXIT_OK


@pytest.mark.parametrize("cad, failed", [
    ({"kept": 50, "planned": 100}, "cad_path: coverage"),             # bottle_punch: half the path dropped
    ({"deviation_mm": 0.41}, None),                                   # within the default 0.5 mm
    ({"deviation_mm": 0.6}, "cad_path: replay deviation"),
    ({"penetration_mm": 0.72}, "cad_path: tip penetration"),
    ({"contacts": 1}, "cad_path: no unintended contact"),
])
def test_each_process_tolerance_decides(cad, failed):
    report = _run_report(**cad)
    assert _failed(report) == ([] if failed is None else [failed])
    report["passed"] = passed(run_checks(report, ToleranceSpec()))
    assert exit_code(report) == (EXIT_OK if failed is None else EXIT_UNTRUSTED)


def test_the_scenario_sets_the_tolerances():
    report = _run_report(kept=90, planned=100)
    assert _failed(report) == ["cad_path: coverage"]
    assert _failed(report, ToleranceSpec(min_process_coverage=0.9)) == []


def test_checks_against_the_truth_are_shown_not_decided():
    report = _run_report()
    report["localization"]["max_error_sigmas"] = 4.0
    checks = run_checks(report, ToleranceSpec())
    shown = [c for c in checks if not c.decides]
    assert [c.passed for c in shown] == [False] and passed(checks)


def test_locate_fails_on_a_miss_and_on_its_uncertainty():
    fine = {"message": "converged", "std_translation_um": [1.0, 2.0, 1.5], "std_rotation_deg": [0.001] * 3,
            "max_error_sigmas": 1.0, "mahalanobis": 2.0}
    report = {"complete": True, "trusted": True, "fine": fine,
              "probing": {"points": 12, "hits": 12, "misses": [], "unintended_contacts": 0}}
    assert passed(locate_checks(report, ToleranceSpec()))
    tight = ToleranceSpec(max_position_uncertainty_m=3e-6)  # U = 2 x 2 um = 4 um > 3 um
    assert [c.name for c in locate_checks(report, tight) if not c.passed] == ["final position uncertainty"]
    report["probing"] |= {"hits": 11, "misses": [{"label": "P7"}]}
    assert [c.name for c in locate_checks(report, ToleranceSpec()) if not c.passed] == ["every planned point hit"]


@pytest.mark.parametrize("table, message", [
    ("min_process_coverage = 1.5", "tolerances.min_process_coverage = 1.5 is outside"),
    ("max_replay_deviation_m = -1e-4", "tolerances.max_replay_deviation_m"),
    ("max_position_uncertainty_m = 0", "tolerances.max_position_uncertainty_m"),
    ("coverage = 0.9", "unknown key(s) tolerances.coverage"),
])
def test_bad_tolerances_are_refused(tmp_path, table, message):
    scen = tmp_path / "bad.toml"
    scen.write_text((SCENARIOS / "s_surface.toml").read_text() + f"\n[tolerances]\n{table}\n")
    with pytest.raises(TwinError, match=message.replace("(", r"\(").replace(")", r"\)")):
        load_scenario(scen)


def test_a_run_outside_its_tolerance_exits_3_and_names_the_check(tmp_path):
    """The whole command: a short S-surface run held to a 10 um replay deviation (its servo lag
    is about 0.1 mm) finishes, writes everything, and fails on that check."""
    text = (SCENARIOS / "s_surface.toml").read_text().replace('line_axis = "x"', 'line_axis = "x"\nmax_lines = 3', 1)
    text = with_path_keys(text, {"line_spacing_m": "0.02"})
    scen = tmp_path / "tight.toml"
    scen.write_text(text + "\n[tolerances]\nmax_replay_deviation_m = 1e-5\n")
    out = tmp_path / "out"
    r = run_cli("run", scen, "--out", out)
    assert r.returncode == EXIT_UNTRUSTED, r.stderr
    verdict = r.stdout.splitlines()[0]
    assert verdict.startswith("verdict") and "FAIL" in verdict and "replay deviation" in verdict
    report = json.loads((out / "report.json").read_text())
    assert report["complete"] and report["trusted"] and not report["passed"]
    failed = {c["name"] for c in report["checks"] if c["decides"] and not c["passed"]}
    assert failed and all(name.endswith("replay deviation") for name in failed)
    assert "Verdict: <span class=fail>FAIL" in (out / "report.html").read_text()

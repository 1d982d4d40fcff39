"""The documentation cannot drift from the code or the reports.

- every number typed in the README and the docs is found in the file its sentence cites (a
  planted wrong number fails);
- the reference pages are generated from the validators and the parsers: a key added to a
  validator appears without editing a page, and every key has a meaning on its format page;
- the README stays short and keeps the two set-up commands CI runs;
- a report older than the code it measured is marked.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "docs" / "_tools"))

import hooks  # noqa: E402
import number_check  # noqa: E402
import report_stamps  # noqa: E402

from twin import scenario as scenario_module  # noqa: E402
from twin.cli import COMMANDS, build_parser  # noqa: E402
from twin.cli.reference import commands_markdown  # noqa: E402
from twin.schema import keys_markdown, scenario_keys, study_keys  # noqa: E402
from twin.studies import spec  # noqa: E402

TEST_COMMAND = 'python3 -m venv .venv && . .venv/bin/activate && pip install -e ".[test]" && pytest'
MAIN_COMMAND = "python3 -m venv .venv && . .venv/bin/activate && pip install -e . && twin demo"


# --- numbers ---------------------------------------------------------------------------------


def test_every_number_in_the_readme_and_the_docs_is_found_in_what_it_cites():
    problems = number_check.check_all()
    assert not problems, "\n".join(map(str, problems))


def _page(tmp_path: Path, text: str) -> list[number_check.Problem]:
    page = tmp_path / "page.md"
    page.write_text(text, encoding="utf-8")
    return number_check.check_page(page)


@pytest.fixture
def report(tmp_path: Path) -> Path:
    path = tmp_path / "results_fixture.md"
    path.write_text("| case | rms |\n|---|---|\n| S-surface | 3.62 um |\n| sigma | 0.000005 m |\n", encoding="utf-8")
    return path


def test_a_planted_wrong_number_fails(tmp_path, report):
    wrong = _page(tmp_path, f"The residual RMS is 3.71 um ([the report]({report.name})).\n")
    assert [p.number for p in wrong] == ["3.71"]
    assert wrong[0].cited == (str(report),) and "3.71 is not in" in str(wrong[0])


def test_a_number_found_in_the_cited_report_passes_in_its_units(tmp_path, report):
    assert _page(tmp_path, f"The residual RMS is 3.62 um and sigma 5 um ([the report]({report.name})).\n") == []


def test_an_uncited_number_fails_and_a_name_does_not(tmp_path):
    problems = _page(tmp_path, "Document 001 and Algorithm 5 (eq. 11) on a UR5e run 17 % faster.\n")
    assert [p.number for p in problems] == ["17"]


def test_code_and_page_sources_are_honoured(tmp_path, report):
    text = f"<!-- sources: {report} -->\n\nThe band is 3.62 um wide; `--trials 99` is code.\n"
    assert _page(tmp_path, text) == []
    missing = _page(tmp_path, "<!-- sources: no/such/file.toml -->\n\nText.\n")
    assert missing and "missing file" in missing[0].text


# --- generated reference pages ---------------------------------------------------------------


def test_a_key_added_to_the_scenario_validator_appears_in_the_reference(monkeypatch):
    original = scenario_module._parse_noise

    def with_planted_key(s):
        s.number("planted_drift_m", 0.25, 0.0, 1.0)
        return original(s)

    monkeypatch.setattr(scenario_module, "_parse_noise", with_planted_key)
    keys = scenario_keys()
    planted = [k for k in keys if k.key == "planted_drift_m"]
    assert len(planted) == 1 and planted[0].table == "noise" and planted[0].default == "0.25"
    assert "`planted_drift_m` | number | 0.25 | [0, 1]" in keys_markdown(keys)


def test_a_key_added_to_the_study_validator_appears_in_the_reference(monkeypatch):
    monkeypatch.setitem(spec.SUCCESS_KEYS, "planted_rate", (0.5, lambda v: True, "a number in [0, 1]"))
    assert "| `planted_rate` | 0.5 | a number in [0, 1] |" in keys_markdown(study_keys())


def test_the_scenario_reference_lists_what_the_validator_reads():
    keys = {(k.table, k.key): k for k in scenario_keys()}
    assert keys[("sensor", "sigma_m")].default == "2e-06"
    assert keys[("workpiece", "true_pose")].default == "required"
    assert keys[("scan.passes[]", "edge_margin_m")].kind == "number"
    assert ("cmm", "styli") in keys and ("probe", "points") in keys
    assert scenario_module.KEY_LOG is None  # the validator's notes are off again


def test_every_key_the_validators_accept_has_a_meaning_on_its_format_page():
    docs = ROOT / "docs" / "concepts"
    for keys, page in ((scenario_keys(), docs / "scenario-files.md"), (study_keys(), docs / "study-files.md")):
        meanings = hooks.meanings(page)
        missing = [f"{k.table}.{k.key}" for k in keys if (k.table, k.key) not in meanings]
        assert not missing, f"{page.name} does not describe {missing}"


def test_the_command_reference_holds_every_command_and_option():
    text = commands_markdown()
    parser = build_parser()
    for name in COMMANDS:
        assert f"`twin {name}`" in text
    sub = next(a for a in parser._actions if a.choices and "run" in a.choices)
    for flag in ("--export-urscript", "--place-base", "--strict"):
        assert flag in " ".join(o for a in sub.choices["run"]._actions for o in a.option_strings)
        assert f"`{flag}`" in text
    assert str(ROOT) not in text  # defaults shown relative to the repository


def test_the_readme_is_short_and_keeps_the_two_set_up_commands():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(readme.splitlines()) <= 150
    assert TEST_COMMAND in readme and MAIN_COMMAND in readme
    assert TEST_COMMAND in (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    listed = re.findall(r"^\| `twin ([\w-]+)` \|", readme, re.MULTILINE)
    assert sorted(listed) == sorted(COMMANDS)


# --- report stamps ---------------------------------------------------------------------------


def _history() -> bool:
    try:
        done = subprocess.run(["git", "rev-parse", "--is-shallow-repository"], cwd=ROOT, capture_output=True,
                              text=True, check=False)
    except OSError:
        return False
    return done.returncode == 0 and done.stdout.strip() == "false"


@pytest.mark.skipif(not _history(), reason="needs the repository's full git history")
def test_a_report_older_than_the_code_it_measured_is_marked(tmp_path):
    first = report_stamps.git("rev-list", "--max-parents=0", "HEAD").split()[0][:7]
    old_report = tmp_path / "old.md"
    old_report.write_text(f"# A report\n\nCommand: `python -m benchmarks.bench_scan`; commit {first}.\n")
    old = report_stamps.stamp(old_report, ["twin/schema.py"])  # written long after the first commit
    assert old.commit == first and old.stamped and old.changed_since >= 1
    assert "benchmarks/bench_scan.py" in old.measured  # the benchmark its command names
    assert "Older than the code it measured" in report_stamps.stamp_markdown(old, "old.md")
    head = report_stamps.git("rev-parse", "--short", "HEAD")
    new_report = tmp_path / "new.md"
    new_report.write_text(f"# A report\n\nMade at commit {head}.\n")
    fresh = report_stamps.stamp(new_report, ["twin/schema.py"])
    assert fresh.changed_since == 0
    assert "unchanged since" in report_stamps.stamp_markdown(fresh, "new.md")


@pytest.mark.skipif(not _history(), reason="needs the repository's full git history")
def test_a_report_without_a_commit_is_stamped_with_the_commit_that_wrote_it():
    report = ROOT / "benchmarks" / "results_closest_point.md"  # names no commit
    s = report_stamps.stamp(report, [])
    assert s.commit and not s.stamped
    assert s.commit == report_stamps.git("log", "-1", "--format=%h", "--", str(report.relative_to(ROOT)))[:7]


def test_an_included_report_keeps_its_text_under_its_stamp():
    text = hooks.include_report("benchmarks/results_dmis.md", ["algorithms/probing/dmis"], depth=1)
    body = (ROOT / "benchmarks" / "results_dmis.md").read_text(encoding="utf-8")
    first_row = next(line for line in body.splitlines() if line.startswith("| "))
    assert first_row in text
    assert text.index("benchmarks/results_dmis.md") < text.index(first_row)
    assert re.search(r"^### ", text, re.MULTILINE)  # its title two levels down

"""The architecture's promises that lint-imports cannot see: the stage runner names the stage
that failed, only the evaluation reads the truth, and the library's front door refuses bad
input with the same one-line errors as the commands."""

import ast
from pathlib import Path

import pytest

import twin
from algorithms.errors import AlgorithmError
from twin.errors import TwinError
from twin.stages import StageFailed, StageRunner

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "scenarios"

# What only the simulator knows: the realized truth, the truth a scan or a probe hit carries
# along for evaluation, the CMM part's true placement.
TRUTH_NAMES = {"truth", "T_base_workpiece_true", "T_world_part_true", "d_true"}
# The simulator makes the truth and uses it (the true cell, the rollout, the sensors' ideal
# rays, the probe's trigger); evaluate.py is the one reader on the tool's side.
SIMULATOR = {"realize.py", "cell.py", "scan.py", "probing.py", "cmm_machine.py", "evaluate.py",
             "sensors/base.py", "sensors/laser.py", "sensors/laser_line.py", "sensors/laser_point.py",
             "sensors/touch_probe.py", "env/base.py"}


def test_a_stage_that_fails_is_named_by_the_runner():
    runner = StageRunner()

    def stages():
        with runner.stage("scan"):
            pass
        with runner.stage("localize"):
            raise AlgorithmError("points must be (N, 3)")

    runner.run(stages)
    assert runner.failure == ("localize", "points must be (N, 3)")
    assert set(runner.timings_s) == {"scan_s"}  # a stage that failed has no time


def test_a_stage_failure_raised_inside_keeps_its_own_stage_and_other_errors_propagate():
    runner = StageRunner()

    def stages():
        with runner.stage("probe"):
            raise StageFailed("fine", "only 3 of 12 planned points were hit")

    runner.run(stages)
    assert runner.failure == ("fine", "only 3 of 12 planned points were hit")
    with pytest.raises(ZeroDivisionError):  # a bug is not a stage failure
        StageRunner().run(lambda: 1 / 0)


def _truth_reads(path: Path) -> list[str]:
    tree = ast.parse(path.read_text())
    return [f"{path.relative_to(ROOT)}:{n.lineno} .{n.attr}" for n in ast.walk(tree)
            if isinstance(n, ast.Attribute) and n.attr in TRUTH_NAMES]


def test_only_the_evaluation_and_the_simulator_read_the_truth():
    twin_dir = ROOT / "twin"
    reads = [r for p in sorted(twin_dir.rglob("*.py")) if p.relative_to(twin_dir).as_posix() not in SIMULATOR
             for r in _truth_reads(p)]
    assert reads == []


def test_the_truth_check_sees_a_read():
    assert _truth_reads(ROOT / "twin" / "evaluate.py")  # the one reader is found by the same check


def test_the_front_door_refuses_a_missing_scenario_in_one_line():
    with pytest.raises(TwinError) as exc:
        twin.run(SCENARIOS / "no_such_scenario.toml")
    assert "\n" not in str(exc.value) and "no_such_scenario.toml" in str(exc.value)


def test_the_front_door_refuses_locate_without_a_probe():
    with pytest.raises(TwinError, match=r"has no \[probe\] table"):
        twin.locate(SCENARIOS / "cube.toml")


def test_the_front_door_refuses_a_bad_study_scheduler(tmp_path):
    with pytest.raises(TwinError, match="--scheduler must be"):
        twin.study(ROOT / "studies" / "sensor_sigma.toml", tmp_path / "out", scheduler="carrier-pigeon")


# Modules allowed past MAX_MODULE_LINES, each for the reason given beside it.
DECLARATIVE_MODULES = {
    "twin/scenario.py": "the scenario file's schema: a documented dataclass per TOML table and its parser",
}
MAX_MODULE_LINES = 800
MAX_FUNCTION_LINES = 100


def _sources():
    for package in ("twin", "algorithms"):
        yield from sorted((ROOT / package).rglob("*.py"))


def test_no_module_is_too_long_to_read():
    long = {p.relative_to(ROOT).as_posix(): n for p in _sources()
            if (n := len(p.read_text().splitlines())) > MAX_MODULE_LINES}
    assert set(long) <= set(DECLARATIVE_MODULES), long


def test_no_function_is_longer_than_a_screenful_or_two():
    long = [f"{p.relative_to(ROOT)}:{n.lineno} {n.name} ({n.end_lineno - n.lineno + 1} lines)"
            for p in _sources() for n in ast.walk(ast.parse(p.read_text()))
            if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)
            and n.end_lineno - n.lineno + 1 > MAX_FUNCTION_LINES]
    assert long == []

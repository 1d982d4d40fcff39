"""Robot-side Monte Carlo: how fast full trials run (``studies/robot_errors.toml``, the whole
loop of ``twin run`` per trial) and whether they still give the committed report's numbers.

Runs ``twin study studies/robot_errors.toml --workers W`` into a temporary folder, timing the
whole command (wall clock), and compares its ``report.md`` with the committed one
(``studies/reports/robot_errors/report.md``) line by line, the localization times aside (the
only column that is a timing). Then splits one trial into its stages (``timings_s`` of
:func:`twin.workflows.loop.run`) in this process.

    python -m benchmarks.bench_trials [--workers 2] [--out benchmarks/results_trials.md]
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tests.helpers import ROOT, commit_stamp

STUDY = ROOT / "studies" / "robot_errors.toml"
COMMITTED = ROOT / "studies" / "reports" / "robot_errors" / "report.md"
# the report's timing columns and sentences: left out of the comparison
_TIMING = re.compile(r"median (localization )?time [0-9.e+]+ ms|\| [0-9.e+]+ \|$")


def _without_timings(text: str) -> list[str]:
    return [_TIMING.sub("", line) for line in text.splitlines()]


def _study(workers: int) -> tuple[float, int, list[str]]:
    """Wall time of the study, its trial count, and the report lines that differ from the committed one."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "robot_errors"
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "twin.cli", "study", str(STUDY), "--out", str(out), "--workers",
                        str(workers)], check=True, capture_output=True, cwd=ROOT)
        wall_s = time.perf_counter() - t0
        new = _without_timings((out / "report.md").read_text())
    old = _without_timings(COMMITTED.read_text())
    differ = [f"{a!r} -> {b!r}" for a, b in zip(old, new, strict=False) if a != b]
    if len(old) != len(new):
        differ.append(f"{len(old)} lines -> {len(new)} lines")
    n_trials = sum(int(m) for m in re.findall(r"^(\d+) trials, status", "\n".join(new), re.M))
    return wall_s, n_trials, differ


def _stages() -> dict[str, float]:
    """One trial's stages [s] (cell 0, trial 0 of the study), this process, after a warm-up trial."""
    from twin.realize import realize
    from twin.scenario import load_scenario, merge_tables
    from twin.studies.spec import load_study
    from twin.studies.trials import full_trial, trial_streams
    from twin.workflows.loop import run as run_loop

    study = load_study(STUDY)
    full_trial(study, 0, 1)  # imports, numba's cache, the part
    settings = study.cell_settings(0)
    _, rng_err, _, _ = trial_streams(study.seed, 0, 0)
    seed = int(rng_err.integers(0, 2**63 - 1))
    scenario = load_scenario(settings.scenario_path, merge_tables(settings.overrides, {"seed": seed}), machine="arm")
    t0 = time.perf_counter()
    result = run_loop(realize(scenario))
    timings = dict(result.timings_s)
    timings["the whole trial"] = time.perf_counter() - t0
    return timings


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results_trials.md"))
    args = ap.parse_args(argv)
    wall_s, n_trials, differ = _study(args.workers)
    stages = _stages()
    text = [
        "# Full trials of studies/robot_errors.toml",
        "",
        f"Command: `python -m benchmarks.bench_trials --workers {args.workers}`; commit {commit_stamp()}; "
        f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
        f"load average {os.getloadavg()[0]:.2f} at the end.",
        "",
        f"`twin study studies/robot_errors.toml --workers {args.workers}`: {n_trials} full trials in {wall_s:.1f} s "
        f"({n_trials / wall_s:.2f} trials/s, the start-up and the report included).",
        "",
        "Its report against the committed `studies/reports/robot_errors/report.md`, timings aside: "
        + ("the same numbers." if not differ else f"{len(differ)} lines differ:"),
        *[f"- {d}" for d in differ[:20]],
        "",
        "One trial's stages in this process (cell 0, after a warm-up trial), seconds:",
        "",
        "| stage | [s] |",
        "|---|---|",
        *[f"| {k} | {v:.2f} |" for k, v in stages.items()],
    ]
    Path(args.out).write_text("\n".join(text) + "\n")
    print("\n".join(text))
    return 0


if __name__ == "__main__":
    sys.exit(main())

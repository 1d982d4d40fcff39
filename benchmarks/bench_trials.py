"""Robot-side Monte Carlo: how fast full trials run (``studies/robot_errors.toml``,
:mod:`twin.studies.full_trials`) and whether they still give the committed report's numbers.

Runs ``twin study studies/robot_errors.toml --workers W`` into a temporary folder, timing the
whole command (wall clock), then the same study with ``--trials`` per cell (the start-up
spread over more trials), and compares the first one's ``report.md`` with the committed one
(``studies/reports/robot_errors/report.md``) line by line, the localization times aside (the
only column that is a timing). Then times one trial in this process: the whole loop of
``twin run`` on its realization (what a full trial was before it shared anything) and the
full trial on a shared truth and on a truth of its own.

    python -m benchmarks.bench_trials [--workers 2] [--trials 40] [--out benchmarks/results_trials.md]
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


def _study(workers: int, trials: int | None) -> tuple[float, int, list[str] | None]:
    """Wall time of the study (with ``trials`` per cell where given), its trial count, and the
    report lines that differ from the committed one (None where the trial count differs from it)."""
    with tempfile.TemporaryDirectory() as tmp:
        study = STUDY
        if trials is not None:
            text = STUDY.read_text().replace('scenario = "../scenarios/', f'scenario = "{ROOT}/scenarios/')
            study = Path(tmp) / STUDY.name
            study.write_text(re.sub(r"^trials = \d+$", f"trials = {trials}", text, flags=re.M))
        out = Path(tmp) / "robot_errors"
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "twin.cli", "study", str(study), "--out", str(out), "--workers",
                        str(workers)], check=True, capture_output=True, cwd=ROOT)
        wall_s = time.perf_counter() - t0
        new = _without_timings((out / "report.md").read_text())
    n_trials = sum(int(m) for m in re.findall(r"^(\d+) trials \(ok", "\n".join(new), re.M))
    if trials is not None:
        return wall_s, n_trials, None
    old = _without_timings(COMMITTED.read_text())
    differ = [f"{a!r} -> {b!r}" for a, b in zip(old, new, strict=False) if a != b and not a.startswith("Made with")]
    if len(old) != len(new):
        differ.append(f"{len(old)} lines -> {len(new)} lines")
    return wall_s, n_trials, differ


def _per_trial() -> dict[str, float]:
    """One trial's wall time [s] in this process, after a warm-up trial of each cell: the whole
    loop on the trial's realization (what a full trial was before it shared anything), and the
    full trial as the study runs it, on a truth simulated before (cell 0) and on a truth of its
    own (cell 3: the kinematic errors drawn per trial: a true cell and a rollout per trial)."""
    from tests.test_full_trials import plain_full_trial
    from twin.studies.full_trials import full_trial
    from twin.studies.spec import load_study

    study = load_study(STUDY)
    full_trial(study, 0, 0)  # imports, numba's cache, the part, the plan, cell 0's truth
    full_trial(study, 3, 0)
    out = {}
    for name, run in (("the whole loop (twin run's pipeline), cell 0", lambda: plain_full_trial(study, 0, 1)),
                      ("full trial, a truth simulated before (cell 0)", lambda: full_trial(study, 0, 1)),
                      ("full trial, a truth of its own (cell 3)", lambda: full_trial(study, 3, 1))):
        t0 = time.perf_counter()
        run()
        out[name] = time.perf_counter() - t0
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--trials", type=int, default=40, help="trials per cell of the longer run (default 40)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results_trials.md"))
    args = ap.parse_args(argv)
    wall_s, n_trials, differ = _study(args.workers, None)
    long_s, long_trials, _ = _study(args.workers, args.trials)
    per_trial = _per_trial()
    text = [
        "# Full trials of studies/robot_errors.toml",
        "",
        f"Command: `python -m benchmarks.bench_trials --workers {args.workers} --trials {args.trials}`; commit "
        f"{commit_stamp()}; {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
        f"load average {os.getloadavg()[0]:.2f} at the end.",
        "",
        f"`twin study studies/robot_errors.toml --workers {args.workers}`: {n_trials} full trials in {wall_s:.1f} s "
        f"({n_trials / wall_s:.2f} trials/s, the start-up and the report included).",
        "",
        f"The same study with {args.trials} trials per cell: {long_trials} full trials in {long_s:.1f} s "
        f"({long_trials / long_s:.2f} trials/s).",
        "",
        "Its report against the committed `studies/reports/robot_errors/report.md`, timings and the commit aside: "
        + ("the same numbers." if not differ else f"{len(differ)} lines differ:"),
        *[f"- {d}" for d in (differ or [])[:20]],
        "",
        "One trial in this process (after a warm-up trial of each cell), seconds:",
        "",
        "| trial | [s] |",
        "|---|---|",
        *[f"| {k} | {v:.2f} |" for k, v in per_trial.items()],
    ]
    Path(args.out).write_text("\n".join(text) + "\n")
    print("\n".join(text))
    return 0


if __name__ == "__main__":
    sys.exit(main())

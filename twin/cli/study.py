"""``twin study STUDY.toml --out DIR``: a Monte Carlo / benchmark study (``twin.studies``).

Runs every trial of the study's grid not yet in ``DIR`` on one process, a process pool
(``--workers N``) or Dask (``--scheduler dask``: a LocalCluster of N workers; ``tcp://HOST:PORT``:
a running scheduler), streams the results to ``DIR/results/`` in batches, then writes
``DIR/results.parquet`` (sorted by cell and trial) and ``DIR/report.md`` with its plot.
``--resume`` continues a study whose run was stopped, or extends one whose ``trials`` or
``[adaptive]`` were raised; the results do not depend on the worker count, the scheduler or the
resume. Exit 3 when an adaptive rule was not met within ``trials`` (stdout names the cells and
quantities).
"""

from __future__ import annotations

import argparse

from twin.cli import COMMANDS
from twin.cli.common import EXIT_UNTRUSTED, add_print_options, positive_int, print_result, progress
from twin.studies.runner import progress_printer, run_study
from twin.studies.spec import GUIDE_BATCH, load_study


def add_parser(sub) -> None:
    p = sub.add_parser(
        "study", help=COMMANDS["study"],
        description="Run the study file's trials (a grid of scenario and localization factors, trials per "
                    "cell) and write DIR/results.parquet, DIR/report.md and its plot. Results stream to "
                    "DIR/results/ in batches; --resume skips the finished trials. The same study gives the "
                    "same table whatever the workers, the scheduler or the resume.",
    )
    p.add_argument("study", help="study TOML file (its keys: docs/concepts/study-files.md)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--workers", type=positive_int, default=1,
                   help="worker processes (default 1: this process; with --scheduler dask the cluster's size); "
                        "no more are started than the machine has cores or trials are left")
    p.add_argument("--scheduler", default="local",
                   help="local (a process pool, default), dask (start a Dask LocalCluster) or "
                        "tcp://HOST:PORT (a running Dask scheduler)")
    p.add_argument("--resume", action="store_true",
                   help="continue the same study in DIR, running only the trials not yet finished")
    p.add_argument("--force", action="store_true", help="replace an existing DIR whole (start over)")
    add_print_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    study = load_study(args.study)
    if study.adaptive and study.adaptive["batch"] < GUIDE_BATCH:
        progress("study", f"warning: [adaptive] batch = {study.adaptive['batch']}, fewer trials per batch than "
                          f"JCGM 101 7.9.4 asks ({GUIDE_BATCH}); the report says so")
    summary = run_study(study, args.out, workers=args.workers, scheduler=args.scheduler, resume=args.resume,
                        force=args.force, on_progress=progress_printer(args.quiet))
    rows = [("study", f"{summary['study']} ({summary['cells']} cell(s) x {summary['trials_per_cell']} trial(s))"),
            ("trials", f"{summary['trials']} ({summary['trials_run']} run now, {summary['trials_resumed']} resumed)"),
            ("ok", f"{summary['trials_ok']} of {summary['trials']}"),
            ("time", f"{summary['seconds']:.1f} s"),
            ("results", summary["results"]),
            ("report", summary["report"])]
    unmet = [(c, r["trials"], r["unstable"]) for c, r in enumerate(summary.get("adaptive") or []) if not r["stable"]]
    if unmet:
        rows.append(("adaptive rule", "NOT met: " + "; ".join(
            f"cell {c} after {n} trials ({', '.join(q)})" for c, n, q in unmet)))
    print_result(args, summary, rows)
    return EXIT_UNTRUSTED if unmet else 0

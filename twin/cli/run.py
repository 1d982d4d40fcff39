"""``twin run SCENARIO --out DIR [--rrd FILE] [--force]``: scan -> localize -> path -> IK -> replay -> report."""

from __future__ import annotations

import argparse
import json
import time
from functools import partial
from pathlib import Path

from twin import pipeline
from twin.cli.common import add_output_options, checked_outputs, progress
from twin.io.output import Staged
from twin.io.report import headline, run_report, write_json
from twin.realize import realize
from twin.scenario import Scenario, load_scenario

REPORT_FILE = "report.json"


def add_parser(sub) -> None:
    p = sub.add_parser(
        "run", help="scan, localize, plan the process paths, solve IK, replay and verify",
        description="Scan the part, localize it, make a process path from the scan (document 004) "
                    "and one from the CAD model moved by the estimate (document 003), solve the joints "
                    "with mink, replay both in the true cell at 1 ms and write DIR/report.json. The "
                    "folder (and the recording) appear when everything is written.",
    )
    p.add_argument("scenario", help="scenario TOML file")
    add_output_options(p, "output folder for report.json (created; refused if it exists, unless --force)")
    p.set_defaults(run=run)


def run_and_report(scenario: Scenario, stage: Staged, rrd: Path | None, command: str = "run"):
    """Run the loop and write ``report.json`` (and the recording) into the staged folder;
    returns (result, report). The caller commits the stage."""
    t_all = time.perf_counter()
    realized = realize(scenario)
    result = pipeline.run(realized, say=partial(progress, command))
    report = run_report(result, pipeline.sensor_sigma_m(realized.scenario))
    if rrd is not None:
        from twin.viz import save_run_recording

        t0 = time.perf_counter()
        save_run_recording(stage.file(rrd), result)
        report["timings_s"]["recording_s"] = round(time.perf_counter() - t0, 3)
        report["recording"] = str(rrd)
    report["wall_s"] = round(time.perf_counter() - t_all, 2)
    report["report"] = str(stage.out / REPORT_FILE)
    write_json(stage.folder / REPORT_FILE, report)
    return result, report


def run(args: argparse.Namespace) -> int:
    scenario = load_scenario(args.scenario)
    out, rrd = checked_outputs(args)
    with Staged(out) as stage:
        _, report = run_and_report(scenario, stage, rrd)
        stage.commit()
    print(json.dumps(headline(report), indent=2))
    return 0

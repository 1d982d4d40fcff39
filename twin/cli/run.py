"""``twin run SCENARIO --out DIR [--rrd FILE]``: scan -> localize -> path -> IK -> replay -> report."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from twin import pipeline
from twin.io.report import headline, run_report, write_json
from twin.realize import realize
from twin.scenario import Scenario, load_scenario


def add_parser(sub) -> None:
    p = sub.add_parser(
        "run", help="scan, localize, plan the process paths, solve IK, replay and verify",
        description="Scan the part, localize it, make a process path from the scan (document 004) "
                    "and one from the CAD model moved by the estimate (document 003), solve the joints "
                    "with mink, replay both in the true cell at 1 ms and write DIR/report.json.",
    )
    p.add_argument("scenario", help="scenario TOML file")
    p.add_argument("--out", required=True, help="output folder for report.json")
    p.add_argument("--rrd", help="also write a rerun recording to this file")
    p.set_defaults(run=run)


def progress(msg: str) -> None:
    print(f"[run] {msg}", file=sys.stderr, flush=True)


def run_and_report(scenario: Scenario, out: Path, rrd: Path | None):
    """Run the loop and write ``out/report.json`` (and the recording); returns (result, report)."""
    t_all = time.perf_counter()
    report_file = out / "report.json"
    if report_file.exists():
        report_file.unlink()  # a failed run must not leave an older report looking current
    realized = realize(scenario)
    result = pipeline.run(realized, say=progress)
    report = run_report(result, pipeline.sensor_sigma_m(realized.scenario))
    if rrd is not None:
        from twin.viz import save_run_recording

        t0 = time.perf_counter()
        save_run_recording(rrd, result)
        report["timings_s"]["recording_s"] = round(time.perf_counter() - t0, 3)
        report["recording"] = str(rrd)
    report["wall_s"] = round(time.perf_counter() - t_all, 2)
    report["report"] = str(report_file)
    write_json(report_file, report)
    return result, report


def run(args: argparse.Namespace) -> int:
    _, report = run_and_report(load_scenario(args.scenario), Path(args.out), Path(args.rrd) if args.rrd else None)
    print(json.dumps(headline(report), indent=2))
    return 0

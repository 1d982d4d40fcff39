"""``twin demo``: the whole loop of ``twin run`` on the S-surface scenario, with the scan files."""

from __future__ import annotations

import argparse

from twin.cli import COMMANDS
from twin.cli.common import (
    add_live_options,
    add_output_options,
    checked_outputs,
    live_sink,
    print_result,
    progress,
    reporting,
)
from twin.cli.run import exit_code, run_and_report, summary_rows
from twin.errors import TwinError
from twin.io import write_scan
from twin.io.output import Staged
from twin.io.report import headline
from twin.robot import MODELS_DIR
from twin.scenario import load_scenario

DEFAULT_SCENARIO = MODELS_DIR.parent / "scenarios" / "s_surface.toml"


def add_parser(sub) -> None:
    p = sub.add_parser(
        "demo", help=COMMANDS["demo"],
        description="Scan the S-surface part at 1 ms, localize it against its CAD model, make a "
                    "process path from the scan (document 004) and one from the CAD model moved by "
                    "the estimate (document 003), solve the joints with mink, replay both in the true "
                    "cell and report errors against the truth, path deviation and contacts. stdout: a "
                    "short summary, or with --json the report's headline as one JSON object; progress "
                    "goes to stderr.",
    )
    p.add_argument("--scenario", default=str(DEFAULT_SCENARIO), help="scenario TOML (default: S-surface)")
    add_output_options(p, "output folder (default: out/demo; refused if it exists, unless --force)",
                       default_out="out/demo", rrd_help="recording path (default: OUT/demo.rrd)")
    p.add_argument("--no-rrd", action="store_true", help="do not write a recording")
    add_live_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if args.no_rrd and args.rrd:
        raise TwinError("--rrd and --no-rrd exclude each other; give one")
    scenario = load_scenario(args.scenario, machine="arm")
    out, rrd = checked_outputs(args, default_rrd_name=None if args.no_rrd else "demo.rrd")
    live = live_sink(args)
    with reporting(args, "demo") as say, Staged(out) as stage:
        result, report = run_and_report(scenario, stage, rrd, command="demo", say=say, live=live)
        if result.scan is not None:
            write_scan(result.scan, stage.folder)
            say("wrote samples.parquet, points.ply, scan.json")
        stage.commit()
    h = headline(report)
    files = f"{out} (samples.parquet, points.ply, scan.json)" if result.scan is not None else None
    print_result(args, h, summary_rows(h, files), indent=2)
    if not report["complete"]:
        progress("demo", f"stopped at {report['failed_stage']}: {report['failure']} "
                         f"(partial report in {report['report']})")
    return exit_code(report)

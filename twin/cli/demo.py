"""``twin demo``: the whole loop of ``twin run`` on the S-surface scenario, with the scan files."""

from __future__ import annotations

import argparse
import json

from twin.cli.common import add_output_options, checked_outputs
from twin.cli.run import exit_code, run_and_report
from twin.errors import TwinError
from twin.io import write_scan
from twin.io.output import Staged
from twin.io.report import headline
from twin.robot import MODELS_DIR
from twin.scenario import load_scenario

DEFAULT_SCENARIO = MODELS_DIR.parent / "scenarios" / "s_surface.toml"


def add_parser(sub) -> None:
    p = sub.add_parser(
        "demo", help="run the whole loop on the S-surface part and write a report and a recording",
        description="Scan the S-surface part at 1 ms, localize it against its CAD model, make a "
                    "process path from the scan (document 004) and one from the CAD model moved by "
                    "the estimate (document 003), solve the joints with mink, replay both in the true "
                    "cell and report errors against the truth, path deviation and contacts.",
    )
    p.add_argument("--scenario", default=str(DEFAULT_SCENARIO), help="scenario TOML (default: S-surface)")
    add_output_options(p, "output folder (default: out/demo; refused if it exists, unless --force)",
                       default_out="out/demo", rrd_help="recording path (default: OUT/demo.rrd)")
    p.add_argument("--no-rrd", action="store_true", help="do not write a recording")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if args.no_rrd and args.rrd:
        raise TwinError("--rrd and --no-rrd exclude each other; give one")
    scenario = load_scenario(args.scenario)
    out, rrd = checked_outputs(args, default_rrd_name=None if args.no_rrd else "demo.rrd")
    with Staged(out) as stage:
        result, report = run_and_report(scenario, stage, rrd, command="demo")
        if result.scan is not None:
            write_scan(result.scan, stage.folder)
        stage.commit()
    print(json.dumps(headline(report), indent=2))
    return exit_code(report)

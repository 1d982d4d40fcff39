"""``twin scan SCENARIO --out DIR [--rrd FILE] [--force]``: simulate a scan and write its files."""

from __future__ import annotations

import argparse
import dataclasses
import json
import time

from twin.cell import build_cell
from twin.cli.common import add_output_options, checked_outputs
from twin.io import write_scan
from twin.io.output import Staged
from twin.realize import realize
from twin.scan import run_scan
from twin.scenario import load_scenario


def add_parser(sub) -> None:
    p = sub.add_parser(
        "scan", help="simulate a scan of a scenario and write samples, points and metadata",
        description="Simulate the scenario's raster scan at 1 ms in the true cell and write "
                    "DIR/samples.parquet (t, q1..q6, d, valid, status, line), DIR/points.ply "
                    "(valid points, robot base frame, metres) and DIR/scan.json. The folder (and the "
                    "recording) appear when everything is written; an existing one is refused "
                    "unless --force.",
    )
    p.add_argument("scenario", help="scenario TOML file (see scenarios/README.md)")
    add_output_options(p, "output folder (created; refused if it exists, unless --force)")
    p.add_argument("--noise-off", action="store_true", help="switch every error source off")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    scenario = load_scenario(args.scenario)
    if args.noise_off:
        scenario = dataclasses.replace(scenario, noise=scenario.noise.all_off())
    out, rrd = checked_outputs(args)
    t0 = time.perf_counter()
    with Staged(out) as stage:
        realized = realize(scenario)
        true_cell = build_cell(realized, "true")
        scan = run_scan(realized, build_cell(realized, "nominal"), true_cell)
        write_scan(scan, stage.folder, extra={"recording": str(rrd)} if rrd else None)
        if rrd is not None:
            from twin.viz import save_scan_recording

            save_scan_recording(stage.file(rrd), true_cell, scan)
        stage.commit()
    summary = {
        "out": str(out),
        "samples": int(len(scan.t)),
        "valid": int(scan.valid.sum()),
        "duration_s": round(float(scan.t[-1]), 3),
        "wall_s": round(time.perf_counter() - t0, 2),
    }
    print(json.dumps(summary))
    return 0

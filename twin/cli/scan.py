"""``twin scan SCENARIO --out DIR [--rrd FILE] [--force]``: simulate a scan and write its files."""

from __future__ import annotations

import argparse
import dataclasses
import time

from twin.cell import build_cell
from twin.cli import COMMANDS
from twin.cli.common import (
    EXIT_UNTRUSTED,
    add_output_options,
    checked_outputs,
    number,
    print_result,
    progress,
    reporting,
)
from twin.io import write_scan
from twin.io.output import Staged
from twin.realize import realize
from twin.scan import run_scan
from twin.scenario import load_scenario


def add_parser(sub) -> None:
    p = sub.add_parser(
        "scan", help=COMMANDS["scan"],
        description="Simulate the scenario's raster scan at 1 ms in the true cell and write "
                    "DIR/samples.parquet (t, q1..q6, d, valid, status, line), DIR/points.ply "
                    "(valid points, robot base frame, metres) and DIR/scan.json. The folder (and the "
                    "recording) appear when everything is written; an existing one is refused "
                    "unless --force. stdout: a short summary, or with --json one JSON object (out, "
                    "samples, valid, duration_s, wall_s, recording); progress goes to stderr.",
        epilog="exit status: 0 a scan with valid points; 2 bad input; 3 the scan measured no point (every beam "
               "missed or fell outside the sensor's window: the files are written and say so)",
    )
    p.add_argument("scenario", help="scenario TOML file (its keys: docs/concepts/scenario-files.md)")
    add_output_options(p, "output folder (created; refused if it exists, unless --force)")
    p.add_argument("--noise-off", action="store_true", help="switch every error source off")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    scenario = load_scenario(args.scenario, machine="arm")
    if args.noise_off:
        scenario = dataclasses.replace(scenario, noise=scenario.noise.all_off())
    out, rrd = checked_outputs(args)
    t0 = time.perf_counter()
    # deferred lines until every scan line is known reachable: a refused scenario (a part that
    # cannot be loaded, a pass or a line the arm cannot reach) is one line on stderr; from then
    # on the stages show as they run
    with reporting(args, "scan", defer=True) as say, Staged(out) as stage:
        realized = realize(scenario)
        say(f"realized the scenario: {len(realized.workpiece.mesh.faces)} triangles, seed {scenario.seed}")
        true_cell = build_cell(realized, "true")
        nominal_cell = build_cell(realized, "nominal")
        say("built the nominal and the true cell")

        def reachable(plan) -> None:
            say(f"planned {int(plan.line.max()) + 1} scan lines, {len(plan.t)} samples at 1 ms: every one reachable; "
                "simulating")
            say.release()

        scan = run_scan(realized, nominal_cell, true_cell, reachable=reachable)
        say(f"scanned {len(scan.t)} samples ({scan.t[-1]:.1f} s simulated), {int(scan.valid.sum())} valid")
        write_scan(scan, stage.folder, extra={"recording": str(rrd)} if rrd else None)
        from twin.io.figures import scan_figures
        from twin.sensors.laser import sensor_sigma_m

        scan_figures(scan, realized, sensor_sigma_m(scenario), stage.folder)
        say("wrote samples.parquet, points.ply, scan.json, scan_residuals.png, scan_deviation_map.png")
        if rrd is not None:
            from twin.viz import save_scan_recording

            save_scan_recording(stage.file(rrd), true_cell, scan, realized)
            say("wrote the recording")
        stage.commit()
    summary = {
        "out": str(out),
        "samples": int(len(scan.t)),
        "valid": int(scan.valid.sum()),
        "duration_s": round(float(scan.t[-1]), 3),
        "wall_s": round(time.perf_counter() - t0, 2),
    }
    if rrd is not None:
        summary["recording"] = str(rrd)
    print_result(args, summary, scan_rows(summary))
    if summary["valid"] == 0:
        progress("scan", "the scan measured no point: every beam missed or fell outside the window "
                         "(the files say so; nothing to localize)")
        return EXIT_UNTRUSTED
    return 0


def scan_rows(summary: dict) -> list[tuple[str, str]]:
    """The summary of ``twin scan`` for a reader."""
    share = 100.0 * summary["valid"] / max(summary["samples"], 1)
    rows = [("scan", f"complete: {summary['samples']} samples at 1 ms ({summary['duration_s']:.3f} s simulated), "
                     f"{summary['valid']} valid ({share:.1f} %)"),
            ("files", f"{summary['out']} (samples.parquet, points.ply, scan.json)")]
    if "recording" in summary:
        rows.append(("recording", summary["recording"]))
    rows.append(("wall time", number(summary["wall_s"], "s", 3)))
    return rows

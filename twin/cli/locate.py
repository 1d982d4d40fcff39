"""``twin locate SCENARIO --out DIR [--coarse ...] [--points M] [--planner ...]``: document
001's locate-then-machine hierarchy in the twin (:mod:`twin.workflows.locate`)."""

from __future__ import annotations

import argparse
import csv
import time

import numpy as np

from twin.cli import COMMANDS
from twin.cli.common import (
    EXIT_OK,
    EXIT_STAGE_FAILED,
    EXIT_UNTRUSTED,
    add_output_options,
    checked_outputs,
    number,
    print_result,
    progress,
    reporting,
    yes_no,
)
from twin.cli.run import exit_code, verdict_row
from twin.io.output import Staged
from twin.io.report import locate_headline, locate_report, write_json
from twin.io.scan_files import write_points_ply
from twin.realize import realize
from twin.scenario import COARSE_METHODS, PROBE_PLANNERS, load_scenario

REPORT_FILE = "report.json"
PAGE_FILE = "report.html"
HITS_FILE = "probe_hits.csv"
COARSE_POINTS_FILE = "coarse_points.ply"
#: Columns of probe_hits.csv (robot base frame, metres, seconds).
HIT_COLUMNS = ("label", "hit", "target_x_m", "target_y_m", "target_z_m", "normal_x", "normal_y", "normal_z",
               "centre_x_m", "centre_y_m", "centre_z_m", "trigger_t_s", "miss")


def add_parser(sub) -> None:
    p = sub.add_parser(
        "locate", help=COMMANDS["locate"],
        description="Locate a part clamped far from its nominal pose, as document 001 does: a sparse laser pass "
                    "and a coarse pose from no prior orientation, the touch probe qualified on the cell's "
                    "reference sphere, fine probe points planned on the CAD model at the coarse pose (D-optimal "
                    "by default), probed by the arm in the true cell at 1 ms, and document 001's fine stage. "
                    f"Writes DIR/{REPORT_FILE} (every stage's error against the truth, the covariance, hits, "
                    f"misses, contacts, times), DIR/{HITS_FILE} and DIR/{COARSE_POINTS_FILE}. stdout: a short "
                    "summary, or with --json the report's headline as one JSON object; progress goes to stderr.",
        epilog=f"exit status: {EXIT_OK} a trusted pose within the scenario's [tolerances]; 2 bad input; "
               f"{EXIT_UNTRUSTED} finished but a check failed (fine fit not ok, a planned point missed, an "
               "unintended contact, or the final uncertainty beyond tolerances.max_position_uncertainty_m / "
               f"max_rotation_uncertainty_rad: the checks in report.json); {EXIT_STAGE_FAILED} a stage failed "
               "(what the finished stages made is written, the report says complete: false)",
    )
    p.add_argument("scenario", help="scenario TOML file with a [probe] table")
    add_output_options(p, "output folder (created; refused if it exists, unless --force)")
    p.add_argument("--coarse", choices=COARSE_METHODS,
                   help="coarse method (default: the scenario's locate.coarse): multistart (document 000, "
                        "Algorithm 5), ga (document 001's genetic algorithm, one run, its pose as it comes), "
                        "ga_restarts (up to ten checked runs, then a fine stage on the laser points)")
    p.add_argument("--points", type=int, help="number of fine probe points (>= 6; default probe.points)")
    p.add_argument("--planner", choices=PROBE_PLANNERS, help="how the fine points are chosen (default d_optimal)")
    p.set_defaults(run=run)


def write_hits(path, hits) -> None:
    """``probe_hits.csv``: one row per probing move (columns ``HIT_COLUMNS``)."""
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(HIT_COLUMNS)
        for h in hits:
            c = h.centre if h.hit else np.full(3, np.nan)
            w.writerow([h.target.label, int(h.hit), *[f"{v:.10f}" for v in h.target.point],
                        *[f"{v:.9f}" for v in h.target.normal], *[f"{v:.10f}" for v in c],
                        f"{h.trigger_t_s:.6f}", h.miss or ""])


def summary_rows(h: dict) -> list[tuple[str, str]]:
    """The summary of ``twin locate`` for a reader, from its headline ``h``."""
    rows = [verdict_row(h),
            ("complete", "yes" if h["complete"] else f"no: stopped at {h.get('failed_stage')}: {h.get('failure')}"),
            ("trusted", yes_no(h["trusted"]))]
    c = h.get("coarse")
    if c is not None:
        rows.append(("coarse pose", f"{c['method']}: rotation error {number(c['rotation_error_deg'], 'deg')}, "
                                    f"translation error {number(c['translation_error_mm'], 'mm')}"
                                    f"{'' if c['within_1mm_1deg'] else ' (outside 1 mm / 1 deg)'}"))
    if "effective_radius_error_um" in h:
        rows.append(("qualification", f"effective ball radius error {number(h['effective_radius_error_um'], 'um')}"))
    pr = h.get("probing")
    if pr is not None:
        rows.append(("probing", f"{pr['hits']} of {pr['points']} points hit, "
                                f"{pr['unintended_contacts']} unintended contact(s)"))
    f = h.get("fine")
    if f is not None:
        rows.append(("fine pose", f"{f['status']}: rotation error {number(f['rotation_error_deg'], 'deg')}, "
                                  f"translation error {number(f['translation_error_mm'], 'mm')}, "
                                  f"largest error {number(f.get('max_error_sigmas'), 'sigma', 3)}"))
    rows.append(("report", h.get("report", "n/a")))
    if "recording" in h:
        rows.append(("recording", h["recording"]))
    if "wall_s" in h:
        rows.append(("wall time", number(h["wall_s"], "s", 3)))
    return rows


def run(args: argparse.Namespace) -> int:
    from twin.workflows.locate import locate

    scenario = load_scenario(args.scenario, machine="arm")
    if scenario.probe is None:
        from twin.errors import TwinError

        raise TwinError(f"scenario {args.scenario} has no [probe] table: twin locate needs a touch probe")
    if args.points is not None and args.points < 6:
        from twin.errors import TwinError

        raise TwinError(f"--points {args.points} is too few: at least 6 points fix six pose directions")
    out, rrd = checked_outputs(args)
    t_all = time.perf_counter()
    with reporting(args, "locate") as say, Staged(out) as stage:
        realized = realize(scenario)
        result = locate(realized, say=say, coarse=args.coarse, points=args.points, planner=args.planner)
        report = locate_report(result)
        if result.coarse_points is not None:
            write_points_ply(stage.folder / COARSE_POINTS_FILE, result.coarse_points)
        if result.hits:
            write_hits(stage.folder / HITS_FILE, result.hits)
        if rrd is not None:
            from twin.probing import build_probe_cell
            from twin.viz.locate import save_locate_recording

            save_locate_recording(stage.file(rrd), result, build_probe_cell(realized), report)
            say("wrote the recording")
            report["recording"] = str(rrd)
        from twin.io.figures import locate_figures, report_page
        from twin.sensors.laser import sensor_sigma_m

        figures = locate_figures(result, sensor_sigma_m(scenario), stage.folder)
        report["figures"] = [f.name for f in figures]
        report["wall_s"] = round(time.perf_counter() - t_all, 2)
        report["report"] = str(stage.out / REPORT_FILE)
        report_page(report, figures, stage.folder / PAGE_FILE, f"twin locate: {scenario.name}")
        write_json(stage.folder / REPORT_FILE, report)
        stage.commit()
    h = locate_headline(report)
    print_result(args, h, summary_rows(h), indent=2)
    if not report["complete"]:
        progress("locate", f"stopped at {report['failed_stage']}: {report['failure']} "
                           f"(partial report in {report['report']})")
    return exit_code(report)

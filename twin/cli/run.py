"""``twin run SCENARIO --out DIR [--rrd FILE] [--force]``: scan -> localize -> path -> IK -> replay -> report."""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path

from twin.cli import COMMANDS
from twin.cli.common import (
    EXIT_OK,
    EXIT_STAGE_FAILED,
    EXIT_UNTRUSTED,
    add_live_options,
    add_output_options,
    checked_outputs,
    live_sink,
    number,
    print_result,
    progress,
    reporting,
    yes_no,
)
from twin.errors import TwinError
from twin.io.output import Staged
from twin.io.report import headline, run_report, write_json
from twin.realize import realize
from twin.scenario import Scenario, load_scenario
from twin.sensors.laser import sensor_sigma_m
from twin.workflows import loop

REPORT_FILE = "report.json"
PAGE_FILE = "report.html"


def add_parser(sub) -> None:
    p = sub.add_parser(
        "run", help=COMMANDS["run"],
        description="Scan the part, localize it, make a process path from the scan (document 004) "
                    "and one from the CAD model moved by the estimate (document 003), solve the joints "
                    "with mink, replay both in the true cell at 1 ms and write DIR/report.json. The "
                    "folder (and the recording) appear when everything is written. stdout: a short "
                    "summary, or with --json the report's headline as one JSON object; progress goes "
                    "to stderr.",
        epilog=f"exit status: {EXIT_OK} every check passed: complete, a trusted localization, and each path "
               "within the scenario's [tolerances] (min_process_coverage, max_replay_deviation_m, "
               f"max_tip_penetration_m) without an unintended contact; 2 bad input; {EXIT_UNTRUSTED} finished "
               "but a check failed (named on stdout and in report.json's checks); "
               f"{EXIT_STAGE_FAILED} a stage failed (what the finished stages made is written)",
    )
    p.add_argument("scenario", help="scenario TOML file")
    add_output_options(p, "output folder for report.json (created; refused if it exists, unless --force)")
    p.add_argument("--place-base", action="store_true",
                   help="first move the robot base on the table to a pose from which the arm reaches every "
                        "scan and path pose (a search over x, y and yaw around the part), then run from there; "
                        "the placement is written to the report (placement)")
    p.add_argument("--export-urscript", action="store_true",
                   help="also write each replayed path as a robot program: DIR/<path>.script (URScript: servoj "
                        "every 2 ms through the verified 1 ms references) and DIR/<path>_joints.csv; a path past "
                        "a joint range or speed limit is not written (exit 3)")
    p.add_argument("--strict", action="store_true",
                   help="a path stretch that cannot be processed (unreachable, singular, colliding) fails "
                        "the run instead of being dropped and listed")
    add_live_options(p)
    p.set_defaults(run=run)


def export_programs(result, folder: Path) -> list[dict]:
    """Each replayed path as URScript and a joint CSV in ``folder`` (:mod:`twin.formats.urscript`);
    one entry per path: the files, or why it was not written."""
    from twin.formats.urscript import write_joint_csv, write_urscript

    model = result.replay_cell.model
    lo, hi = model.jnt_range[:6, 0], model.jnt_range[:6, 1]
    out = []
    for r in result.runs:
        try:
            text = write_urscript(r.name, r.trajectory, lo, hi, note=f"{result.realized.scenario.name}, {r.name}")
        except TwinError as exc:
            out.append({"path": r.name, "written": False, "why": str(exc)})
            continue
        (folder / f"{r.name}.script").write_text(text)
        (folder / f"{r.name}_joints.csv").write_text(write_joint_csv(r.trajectory))
        out.append({"path": r.name, "written": True, "script": f"{r.name}.script", "joints": f"{r.name}_joints.csv",
                    "duration_s": round(float(r.trajectory.t[-1] - r.trajectory.t[0]), 3)})
    return out


def run_and_report(scenario: Scenario, stage: Staged, rrd: Path | None, command: str = "run",
                   strict: bool = False, placement: dict | None = None,
                   say: Callable[[str], None] | None = None, live: str | None = None,
                   urscript: bool = False):
    """Run the loop and write ``report.json`` (and the recording) into the staged folder;
    returns (result, report). ``say`` gets the stage lines (default: plain lines on stderr);
    ``live``: a viewer to stream the stages to as they finish (``"spawn"`` or its address).
    The caller commits the stage: a run that stopped at a stage still leaves its evidence (the
    report says ``complete: false``, the failing stage and why)."""
    if say is None:
        say = partial(progress, command)
    t_all = time.perf_counter()
    realized = realize(scenario)
    if live is None:
        result = loop.run(realized, say=say, strict=strict)
    else:
        from twin.viz import LiveRecording

        viewer = LiveRecording(live, say=say)
        result = loop.run(realized, say=say, strict=strict, watch=viewer)
    report = run_report(result, sensor_sigma_m(realized.scenario))
    if live is not None:
        viewer.finish(result, report)
        say("streamed the run to the viewer")
    if urscript:
        report["robot_programs"] = export_programs(result, stage.folder)
        say(f"wrote {sum(p['written'] for p in report['robot_programs'])} robot program(s)")
    if placement is not None:
        report["placement"] = placement
    if result.failure is not None and "unreachable" in result.failure[1]:
        from twin.workflows.placement import describe_unreachable_fix, reach_targets

        try:
            fix = describe_unreachable_fix(scenario, reach_targets(scenario, realized))
        except TwinError as exc:
            fix = f"no base on the table reaches every pose ({exc})"
        if fix:
            report["failure"] += f"; {fix}"
    if rrd is not None:
        from twin.viz import save_run_recording

        t0 = time.perf_counter()
        save_run_recording(stage.file(rrd), result, report=report)
        say("wrote the recording")
        report["timings_s"]["recording_s"] = round(time.perf_counter() - t0, 3)
        report["recording"] = str(rrd)
    from twin.io.figures import report_page, run_figures

    figures = run_figures(result, sensor_sigma_m(realized.scenario), stage.folder)
    report["figures"] = [f.name for f in figures]
    report["wall_s"] = round(time.perf_counter() - t_all, 2)
    report["report"] = str(stage.out / REPORT_FILE)
    report_page(report, figures, stage.folder / PAGE_FILE, f"twin {command}: {scenario.name}")
    write_json(stage.folder / REPORT_FILE, report)
    return result, report


def exit_code(report: dict) -> int:
    """0 complete and every deciding check passed (:mod:`twin.verdicts`: trusted, and within the
    scenario's tolerances); 3 finished but a check failed; 4 a stage failed (evidence written)."""
    if not report["complete"]:
        return EXIT_STAGE_FAILED
    return EXIT_OK if report["passed"] else EXIT_UNTRUSTED


def verdict_row(h: dict) -> tuple[str, str]:
    """The verdict line for a reader: pass, or FAIL with each failed check."""
    failed = h.get("failed_checks", [])
    if h.get("passed"):
        return ("verdict", "pass")
    return ("verdict", "FAIL: " + "; ".join(f"{c['name']}: {c['detail']}" for c in failed))


def summary_rows(h: dict, files: str | None = None) -> list[tuple[str, str]]:
    """The summary of ``twin run`` and ``twin demo`` for a reader, from the headline ``h``."""
    rows = [verdict_row(h),
            ("complete", "yes" if h["complete"] else f"no: stopped at {h.get('failed_stage')}: {h.get('failure')}")]
    loc = h.get("localization")
    loc_note = f" (localization {loc['status']})" if loc is not None and loc["status"] != "ok" else ""
    rows.append(("trusted", yes_no(h["trusted"]) + loc_note))
    if loc is not None:
        if "free" in (loc["rotation_error_deg"], loc["translation_error_mm"]):
            # along a free direction the points say nothing, so there is no pose error to state
            errors = "free direction(s), no pose error defined"
        else:
            errors = (f"rotation error {number(loc['rotation_error_deg'], 'deg')}, "
                      f"translation error {number(loc['translation_error_mm'], 'mm')}")
        rows.append(("localization", f"{loc['status']}: {errors}; largest error along the determined directions "
                                     f"{number(loc['max_error_sigmas'], 'sigma', 3)}"))
    pv = h.get("path_verification")
    if pv is not None:
        rows.append(("path replay", f"{pv['path']}: max deviation {number(pv['max_deviation_mm'], 'mm')}, "
                                    f"rms {number(pv['rms_deviation_mm'], 'mm')}, "
                                    f"{pv['unintended_contacts']} unintended contact(s)"))
    if "max_surface_error_mm" in h:
        rows.append(("surface error", f"max {number(h['max_surface_error_mm'], 'mm')} (CAD path against the true "
                                      "surface)"))
    rows.append(("report", h.get("report", "n/a")))
    if files:
        rows.append(("files", files))
    if "recording" in h:
        rows.append(("recording", h["recording"]))
    if "wall_s" in h:
        rows.append(("wall time", number(h["wall_s"], "s", 3)))
    return rows


def run(args: argparse.Namespace) -> int:
    scenario = load_scenario(args.scenario, machine="arm")
    out, rrd = checked_outputs(args)
    live = live_sink(args)
    placement = None
    with reporting(args, "run") as say:
        if args.place_base:
            from twin.workflows.placement import place_base

            scenario, placement = place_base(scenario)
            say(f"base placed at {placement['new_base']} (was {placement['old_base']}; "
                f"margin {placement['margin']:.2f}, {placement['time_s']:.1f} s)")
        with Staged(out) as stage:
            _, report = run_and_report(scenario, stage, rrd, strict=args.strict, placement=placement, say=say,
                                       live=live, urscript=args.export_urscript)
            stage.commit()
    h = headline(report)
    print_result(args, h, summary_rows(h), indent=2)
    if not report["complete"]:
        progress("run", f"stopped at {report['failed_stage']}: {report['failure']} "
                        f"(partial report in {report['report']})")
    refused = [p for p in report.get("robot_programs", []) if not p["written"]]
    for p in refused:
        progress("run", f"robot program not written: {p['why']}")
    code = exit_code(report)
    return EXIT_UNTRUSTED if refused and code == EXIT_OK else code

"""``twin cmm plan|run|compare``: document 002's measurement programs on the CMM (:mod:`twin.workflows.cmm`).

* ``twin cmm plan TEACH SCENARIO --out DIR``: plan a teach file with the safe-plane baseline,
  document 002's algorithm and the full-check variant; write each program as DMIS and
  ``plan.json`` (every GOTO with its reason, the penetrations, the moves the swept check finds
  colliding, the moves a planner could not clear).
* ``twin cmm run PROGRAM.dmi SCENARIO --out DIR``: execute a DMIS program in the twin at 1 ms;
  write ``report.json`` (hits, misses, every unintended contact located, path length, cycle
  time) and ``hits.csv``.
* ``twin cmm compare TEACH SCENARIO --out DIR``: both for all three planners, with the table
  side by side (``report.md``) and one recording with each program on its own entity.
* ``twin cmm check PROGRAM.dmi [SCENARIO --out DIR]``: read a DMIS program as measurement
  software writes it (:mod:`algorithms.probing.dmis.reader`) and list its features, tolerances,
  moves, stylus changes and every statement not run; with a scenario, run it in the twin and
  evaluate its tolerances: ``output.dmo`` (DMIS output), ``results.csv``, ``report.html``,
  ``report.json``, ``hits.csv``.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np

from twin.cli import COMMANDS
from twin.cli.common import (
    EXIT_OK,
    EXIT_UNTRUSTED,
    add_output_options,
    add_print_options,
    checked_outputs,
    non_negative_int,
    number,
    print_result,
    reporting,
)
from twin.io.output import Staged
from twin.io.report import write_json
from twin.scenario import load_scenario

PLAN_FILE = "plan.json"
REPORT_FILE = "report.json"
TABLE_FILE = "report.md"
HITS_FILE = "hits.csv"
DMO_FILE = "output.dmo"
RESULTS_FILE = "results.csv"
PAGE_FILE = "report.html"
CHECK_FILE = "check.json"
#: The template of a --part run (its machine, probe and stylus S1), and the part's default pose.
PART_TEMPLATE = "cmm/bore_and_face.toml"
DEFAULT_FIXTURE = (0.35, 0.50, 0.12, 0.0, 0.0, 0.0)
PLANNER_CHOICES = ("all", "baseline", "document", "full_check")


def add_parser(sub) -> None:
    p = sub.add_parser(
        "cmm", help=COMMANDS["cmm"],
        description="CMM measurement programs (document 002): teach files planned into DMIS programs by the "
                    "safe-plane baseline, the document's algorithm and a full-check variant, and DMIS programs "
                    "run in the twin's CMM with every contact of the probe with the part counted and located.",
    )
    cmd = p.add_subparsers(dest="cmm_command", required=True, metavar="SUBCOMMAND")
    common_epilog = (f"exit status: {EXIT_OK} done and safe; 2 bad input (nothing written); {EXIT_UNTRUSTED} done, "
                     "but a program hits the part, misses a point or a move could not be cleared")
    pp = cmd.add_parser("plan", help="plan a teach file with the three planners and write DMIS programs",
                        description="Plan TEACH (a teach file) on SCENARIO's part (machine = \"cmm\"): "
                                    f"DIR/<planner>.dmi for each planner and DIR/{PLAN_FILE}.",
                        epilog=f"exit status: {EXIT_OK} planned; 2 bad input; {EXIT_UNTRUSTED} a planner could not "
                               "clear a move, or the full-check program (with --planner X: X's program) collides "
                               "in the swept check")
    pp.add_argument("teach", help="teach file (TOML): the operator's moves, touches and stylus changes")
    pp.add_argument("scenario", help='scenario TOML file with machine = "cmm"')
    pp.add_argument("--planner", choices=PLANNER_CHOICES, default="all", help="which planner (default: all three)")
    add_output_options(pp, "output folder (created; refused if it exists, unless --force)")
    pp.set_defaults(run=run_plan)

    pr = cmd.add_parser("run", help="execute a DMIS program in the twin's CMM at 1 ms",
                        description=f"Execute PROGRAM (DMIS) on SCENARIO's CMM: DIR/{REPORT_FILE}, DIR/{HITS_FILE}.",
                        epilog=common_epilog)
    pr.add_argument("program", help="DMIS program (.dmi)")
    pr.add_argument("scenario", help='scenario TOML file with machine = "cmm"')
    pr.add_argument("--seed", type=non_negative_int, help="random stream of the probe and scales (default: scenario)")
    add_output_options(pr, "output folder (created; refused if it exists, unless --force)")
    pr.set_defaults(run=run_program)

    pc = cmd.add_parser("compare", help="plan a teach file three ways, run each program, table them side by side",
                        description=f"Plan TEACH with the three planners, write the DMIS programs, run each in "
                                    f"the twin, and write DIR/{TABLE_FILE}, DIR/{REPORT_FILE} and DIR/cmm.rrd.",
                        epilog=f"exit status: {EXIT_OK} the full-check program ran without contact or miss; 2 bad "
                               f"input; {EXIT_UNTRUSTED} it did not, or it has a move it could not clear")
    pc.add_argument("teach", help="teach file (TOML)")
    pc.add_argument("scenario", help='scenario TOML file with machine = "cmm"')
    pc.add_argument("--seed", type=non_negative_int, help="random stream of the probe and scales (default: scenario)")
    pc.add_argument("--no-rrd", action="store_true", help="do not write DIR/cmm.rrd")
    add_output_options(pc, "output folder (created; refused if it exists, unless --force)")
    pc.set_defaults(run=run_compare)

    pk = cmd.add_parser("check", help="read a DMIS program from measurement software; with a scenario, run it and "
                                      "evaluate its tolerances",
                        description="Read PROGRAM (DMIS 5.3 as measurement software writes it: UTF-8 or Latin-1, "
                                    "$ continuations, variables, IF/JUMPTO/DO, macros, CALL/EXTERN) and list what it "
                                    "measures, moves and evaluates, and every statement not run with its line. With "
                                    "SCENARIO (machine = \"cmm\"), run it in the twin's CMM at 1 ms and evaluate its "
                                    f"tolerances on the measured points: DIR/{DMO_FILE} (DMIS output), "
                                    f"DIR/{RESULTS_FILE}, DIR/{PAGE_FILE}, DIR/{REPORT_FILE}, DIR/{HITS_FILE}.",
                        epilog=f"exit status: {EXIT_OK} read (and, with a scenario: every touch hit, no unintended "
                               "contact, every tolerance evaluated and in); 2 bad input or a statement that moves the "
                               f"machine and is not run (nothing written); {EXIT_UNTRUSTED} ran, but a touch missed, "
                               "the probe hit the part, or a tolerance is out or could not be evaluated")
    pk.add_argument("program", help="DMIS program (.dmi, .dms, ...)")
    pk.add_argument("scenario", nargs="?", help='scenario TOML file with machine = "cmm" (omit to only read, or '
                                                 "give --part)")
    pk.add_argument("--part", metavar="FILE",
                    help="run on the twin's bridge CMM with this part (STL, OBJ, PLY or STEP) on the table at "
                         "--fixture, where the program expects it, instead of a scenario's")
    pk.add_argument("--units", choices=("m", "mm"), default="mm",
                    help="units of a --part mesh file (default mm; a STEP file states its own)")
    pk.add_argument("--fixture", default=",".join(f"{x:g}" for x in DEFAULT_FIXTURE), metavar="X,Y,Z,RX,RY,RZ",
                    help="the --part's pose on the table: the part frame's origin [m] and its roll, pitch, yaw "
                         "[deg] in the machine frame (default: on the riser in the middle of the table, "
                         f"{','.join(f'{x:g}' for x in DEFAULT_FIXTURE)})")
    pk.add_argument("--stylus", action="append", default=[], metavar="PROGRAM=MACHINE",
                    help="run the program's stylus PROGRAM (its SNSLCT label) as the machine's stylus MACHINE; "
                         "repeat for each")
    pk.add_argument("--seed", type=non_negative_int, help="random stream of the probe and scales (default: scenario)")
    pk.add_argument("--out", help=f"output folder (created; refused if it exists, unless --force); without a "
                                  f"scenario optional: DIR/{CHECK_FILE}")
    pk.add_argument("--rrd", help="also write a rerun recording to this .rrd file")
    pk.add_argument("--force", action="store_true", help="replace an existing output folder (and recording) whole")
    add_print_options(pk)
    pk.set_defaults(run=run_check)


def _setup(path: str):
    from twin.cmm_machine import cmm_setup

    return cmm_setup(load_scenario(path, machine="cmm"))


def _methods(choice: str) -> tuple[str, ...]:
    from algorithms.probing.cmm_planning import PLANNERS

    return PLANNERS if choice == "all" else (choice,)


def run_plan(args: argparse.Namespace) -> int:
    from algorithms.probing.dmis import write_dmis_file
    from twin.formats.teach import load_teach
    from twin.io.cmm_files import plan_report
    from twin.workflows.cmm import plan_programs

    teach = load_teach(args.teach)
    setup = _setup(args.scenario)
    out, _ = checked_outputs(args)
    with reporting(args, "cmm plan") as say, Staged(out) as stage:
        plans = plan_programs(teach, setup, _methods(args.planner))
        say(f"planned {', '.join(plans)}")
        report: dict[str, Any] = {"teach": str(args.teach), "scenario": str(args.scenario), "plans": {}}
        for m, p in plans.items():
            write_dmis_file(p.program, stage.folder / f"{m}.dmi")
            report["plans"][m] = plan_report(p) | {"program": str(out / f"{m}.dmi")}
        write_json(stage.folder / PLAN_FILE, report)
        stage.commit()
    rows = [(m, f"{len(r['gotos'])} GOTOs, {len(r['predicted_collisions'])} predicted collisions"
             + (f", {len(r['unresolved'])} moves not cleared" if r["unresolved"] else ""))
            for m, r in report["plans"].items()]
    print_result(args, report, rows, indent=2)
    # with all three, the baseline's and the document's collisions are what the comparison shows;
    # the full check's program, or the one planner asked for, must be clear
    judged = report["plans"] if args.planner != "all" else {"full_check": report["plans"]["full_check"]}
    bad = any(r["unresolved"] for r in report["plans"].values()) or any(
        r["predicted_collisions"] for r in judged.values())
    return EXIT_UNTRUSTED if bad else EXIT_OK


def _rng(setup, seed: int | None) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(setup.scenario.seed if seed is None else seed))


def run_program(args: argparse.Namespace) -> int:
    from algorithms.errors import AlgorithmError
    from algorithms.probing.dmis import read_dmis
    from twin.cmm_machine import execute
    from twin.errors import TwinError
    from twin.io.cmm_files import run_report, write_hits_csv

    try:
        program = read_dmis(args.program)
    except AlgorithmError as exc:
        raise TwinError(str(exc)) from None
    setup = _setup(args.scenario)
    out, rrd = checked_outputs(args)
    t0 = time.perf_counter()
    with reporting(args, "cmm run") as say, Staged(out) as stage:
        run = execute(program, setup, _rng(setup, args.seed))
        say(f"ran {program.name!r}: {run.cycle_time_s:.1f} s, {len(run.contacts)} contacts")
        report = run_report(run) | {"scenario": str(args.scenario), "dmis": str(args.program)}
        write_hits_csv(stage.folder / HITS_FILE, run)
        if rrd is not None:
            from twin.viz.cmm import save_cmm_recording

            save_cmm_recording(stage.file(rrd), setup, {"program": run})
            report["recording"] = str(rrd)
        report["wall_s"] = round(time.perf_counter() - t0, 2)
        write_json(stage.folder / REPORT_FILE, report)
        stage.commit()
    print_result(args, report, _run_rows(report), indent=2)
    return EXIT_UNTRUSTED if report["contacts"] or report["misses"] else EXIT_OK


def _run_rows(r: dict) -> list[tuple[str, str]]:
    rows = [("program", r["program"]), ("contacts", str(r["contacts"])), ("misses", str(r["misses"])),
            ("path length", number(1e3 * r["path_length_m"], "mm", 5)), ("cycle time", number(r["cycle_time_s"], "s"))]
    for c in r["contact_list"][:5]:
        rows.append(("  contact", f"{c['solid']} in statement {c['statement']} ({c['move']}) at t = "
                                  f"{c['first_t_s']:.3f} s, part point " +
                     "(" + ", ".join(f"{1e3 * x:.1f}" for x in c["part_point_m"]) + ") mm"))
    return rows


def run_compare(args: argparse.Namespace) -> int:
    from algorithms.probing.dmis import write_dmis_file
    from twin.cmm_machine import execute
    from twin.formats.teach import load_teach
    from twin.io.cmm_files import comparison_table, plan_report, run_report
    from twin.workflows.cmm import plan_programs

    teach = load_teach(args.teach)
    setup = _setup(args.scenario)
    out, rrd = checked_outputs(args, "cmm.rrd")
    t0 = time.perf_counter()
    with reporting(args, "cmm compare") as say, Staged(out) as stage:
        plans = plan_programs(teach, setup)
        rows: list[dict[str, Any]] = []
        runs = {}
        for m, p in plans.items():
            write_dmis_file(p.program, stage.folder / f"{m}.dmi")
            run = execute(p.program, setup, _rng(setup, args.seed))
            runs[m] = run
            say(f"{m}: {len(run.contacts)} contacts, {run.cycle_time_s:.1f} s")
            rows.append({"method": m, "plan": plan_report(p), "run": run_report(run)})
        table = comparison_table(rows)
        title = f"{teach.name} on {setup.scenario.name}"
        (stage.folder / TABLE_FILE).write_text(f"# {title}\n\n{table}")
        report: dict[str, Any] = {"teach": str(args.teach), "scenario": str(args.scenario), "programs": rows}
        if rrd is not None:
            from twin.viz.cmm import save_cmm_recording

            save_cmm_recording(stage.file(rrd), setup, runs, table=table, title=title)
            report["recording"] = str(rrd)
        report["wall_s"] = round(time.perf_counter() - t0, 2)
        write_json(stage.folder / REPORT_FILE, report)
        stage.commit()
    summary = {r["method"]: {"contacts": r["run"]["contacts"], "predicted_collisions":
                             len(r["plan"]["predicted_collisions"]), "path_length_m": r["run"]["path_length_m"],
                             "cycle_time_s": r["run"]["cycle_time_s"], "misses": r["run"]["misses"],
                             "unresolved": len(r["plan"]["unresolved"])} for r in rows}
    print_result(args, summary, [(m, f"{s['contacts']} contacts, {s['predicted_collisions']} predicted, "
                                     f"{1e3 * s['path_length_m']:.0f} mm, {s['cycle_time_s']:.1f} s, "
                                     f"{s['misses']} misses") for m, s in summary.items()], indent=2)
    full = summary["full_check"]
    return EXIT_UNTRUSTED if full["contacts"] or full["misses"] or full["unresolved"] else EXIT_OK


def _stylus_map(items: list[str]) -> dict[str, str]:
    from twin.errors import TwinError

    out: dict[str, str] = {}
    for item in items:
        program, eq, machine = item.partition("=")
        if not eq or not program.strip() or not machine.strip():
            raise TwinError(f"--stylus {item!r} is not PROGRAM=MACHINE (a stylus label of the program, '=', one of "
                            "the machine's)")
        out[program.strip().upper()] = machine.strip()
    return out


def _part_setup(part: str, units: str, fixture: str):
    """The twin's bridge CMM (:data:`PART_TEMPLATE`'s machine, probe and styli) with ``part`` on the
    table at ``fixture`` (X,Y,Z [m], RX,RY,RZ [deg]), its true pose the one the program expects."""
    from pathlib import Path

    from twin.cmm_machine import cmm_setup
    from twin.errors import TwinError
    from twin.formats.toml_files import read_toml
    from twin.scenario import merge_tables, parse_scenario

    try:
        values = [float(x) for x in fixture.split(",")]
    except ValueError:
        values = []
    if len(values) != 6 or not all(np.isfinite(values)):
        raise TwinError(f"--fixture {fixture!r} is not X,Y,Z,RX,RY,RZ (six numbers: metres, then degrees)")
    template = Path(__file__).resolve().parents[2] / "scenarios" / PART_TEMPLATE
    raw = read_toml(template, "scenario")
    pose = {"xyz": values[:3], "rpy_deg": values[3:]}
    workpiece = {"mesh": str(Path(part).resolve()), "units": units, "true_pose": pose, "nominal_pose": pose}
    raw = merge_tables({k: v for k, v in raw.items() if k != "workpiece"},
                       {"name": f"cmm_{Path(part).stem}", "workpiece": workpiece})
    return cmm_setup(parse_scenario(raw, name=Path(part).stem, base_dir=template.parent, source=str(template)))


def _check_rows(s: dict) -> list[tuple[str, str]]:
    skipped = [n for n in s["notices"] if n["kind"] == "skipped"]
    rows = [("program", f"{s['program']} ({s['encoding']}, {len(s['files'])} file(s), "
                        f"{s['statements_executed']} statements executed)"),
            ("features", f"{len(s['features'])}, {len(s['measurements'])} measured with {s['touches']} touches"),
            ("moves", f"{s['moves']} GOTOs, {len(s['stylus_changes'])} stylus changes "
                      f"({', '.join(sorted({c['stylus'] for c in s['stylus_changes']})) or 'none'})"),
            ("evaluation", f"{len(s['constructions'])} constructions, {len(s['alignments'])} alignments, "
                           f"{len(s['tolerances'])} tolerances, {len(s['outputs'])} outputs"),
            ("not run", f"{len(skipped)} statements skipped, {len(s['notices']) - len(skipped)} warnings")]
    words: dict[str, list[int]] = {}
    for n in skipped:
        words.setdefault(n["word"] or "(free text)", []).append(n["line"])
    for word, lines in sorted(words.items(), key=lambda kv: -len(kv[1]))[:8]:
        more = ", ..." if len(lines) > 5 else ""
        rows.append((f"  {word}", f"{len(lines)} (line {', '.join(map(str, lines[:5]))}{more})"))
    return rows


def run_check(args: argparse.Namespace) -> int:
    from algorithms.errors import AlgorithmError
    from algorithms.probing.dmis.reader import read_program
    from twin.errors import TwinError
    from twin.io.dmis_files import summary

    stylus_names = _stylus_map(args.stylus)
    if args.scenario is not None and args.part is not None:
        raise TwinError("give a SCENARIO or --part FILE to run the program on, not both")
    runs = args.scenario is not None or args.part is not None
    if runs and args.out is None:
        raise TwinError("twin cmm check with a SCENARIO or --part runs the program: give --out DIR for its results")
    if not runs and (args.rrd or args.stylus or args.seed is not None):
        raise TwinError("--rrd, --stylus and --seed need a SCENARIO or --part to run the program on")
    outputs = checked_outputs(args) if args.out is not None else None  # before any work
    try:
        model = read_program(args.program)
    except AlgorithmError as exc:
        raise TwinError(str(exc)) from None
    info = summary(model)
    if not runs:
        if outputs is not None:
            with Staged(outputs[0]) as stage:
                write_json(stage.folder / CHECK_FILE, info)
                stage.commit()
        print_result(args, info, _check_rows(info), indent=2)
        return EXIT_OK
    assert outputs is not None
    return _run_check(args, model, info, stylus_names, outputs)


def _run_check(args: argparse.Namespace, model, info: dict, stylus_names: dict[str, str],
               outputs: tuple) -> int:
    from algorithms.probing.dmis.output import write_output
    from twin.io.cmm_files import run_report, write_hits_csv
    from twin.io.dmis_files import results, write_results_csv, write_results_html
    from twin.workflows.cmm import run_dmis

    setup = _setup(args.scenario) if args.scenario is not None else _part_setup(args.part, args.units, args.fixture)
    out, rrd = outputs
    t0 = time.perf_counter()
    with reporting(args, "cmm check") as say, Staged(out) as stage:
        dr = run_dmis(model, setup, _rng(setup, args.seed), stylus_names)
        run = run_report(dr.run)
        ev = dr.evaluation
        say(f"ran {model.name!r}: {dr.run.cycle_time_s:.1f} s, {len(dr.run.contacts)} contacts, {dr.run.misses} misses")
        checks = [("every touch hit", run["misses"] == 0, f"{run['misses']} of {run['measured_points']} missed"),
                  ("no unintended contact", run["contacts"] == 0, f"{run['contacts']} contacts"),
                  ("every tolerance evaluated", all(t.in_tolerance is not None for t in ev.tolerances),
                   f"{sum(t.in_tolerance is None for t in ev.tolerances)} of {len(ev.tolerances)} not evaluated"),
                  ("every tolerance in", all(t.in_tolerance is not False for t in ev.tolerances),
                   f"{sum(t.in_tolerance is False for t in ev.tolerances)} of {len(ev.tolerances)} out")]
        verdict = "PASS" if all(ok for _, ok, _ in checks) else "FAIL"
        report: dict[str, Any] = {"verdict": verdict, "checks": [{"check": c, "pass": ok, "detail": d}
                                                                 for c, ok, d in checks],
                                  "scenario": str(args.scenario or setup.scenario.source), "part": args.part,
                                  "dmis": str(args.program), "program": info,
                                  "results": results(ev), "run": run}
        (stage.folder / DMO_FILE).write_text(write_output(model, ev), encoding="utf-8")
        write_results_csv(stage.folder / RESULTS_FILE, ev)
        write_results_html(stage.folder / PAGE_FILE, model, ev, run, checks, verdict)
        write_hits_csv(stage.folder / HITS_FILE, dr.run)
        if rrd is not None:
            from twin.viz.cmm import save_cmm_recording

            save_cmm_recording(stage.file(rrd), setup, {"program": dr.run})
            report["recording"] = str(rrd)
        report["wall_s"] = round(time.perf_counter() - t0, 2)
        write_json(stage.folder / REPORT_FILE, report)
        stage.commit()
    rows = [("verdict", verdict)] + [(f"  {c}", ("pass" if ok else "FAIL") + f" ({d})") for c, ok, d in checks]
    for t in ev.tolerances:
        value = "not evaluated: " + t.note if t.in_tolerance is None else (
            f"{1e3 * (t.actual_m or 0.0):.4f} mm in [{1e3 * (t.lower_m or 0.0):.4f}, {1e3 * (t.upper_m or 0.0):.4f}]"
            f" {'in' if t.in_tolerance else 'OUT'}")
        rows.append((f"  {t.label} ({t.kind} {','.join(t.features)})", value))
    print_result(args, {k: report[k] for k in ("verdict", "checks", "results", "run")}, rows, indent=2)
    return EXIT_OK if verdict == "PASS" else EXIT_UNTRUSTED

"""Document 002's planners on the CMM: the document's experiments, the below-the-plane case, and
randomized teach sequences, each program run in the twin with its contacts counted.

Sections:

* ``experiments``: the shipped teach files (``scenarios/cmm/teach``): for each, the three
  programs (safe-plane baseline, document 002's algorithm, the full-check variant) planned,
  written as DMIS, run at 1 ms: GOTOs, predicted collisions (the swept check), contacts in
  the twin with the first one located, path length, cycle time, misses;
* ``random``: N randomized teach sequences (``twin.teaching``: 2-4 features on top, in
  cavities and bores, in both ends of the through hole, visited in a random order, the
  operator sometimes going around an obstacle below the top face), each planned three ways
  and run: per planner, how many sequences hit the part.

Run from the repository root: ``python -m benchmarks.bench_cmm --random 20`` (writes
``benchmarks/results_cmm.md``; ``--workers`` spreads the random sequences over processes,
each sequence's numbers depend only on its index).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from tests.helpers import commit_stamp

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENTS = (("inner_sphere", "inner_sphere"), ("through_hole", "through_hole"),
               ("inner_sphere", "inner_sphere_below_plane"))


def _setup(part: str):
    from twin.cmm_machine import cmm_setup
    from twin.scenario import load_scenario

    return cmm_setup(load_scenario(ROOT / "scenarios" / "cmm" / f"{part}.toml", machine="cmm"))


def _rows(teach, setup, seed: int) -> list[dict]:
    from twin.cmm_machine import execute
    from twin.io.cmm_files import plan_report, run_report
    from twin.workflows.cmm import plan_programs

    rows = []
    for m, p in plan_programs(teach, setup).items():
        run = execute(p.program, setup, np.random.default_rng(seed))
        rows.append({"method": m, "plan": plan_report(p), "run": run_report(run), "dmis": _read_back(p.program)})
    return rows


def _read_back(program) -> dict:
    """The program written as DMIS and read back by both readers: the strict one (the format the
    planners write) and the general one (programs from measurement software), lowered to moves."""
    from algorithms.probing.dmis import parse_dmis, write_dmis
    from algorithms.probing.dmis.model import lower
    from algorithms.probing.dmis.reader import parse_program

    text = write_dmis(program)
    return {"lines": len(text.splitlines()), "strict": parse_dmis(text) == program,
            "general": lower(parse_program(text)).program == program}


def _read_back_table(rows: list[dict]) -> str:
    lines = ["| program | DMIS lines | read back, strict reader | read back, general reader |", "|---|---|---|---|"]
    for r in rows:
        d = r["dmis"]
        lines += [f"| {r['method']} | {d['lines']} | {'same' if d['strict'] else 'differs'} | "
                  f"{'same' if d['general'] else 'differs'} |"]
    return "\n".join(lines)


def experiments() -> str:
    from twin.formats.teach import load_teach
    from twin.io.cmm_files import comparison_table

    out = []
    for part, teach in EXPERIMENTS:
        t0 = time.perf_counter()
        rows = _rows(load_teach(ROOT / "scenarios" / "cmm" / "teach" / f"{teach}.toml"), _setup(part), 1)
        out.append(f"### {teach} (scenarios/cmm/{part}.toml)\n\n{comparison_table(rows)}\n"
                   f"({time.perf_counter() - t0:.1f} s to plan and run the three)\n\n"
                   f"Each program written as DMIS and read back (the same program: every statement, point and "
                   f"setting):\n\n{_read_back_table(rows)}\n")
    return "\n".join(out)


def _random_one(i: int) -> dict:
    from twin.teaching import PARTS, random_teach

    part = PARTS[i % len(PARTS)]
    setup = _setup(part)
    teach = random_teach(part, setup, np.random.default_rng(np.random.SeedSequence(2002, spawn_key=(i,))),
                         name=f"random_{i}")
    rows = _rows(teach, setup, i)
    return {"i": i, "part": part, "touches": len(teach.touches), "rows": rows}


def random_section(n: int, workers: int) -> str:
    from algorithms.probing.cmm_planning import PLANNERS

    with ProcessPoolExecutor(workers) as pool:
        results = list(pool.map(_random_one, range(n)))
    hit = {m: 0 for m in PLANNERS}
    contacts = {m: 0 for m in PLANNERS}
    unresolved = {m: 0 for m in PLANNERS}
    length = {m: [] for m in PLANNERS}
    cycle = {m: [] for m in PLANNERS}
    lines = ["| # | part | points | " + " | ".join(f"{m} contacts" for m in PLANNERS) + " |",
             "|---|---|---|" + "---|" * len(PLANNERS)]
    for r in results:
        cells = []
        for row in r["rows"]:
            m, c = row["method"], row["run"]["contacts"]
            hit[m] += c > 0
            contacts[m] += c
            unresolved[m] += len(row["plan"]["unresolved"]) > 0
            length[m].append(row["run"]["path_length_m"])
            cycle[m].append(row["run"]["cycle_time_s"])
            cells.append(str(c))
        lines.append(f"| {r['i']} | {r['part']} | {r['touches']} | " + " | ".join(cells) + " |")
    summary = ["| planner | sequences with a contact | contacts | moves not cleared | mean path [mm] | "
               "mean cycle [s] |", "|---|---|---|---|---|---|"]
    for m in PLANNERS:
        summary.append(f"| {m} | {hit[m]} of {n} | {contacts[m]} | {unresolved[m]} | "
                       f"{1e3 * np.mean(length[m]):.0f} | {np.mean(cycle[m]):.1f} |")
    return "\n".join(summary) + "\n\nPer sequence:\n\n" + "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--random", type=int, default=20, help="randomized teach sequences (default 20)")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results_cmm.md"))
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    text = ["# CMM measurement programs (document 002)", "",
            f"Command: `python -m benchmarks.bench_cmm --random {args.random} --workers {args.workers}`; "
            f"commit {commit_stamp()}; {platform.processor() or platform.machine()}, {os.cpu_count()} cores, Python "
            f"{sys.version.split()[0]}.", "",
            "Contacts are counted in the twin (every 1 ms sample of the executed motion against the exact part); "
            "predicted collisions are the planner's swept check of the program's moves.", "",
            "## The document's experiments and the below-the-plane case", "", experiments(),
            f"## {args.random} randomized teach sequences", "", random_section(args.random, args.workers)]
    text.append(f"\nTotal {time.perf_counter() - t0:.0f} s.\n")
    Path(args.out).write_text("\n".join(text))
    print("\n".join(text))
    return 0


if __name__ == "__main__":
    sys.exit(main())

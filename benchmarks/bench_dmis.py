"""DMIS programs from measurement software in the twin: the conformance corpus of
tests/data/dmis read (what each holds, what is skipped, how long reading takes), and the plate
program run on the bore_and_face cell with its tolerances evaluated, with its three datums and
with datum C left out.

    python -m benchmarks.bench_dmis [--out benchmarks/results_dmis.md]
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from algorithms.probing.dmis.reader import parse_program, read_program
from algorithms.probing.dmis.writer import write_model
from tests.helpers import ROOT, commit_stamp
from twin.cmm_machine import cmm_setup
from twin.scenario import load_scenario
from twin.workflows.cmm import run_dmis

DATA = ROOT / "tests" / "data" / "dmis"
SCENARIO = ROOT / "scenarios" / "cmm" / "bore_and_face.toml"
REPEATS = 5


def corpus_section() -> list[str]:
    rows = ["| program | encoding | files | statements executed | features | touches | moves | skipped (words) | "
            "read [ms] | written back and read again |", "|---|---|---|---|---|---|---|---|---|---|"]
    for path in sorted(DATA.glob("*.dm[is]")):
        if path.name == "modus_datum.dmi":
            continue  # called by modus_macros.dms
        times = []
        for _ in range(REPEATS):
            t0 = time.perf_counter()
            m = read_program(path)
            times.append(time.perf_counter() - t0)
        again = parse_program(write_model(m), str(path))
        same = len(again.touches) == len(m.touches) and all(
            np.allclose(a.point_m, b.point_m, atol=2e-9) for a, b in zip(again.touches, m.touches, strict=True))
        skipped = m.unsupported()
        words = sorted({n.word or "free text" for n in skipped})
        rows.append(f"| {path.name} | {m.encoding} | {len(m.sources)} | {m.statements_executed} | {len(m.features)} | "
                    f"{len(m.touches)} | {len(m.moves)} | {len(skipped)} ({', '.join(words)}) | "
                    f"{1e3 * statistics.median(times):.1f} | {'same' if same else 'DIFFERENT'} |")
    errors = sorted((DATA / "errors").iterdir())
    return ["## The corpus", "", *rows, "",
            f"And {len(errors)} error programs in `tests/data/dmis/errors/`, each refused in one line with its file "
            "and line (`tests/test_dmis_reader.py`)."]


def run_section(name: str, text: str) -> tuple[list[str], str]:
    setup = cmm_setup(load_scenario(SCENARIO, machine="cmm"))
    model = parse_program(text, str(DATA / "plate_bore.dmi"))
    t0 = time.perf_counter()
    dr = run_dmis(model, setup, np.random.default_rng(np.random.SeedSequence(setup.scenario.seed)), {"T1A0B0": "S1"})
    wall = time.perf_counter() - t0
    ev = dr.evaluation
    rows = [f"### {name}", "",
            f"{len(dr.run.hits)} touches, {dr.run.misses} missed, {len(dr.run.contacts)} unintended contacts, "
            f"cycle {dr.run.cycle_time_s:.1f} s (simulated at 1 ms in {wall:.1f} s); verdict **{ev.verdict}**.", "",
            "| tolerance | type | feature | nominal [mm] | actual [mm] | limits [mm] | deviation [um] | result |",
            "|---|---|---|---|---|---|---|---|"]
    for t in ev.tolerances:
        result = "not evaluated" if t.in_tolerance is None else ("in" if t.in_tolerance else "OUT")
        rows.append(f"| {t.label} | {t.kind} | {', '.join(t.features)} | {1e3 * (t.nominal_m or 0):.4f} | "
                    f"{1e3 * (t.actual_m or 0):.4f} | {1e3 * (t.lower_m or 0):.4f} to {1e3 * (t.upper_m or 0):.4f} | "
                    f"{1e6 * (t.deviation_m or 0):+.1f} | {result} |")
    touch_dev = [h.deviation_m for h in dr.run.hits if h.deviation_m is not None]
    return rows, f"{1e6 * float(np.median(touch_dev)):.1f}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results_dmis.md")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    text = (DATA / "plate_bore.dmi").read_text()
    two = text.replace(",DAT(C),YORIG", "").replace("62,46,", "62,6,").replace(",46,-15", ",6,-15")
    two = two.replace(",54,-15", ",14,-15").replace(",38,-15", ",-2,-15")
    three_rows, median_dev = run_section("plate_bore.dmi: datums A (top), B (side), C (front)", text)
    two_rows, _ = run_section("the same without datum C (the bore's y from the machine's nominal frame)", two)
    lines = [
        "# DMIS programs from measurement software in the twin", "",
        commit_stamp(), "",
        f"Command: `python -m benchmarks.bench_dmis` ({platform.machine()}, {time.perf_counter() - t0:.0f} s wall).",
        "", *corpus_section(), "",
        "## The plate program on the bore_and_face cell", "",
        "`twin cmm check tests/data/dmis/plate_bore.dmi scenarios/cmm/bore_and_face.toml --out DIR "
        "--stylus T1A0B0=S1` does this run. The part lies 0.1 mm and 0.01 deg off the nominal pose the program "
        "starts from. The touches are compensated with the nominal ball radius, as `twin cmm run` does (the twin's "
        f"CMM has no stylus qualification): the probe's pre-travel shows in every touch (median {median_dev} um "
        "along the normal) and in what depends on one side of the part only (the bore's diameter, distances from "
        "one datum face).", "",
        *three_rows, "", *two_rows, "",
    ]
    args.out.write_text("\n".join(lines))
    print(args.out.read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Scan-cell speed: simulated seconds per wall-clock second.

* point sensor with full arm dynamics (servos, gravity compensation, contacts on) on the
  S-surface scan: the 1 ms rollout alone, and the whole scan (planning + IK + sensor model);
* the line profiler: 1024 beams at 1 kHz, sensor samples (beam distances) per second.

The scenario is realized once and its nominal and true cells built once per case; the times
exclude that set-up.

Run from the repository root: ``python -m benchmarks.bench_scan`` (prints a markdown table;
numbers are best of 3). ``--max-lines N`` scans only the first N lines of the point-sensor
case (a quick check that the script runs, not a benchmark).
"""

from __future__ import annotations

import argparse
import platform
import time

import mujoco
import numpy as np

from tests.helpers import scenario
from twin.cell import build_cell
from twin.plan import plan_scan
from twin.realize import realize
from twin.scan import run_scan, solve_joint_references
from twin.sim import simulate


def best_of(fn, n=3):
    best = np.inf
    for _ in range(n):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def _ignore(i0, sens, q_before):
    """A rollout callback that keeps nothing (the rollout alone is timed)."""


def _cells(sc):
    realized = realize(sc)
    return realized, build_cell(realized, "nominal"), build_cell(realized, "true")


def point_sensor(rows, max_lines=None):
    sc = scenario("s_surface", **({"scan": {"max_lines": max_lines}} if max_lines else {}))
    realized, nominal, true = _cells(sc)
    plan = plan_scan(nominal)
    q_ref, qd_ref = solve_joint_references(nominal, plan)
    sim_s = len(q_ref) * 0.001
    wall = best_of(lambda: simulate(true, q_ref, qd_ref, _ignore))
    rows.append(("point sensor, 1 ms rollout, contacts on", f"{sim_s:.1f}", f"{wall:.3f}", f"{sim_s / wall:.0f}x"))
    flags = true.model.opt.disableflags
    true.model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    wall = best_of(lambda: simulate(true, q_ref, qd_ref, _ignore))
    true.model.opt.disableflags = flags  # the whole scan below runs with contacts, as a scan does
    rows.append(("point sensor, 1 ms rollout, contacts off", f"{sim_s:.1f}", f"{wall:.3f}", f"{sim_s / wall:.0f}x"))
    wall = best_of(lambda: run_scan(realized, nominal, true), n=1)
    rows.append(("point sensor, whole scan (plan + IK + rollout + sensor model + eq. 2)",
                 f"{sim_s:.1f}", f"{wall:.3f}", f"{sim_s / wall:.0f}x"))


def line_profiler(rows, beams=1024):
    sc = scenario("s_surface", sensor={"kind": "line", "beams": beams, "fan_deg": 20.0},
                  scan={"max_lines": 1, "line_axis": "y", "region_m": [[-0.02, -0.035], [0.02, 0.035]]})
    realized, nominal, true = _cells(sc)
    plan = plan_scan(nominal)
    q_ref, qd_ref = solve_joint_references(nominal, plan)
    sim_s = len(q_ref) * 0.001
    wall = best_of(lambda: simulate(true, q_ref, qd_ref, _ignore))
    rows.append((f"line profiler {beams} beams, 1 ms rollout", f"{sim_s:.1f}", f"{wall:.3f}",
                 f"{sim_s / wall:.2f}x ({len(q_ref) * beams / wall / 1e6:.2f} M samples/s)"))
    wall = best_of(lambda: run_scan(realized, nominal, true), n=1)
    rows.append((f"line profiler {beams} beams, whole scan", f"{sim_s:.1f}", f"{wall:.3f}",
                 f"{sim_s / wall:.2f}x ({len(q_ref) * beams / wall / 1e6:.2f} M samples/s)"))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--max-lines", type=int, default=None,
                    help="scan only this many lines in the point-sensor case (quick check)")
    ap.add_argument("--beams", type=int, default=1024, help="beams of the line profiler")
    args = ap.parse_args(argv)
    rows = []
    point_sensor(rows, args.max_lines)
    line_profiler(rows, args.beams)
    machine = platform.processor() or platform.machine()
    print(f"mujoco {mujoco.__version__}, {machine}, python {platform.python_version()}")
    print("| case | simulated s | wall s | speed (x real time) |")
    print("|---|---|---|---|")
    for r in rows:
        print("| " + " | ".join(r) + " |")


if __name__ == "__main__":
    main()

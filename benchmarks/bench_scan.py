"""Scan-cell speed: simulated seconds per wall-clock second.

* point sensor with full arm dynamics (servos, gravity compensation, contacts on) on the
  S-surface scan: the 1 ms rollout alone, and the whole scan (planning + IK + sensor model);
* the line profiler: 1024 beams at 1 kHz, sensor samples (beam distances) per second.

Run: ``python benchmarks/bench_scan.py`` (prints a markdown table; numbers are best of 3).
"""

from __future__ import annotations

import dataclasses
import platform
import sys
import time
from pathlib import Path

import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from tests.helpers import scenario  # noqa: E402
from twin.cell import build_cell, load_workpiece_mesh  # noqa: E402
from twin.plan import plan_scan  # noqa: E402
from twin.scan import run_scan, simulate, solve_joint_references  # noqa: E402


def best_of(fn, n=3):
    best = np.inf
    for _ in range(n):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def point_sensor(rows):
    sc = scenario("s_surface")
    mesh = load_workpiece_mesh(sc)
    nominal, true = build_cell(sc, "nominal", mesh), build_cell(sc, "true", mesh)
    plan = plan_scan(nominal)
    q_ref, qd_ref = solve_joint_references(nominal, plan)
    sim_s = len(q_ref) * 0.001
    wall = best_of(lambda: simulate(true, q_ref, qd_ref, lambda *a: None))
    rows.append(("point sensor, 1 ms rollout, contacts on", f"{sim_s:.1f}", f"{wall:.3f}", f"{sim_s / wall:.0f}x"))
    true.model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    wall = best_of(lambda: simulate(true, q_ref, qd_ref, lambda *a: None))
    rows.append(("point sensor, 1 ms rollout, contacts off", f"{sim_s:.1f}", f"{wall:.3f}", f"{sim_s / wall:.0f}x"))
    wall = best_of(lambda: run_scan(sc, mesh=mesh), n=1)
    rows.append(("point sensor, whole scan (plan + IK + rollout + sensor model + eq. 2)",
                 f"{sim_s:.1f}", f"{wall:.3f}", f"{sim_s / wall:.0f}x"))


def line_profiler(rows, beams=1024):
    sc = scenario("s_surface", sensor={"kind": "line", "beams": beams, "fan_deg": 20.0},
                  scan={"max_lines": 1, "line_axis": "y", "region_m": [[-0.02, -0.035], [0.02, 0.035]]})
    mesh = load_workpiece_mesh(sc)
    nominal, true = build_cell(sc, "nominal", mesh), build_cell(sc, "true", mesh)
    plan = plan_scan(nominal)
    q_ref, qd_ref = solve_joint_references(nominal, plan)
    sim_s = len(q_ref) * 0.001
    wall = best_of(lambda: simulate(true, q_ref, qd_ref, lambda *a: None))
    rows.append((f"line profiler {beams} beams, 1 ms rollout", f"{sim_s:.1f}", f"{wall:.3f}",
                 f"{sim_s / wall:.2f}x ({len(q_ref) * beams / wall / 1e6:.2f} M samples/s)"))
    wall = best_of(lambda: run_scan(dataclasses.replace(sc), mesh=mesh), n=1)
    rows.append((f"line profiler {beams} beams, whole scan", f"{sim_s:.1f}", f"{wall:.3f}",
                 f"{sim_s / wall:.2f}x ({len(q_ref) * beams / wall / 1e6:.2f} M samples/s)"))


def main():
    rows = []
    point_sensor(rows)
    line_profiler(rows)
    print(f"mujoco {mujoco.__version__}, {platform.processor() or platform.machine()}, python {platform.python_version()}")
    print("| case | simulated s | wall s | speed (x real time) |")
    print("|---|---|---|---|")
    for r in rows:
        print("| " + " | ".join(r) + " |")


if __name__ == "__main__":
    main()

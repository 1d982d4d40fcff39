"""Scan-cell speed: simulated seconds per wall-clock second.

* point sensor with full arm dynamics (servos, gravity compensation, contacts on) on the
  S-surface scan: the 1 ms rollout alone, and the whole scan (planning + IK + sensor model);
* the line profiler: 1024 beams at 1 kHz, sensor samples (beam distances) per second: the
  beams cast in bulk after the rollout (``twin.sensors.raycast``), against MuJoCo's camera
  rangefinder of the same fan evaluated inside the rollout (the peer), and the whole scan.

The scenario is realized once and its nominal and true cells built once per case; the times
exclude that set-up.

Run from the repository root: ``python -m benchmarks.bench_scan`` (prints a markdown table
and writes it to ``benchmarks/results_scan.md``, ``--out`` elsewhere; numbers are best of 3).
Each figure is also given as a ratio to its limit measured in the same run: real time (1 ms
of simulated time per ms), and MuJoCo's own ``rollout`` of the same model and joint references
(``twin.sim.simulate`` is that rollout with the sensor read-out); for the line profiler,
MuJoCo's ``rollout`` of the same cell with a camera rangefinder casting the same 1024 beams
inside every step. ``--max-lines N`` scans only
the first N lines of the point-sensor case (a quick check that the script runs, not a
benchmark); ``--line-only`` runs the line profiler case alone.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import mujoco
import numpy as np

from tests.helpers import scenario
from twin.cell import build_cell, build_spec, compile_cell
from twin.plan import plan_scan
from twin.realize import realize
from twin.scan import SampleLog, run_scan, solve_joint_references
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
    rollout_wall = wall
    rows.append(("point sensor, 1 ms rollout, contacts on", f"{sim_s:.1f}", f"{wall:.3f}", f"{sim_s / wall:.0f}x",
                 "1.00"))
    flags = true.model.opt.disableflags
    true.model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    wall = best_of(lambda: simulate(true, q_ref, qd_ref, _ignore))
    true.model.opt.disableflags = flags  # the whole scan below runs with contacts, as a scan does
    rows.append(("point sensor, 1 ms rollout, contacts off", f"{sim_s:.1f}", f"{wall:.3f}", f"{sim_s / wall:.0f}x",
                 f"{rollout_wall / wall:.2f}"))
    wall = best_of(lambda: run_scan(realized, nominal, true), n=1)
    rows.append(("point sensor, whole scan (plan + IK + rollout + sensor model + eq. 2)",
                 f"{sim_s:.1f}", f"{wall:.3f}", f"{sim_s / wall:.0f}x", f"{rollout_wall / wall:.2f}"))


def _with_camera_rangefinder(realized, beams, fan_deg):
    """The true cell with MuJoCo's camera rangefinder over the line profiler's fan (a 1-pixel-
    high perspective camera on the sensor's body: one ray per beam, cast inside mj_step)."""
    spec, poses = build_spec(realized, "true")
    half = np.radians(fan_deg) / 2
    spec.site("laser").parent.add_camera(name="fan_camera", pos=[0, 0, 0], quat=[0, 1, 0, 0], resolution=[beams, 1],
                                         fovy=float(np.degrees(2 * np.arctan(np.tan(half) / beams))))
    spec.add_sensor(name="fan_rays", type=mujoco.mjtSensor.mjSENS_RANGEFINDER, objtype=mujoco.mjtObj.mjOBJ_CAMERA,
                    objname="fan_camera", intprm=[1 | 2 | 16, 0, 0])
    return compile_cell(spec, realized, "true", poses)


def line_profiler(rows, beams=1024):
    fan_deg = 20.0
    sc = scenario("s_surface", sensor={"kind": "line", "beams": beams, "fan_deg": fan_deg},
                  scan={"max_lines": 1, "line_axis": "y", "region_m": [[-0.02, -0.035], [0.02, 0.035]]})
    realized, nominal, true = _cells(sc)
    plan = plan_scan(nominal)
    q_ref, qd_ref = solve_joint_references(nominal, plan)
    sim_s = len(q_ref) * 0.001
    samples = len(q_ref) * beams
    peer = _with_camera_rangefinder(realized, beams, fan_deg)
    peer_wall = best_of(lambda: simulate(peer, q_ref, qd_ref, _ignore))
    rows.append((f"line profiler {beams} beams: MuJoCo rollout with a camera rangefinder casting them in every "
                 "step (peer)", f"{sim_s:.1f}", f"{peer_wall:.3f}",
                 f"{sim_s / peer_wall:.2f}x ({samples / peer_wall / 1e6:.2f} M samples/s)", "1.00"))
    whole = (f"line profiler {beams} beams, whole scan (plan + IK + rollout + beams + sensor model with "
             "receiver rays + eq. 2)")
    # the first scan of a fresh cell builds the ray caster (Embree's scene) and maps its arrays afresh
    wall = best_of(lambda: run_scan(realized, nominal, true), n=1)
    rows.append((f"{whole}, first scan of the cell", f"{sim_s:.1f}", f"{wall:.3f}",
                 f"{sim_s / wall:.2f}x ({samples / wall / 1e6:.2f} M samples/s)", f"{peer_wall / wall:.2f}"))
    wall = best_of(lambda: run_scan(realized, nominal, true), n=3)
    rows.append((f"{whole}, best of the next 3", f"{sim_s:.1f}", f"{wall:.3f}",
                 f"{sim_s / wall:.2f}x ({samples / wall / 1e6:.2f} M samples/s)", f"{peer_wall / wall:.2f}"))
    log = SampleLog(true, len(q_ref))
    wall = best_of(lambda: simulate(true, q_ref, qd_ref, log.on_chunk))
    rows.append((f"line profiler {beams} beams: rollout, then the beams cast in bulk", f"{sim_s:.1f}",
                 f"{wall:.3f}", f"{sim_s / wall:.2f}x ({samples / wall / 1e6:.2f} M samples/s)",
                 f"{peer_wall / wall:.2f}"))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--max-lines", type=int, default=None,
                    help="scan only this many lines in the point-sensor case (quick check)")
    ap.add_argument("--beams", type=int, default=1024, help="beams of the line profiler")
    ap.add_argument("--line-only", action="store_true", help="only the line profiler case")
    ap.add_argument("--out", default=str(Path(__file__).with_name("results_scan.md")))
    args = ap.parse_args(argv)
    rows = []
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    if not args.line_only:
        point_sensor(rows, args.max_lines)
    line_profiler(rows, args.beams)
    load1 = os.getloadavg()
    machine = platform.processor() or platform.machine()
    cmd = " ".join(["python -m benchmarks.bench_scan"] + (argv if argv is not None else sys.argv[1:]))
    lines = [
        "# Scan-cell speed",
        "",
        f"Produced by `{cmd}` in {(time.perf_counter() - t0) / 60:.1f} min on {platform.node()}: "
        f"{machine}, {os.cpu_count()} CPUs, Python {platform.python_version()}, mujoco {mujoco.__version__}. "
        f"Load average (1 min) {load0[0]:.1f} at the start, {load1[0]:.1f} at the end: other processes "
        "share the machine, so the ratios (same run) mean more than the seconds.",
        "",
        "| case | simulated s | wall s | speed (x real time) | speed / MuJoCo rollout (line profiler: with the "
        "camera rangefinder) |",
        "|---|---|---|---|---|",
    ] + ["| " + " | ".join(r) + " |" for r in rows]
    text = "\n".join(lines) + "\n"
    print(text)
    Path(args.out).write_text(text)


if __name__ == "__main__":
    main()

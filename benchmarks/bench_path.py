"""Process-path speed and accuracy: IK per pose, replay speed, servo deviation vs feed, normals.

* ``ik``: mink IK along a 10,000-pose path (a CAD raster on the S-surface at 0.2 mm point
  spacing, tool frames along the normals, flange poses by eq. 13): wall time per pose, and
  per pose after the first (which is solved from the home posture);
* ``replay``: the default S-surface CAD path (1 mm points, 30 mm/s) replayed in the true
  cell with the tool at 1 ms, at each of ``--feeds``: simulated seconds per wall-clock
  second, for the rollout alone and for the whole verification (exact tip-to-part
  distances, deviation, contacts), and the max/RMS deviation of the replayed TCP from the
  planned path and the ball end's surface error (the servo lag);
* ``normals``: cross-line triangulation vs k-NN PCA normals against the analytic S-surface
  normals, on the full scan, noise off and on (``--normals-out`` writes the markdown table).

Run from the repository root:
``python -m benchmarks.bench_path [ik] [replay] [normals] [--feeds 10,30] [--normals-out FILE]``
(prints markdown; timings are best of 3 where stated). ``--max-lines N`` keeps only N lines
of the CAD raster and of the scan (a quick check that the script runs, not a benchmark).
"""

from __future__ import annotations

import argparse
import dataclasses
import platform
import sys
import time
from pathlib import Path

import numpy as np

from algorithms.geometry.se3 import inv_pose, transform_points
from algorithms.paths.normals import angle_deg, pca_normals, triangulation_normals
from algorithms.paths.pointcloud import organize_scan_lines, prepare_scan_lines, remove_outliers
from algorithms.paths.spline import fit_lines
from algorithms.paths.timing import time_law
from algorithms.paths.toolpath import build_path, cad_raster, flange_poses, transform_path
from tests.helpers import scenario
from twin.cell import build_cell
from twin.parts import s_surface_normal
from twin.process_paths import tool_settings
from twin.realize import Realized, realize
from twin.replay import build_replay_cell, replay
from twin.robot import ACCELERATION_LIMIT_RAD_S2, VELOCITY_LIMIT_RAD_S
from twin.scan import run_scan
from twin.sim import simulate
from twin.trajectory import plan_joint_trajectory, solve_path

PARTS = ("ik", "replay", "normals")


def cad_path_on_true_part(realized: Realized, point_spacing: float, max_lines: int | None = None):
    p = realized.scenario.path
    wp = realized.workpiece
    lines, normals = cad_raster(wp.mesh, p.line_spacing_m, point_spacing, p.margin_m, p.line_axis,
                                normals=wp.index.smooth_normals)
    if max_lines is not None:
        lines, normals = lines[:max_lines], normals[:max_lines]
    # the part where it really is (as after a perfect localization): deviations are the servo's
    return transform_path(realized.T_base_workpiece_true, build_path(lines, normals, tool_settings(realized.scenario)))


def bench_ik(realized: Realized, max_lines: int | None = None):
    sc = realized.scenario
    path = cad_path_on_true_part(realized, 0.0002, max_lines)
    T = flange_poses(path.T_tool, sc.path.T_flange_tool)
    nominal = build_cell(realized, "nominal")
    runs = [solve_path(nominal, T) for _ in range(3)]
    best = min(runs, key=lambda r: r.time_s)
    print(f"\n## IK along a {len(T)}-pose path (mink, daqp)\n")
    print("| poses | total [s] | per pose [ms] | per pose after the first [ms] | first pose [ms] | mean QP steps "
          "| max position error [um] |")
    print("|---|---|---|---|---|---|---|")
    print(f"| {len(T)} | {best.time_s:.3f} | {best.time_per_pose_ms:.4f} | {best.tracking_time_per_pose_ms:.4f} | "
          f"{best.first_pose_time_s * 1e3:.1f} | {best.iterations[1:].mean():.2f} | "
          f"{best.position_error_m.max() * 1e6:.3f} |")
    print(f"\n(best of 3; all runs per pose: {', '.join(f'{r.time_per_pose_ms:.4f}' for r in runs)} ms)")
    t0 = time.perf_counter()
    traj = time_law(path, best.q, sc.path.feed_m_s, sc.path.transit_speed_m_s, sc.path.acceleration_m_s2,
                    VELOCITY_LIMIT_RAD_S, ACCELERATION_LIMIT_RAD_S2,
                    touchdown_acceleration_m_s2=sc.path.touchdown_acceleration_m_s2)
    print(f"\nTime law for the same path: {time.perf_counter() - t0:.3f} s wall for {traj.duration_s:.1f} s of motion "
          f"({len(traj.t)} samples).")


def _ignore(i0, sens, q_before):
    """A rollout callback that keeps nothing (the rollout alone is timed)."""


def _time(fn):
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def bench_replay(realized: Realized, feeds, max_lines: int | None = None):
    sc = realized.scenario
    path = cad_path_on_true_part(realized, sc.path.point_spacing_m, max_lines)
    nominal = build_cell(realized, "nominal")
    cell = build_replay_cell(realized)
    rows = []
    for feed in feeds:
        _, traj = plan_joint_trajectory(nominal, path, sc.path.T_flange_tool, feed, sc.path.transit_speed_m_s,
                                        sc.path.acceleration_m_s2,
                                        touchdown_acceleration_m_s2=sc.path.touchdown_acceleration_m_s2)
        sim_s = len(traj.t) * traj.dt
        repeats = 3 if feed == sc.path.feed_m_s else 1
        t_roll = min(_time(lambda traj=traj: simulate(cell, traj.q, traj.qd, _ignore)) for _ in range(repeats))
        t0 = time.perf_counter()
        log = replay(cell, traj, path, realized.workpiece.index)
        t_all = time.perf_counter() - t0
        rows.append((feed, sim_s, t_roll, t_all, log.summary()))
    print(f"\n## Replay at 1 ms in the true cell (tool, height-field part, contact sensors), "
          f"CAD path of {len(path.T_tool)} poses\n")
    print("| feed [mm/s] | simulated [s] | rollout [s] | x real time | whole verification [s] | x real time | "
          "max deviation [mm] | RMS deviation [mm] | max tip surface error [mm] | max tracking error [mm] "
          "| unintended contacts |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for feed, sim_s, t_roll, t_all, s in rows:
        print(f"| {feed * 1e3:.0f} | {sim_s:.1f} | {t_roll:.2f} | {sim_s / t_roll:.0f} | {t_all:.2f} | "
              f"{sim_s / t_all:.0f} | {s['max_deviation_mm']:.3f} | {s['rms_deviation_mm']:.3f} | "
              f"{s['tip_surface_error_max_mm']:.3f} | {s['max_tracking_error_mm']:.3f} | {s['unintended_contacts']} |")


def _normals_rows(noise: str, cname: str, lines, orient, T) -> list[str]:
    """Rows of one cloud: triangulation and PCA at several k against the analytic normals."""
    pts = np.concatenate(lines)
    p_wp = transform_points(inv_pose(T), pts)
    n_true = s_surface_normal(p_wp[:, 0], p_wp[:, 1]) @ T[:3, :3].T

    def triangulation():
        return np.concatenate(triangulation_normals(lines, orient))

    methods = [("triangulation (doc. 004)", triangulation, False)]
    for k in (8, 16, 32, 64, 128):
        methods.append((f"PCA k = {k}", lambda k=k: pca_normals(pts, k, orient), True))
    out = []
    for mname, fn, unsigned in methods:
        t0 = time.perf_counter()
        n = fn()
        dt = time.perf_counter() - t0
        a = angle_deg(n, n_true, unsigned=unsigned)
        out.append(f"| {noise} | {cname} | {len(pts)} | {mname} | {np.sqrt(np.mean(a**2)):.3f} | "
                   f"{np.percentile(a, 95):.3f} | {a.max():.2f} | {100 * np.mean(a > 5):.1f} % | {dt:.3f} |")
    return out


def normals_table(realized: Realized, max_lines: int | None = None) -> str:
    out = ["| noise | cloud | points | method | RMS [deg] | 95 % [deg] | max [deg] | > 5 deg | time [s] |",
           "|---|---|---|---|---|---|---|---|---|"]
    for noise in ("off", "on"):
        sc = scenario("s_surface", **({"scan": {"max_lines": max_lines}} if max_lines else {}))
        if noise == "off":
            sc = dataclasses.replace(sc, noise=sc.noise.all_off())
        # the same mesh (and its index) for both scans; each scenario is realized once
        r = realize(sc, realized.workpiece.mesh)
        scan = run_scan(r, build_cell(r, "nominal"), build_cell(r, "true"))
        T = scan.T_base_workpiece_true
        orient = T[:3, 2]
        points = scan.points_base[:, 0]  # the point sensor's one beam
        raw = remove_outliers(organize_scan_lines(points, scan.line))
        simp = prepare_scan_lines(points, scan.line)
        fits = fit_lines(simp.lines, 0.001)
        clouds = [("raw scan lines", raw.lines), ("simplified 0.2 mm", simp.lines),
                  ("B-spline, resampled 1 mm", fits.lines)]
        for cname, lines in clouds:
            out += _normals_rows(noise, cname, lines, orient, T)
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("parts", nargs="*", help=f"which tables, of {', '.join(PARTS)} (default: all)")
    ap.add_argument("--feeds", default="10,30,50,100", help="feeds [mm/s] of the replay table")
    ap.add_argument("--normals-out", help="write the normals table (markdown) to this file")
    ap.add_argument("--max-lines", type=int, default=None,
                    help="keep only this many CAD raster and scan lines (quick check, not a benchmark)")
    args = ap.parse_args(argv)
    parts = args.parts or list(PARTS)
    unknown = sorted(set(parts) - set(PARTS))
    if unknown:
        ap.error(f"unknown part(s) {', '.join(unknown)}; choose from {', '.join(PARTS)}")
    realized = realize(scenario("s_surface"))
    print(f"# bench_path on {platform.processor() or platform.machine()}, {platform.python_version()}")
    if "ik" in parts:
        bench_ik(realized, args.max_lines)
    if "replay" in parts:
        bench_replay(realized, [float(f) * 1e-3 for f in args.feeds.split(",")], args.max_lines)
    if "normals" in parts:
        table = normals_table(realized, args.max_lines)
        scope = f"first {args.max_lines} scan lines" if args.max_lines else "full scan, 19 lines"
        print(f"\n## Normals against the analytic S-surface normals ({scope} 4 mm apart)\n")
        print(table)
        if args.normals_out:
            Path(args.normals_out).write_text(table + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

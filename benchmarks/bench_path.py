"""Process-path speed and accuracy: IK per pose, replay speed, servo deviation vs feed, normals.

* ``ik``: mink IK along a 10,000-pose path (a CAD raster on the S-surface at 0.2 mm point
  spacing, tool frames along the normals, flange poses by eq. 13): wall time per pose, and
  per pose after the first (which is solved from the home posture);
* ``replay``: the default S-surface CAD path (1 mm points, 30 mm/s) replayed in the true
  cell with the tool at 1 ms: simulated seconds per wall-clock second, for the rollout alone
  and for the whole verification (exact tip-to-part distances, deviation, contacts);
* ``feeds``: the same path at several feeds: max/RMS deviation of the replayed TCP from the
  planned path and the ball end's surface error (the servo lag);
* ``normals``: cross-line triangulation vs k-NN PCA normals against the analytic S-surface
  normals, on the full scan, noise off and on (``--normals-out`` writes the markdown table).

Run: ``python benchmarks/bench_path.py [ik replay feeds normals] [--normals-out FILE]``
(prints markdown; timings are best of 3 where stated).
"""

from __future__ import annotations

import argparse
import dataclasses
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from algorithms.geometry.mesh_index import MeshIndex  # noqa: E402
from algorithms.paths.normals import angle_deg, pca_normals, triangulation_normals  # noqa: E402
from algorithms.paths.pointcloud import organize_scan_lines, prepare_scan_lines, remove_outliers  # noqa: E402
from algorithms.geometry.se3 import inv_pose, transform_points  # noqa: E402
from algorithms.paths.spline import fit_lines  # noqa: E402
from algorithms.paths.toolpath import build_path, cad_raster, flange_poses, transform_path  # noqa: E402
from tests.helpers import scenario  # noqa: E402
from twin.cell import build_cell, load_workpiece_mesh  # noqa: E402
from twin.cli.run import tool_settings  # noqa: E402
from twin.replay import build_replay_cell, replay  # noqa: E402
from twin.scan import run_scan, simulate  # noqa: E402
from twin.trajectory import plan_joint_trajectory, solve_path, time_law  # noqa: E402
from twin.parts import s_surface_normal  # noqa: E402


def cad_path_on_true_part(sc, mesh, index, point_spacing):
    lines, normals = cad_raster(mesh, sc.path.line_spacing_m, point_spacing, sc.path.margin_m,
                                normals=index.smooth_normals)
    # the part where it really is (as after a perfect localization): deviations are the servo's
    T_base_wp = inv_pose(sc.T_world_base) @ sc.workpiece.T_world_workpiece_true
    return transform_path(T_base_wp, build_path(lines, normals, tool_settings(sc)))


def bench_ik(sc, mesh, index):
    path = cad_path_on_true_part(sc, mesh, index, 0.0002)
    T = flange_poses(path.T_tool, sc.path.T_flange_tool)
    nominal = build_cell(sc, "nominal", mesh)
    runs = [solve_path(nominal, T) for _ in range(3)]
    best = min(runs, key=lambda r: r.time_s)
    print(f"\n## IK along a {len(T)}-pose path (mink, daqp)\n")
    print("| poses | total [s] | per pose [ms] | per pose after the first [ms] | first pose [ms] | mean QP steps | max position error [um] |")
    print("|---|---|---|---|---|---|---|")
    print(f"| {len(T)} | {best.time_s:.3f} | {best.time_per_pose_ms:.4f} | {best.tracking_time_per_pose_ms:.4f} | "
          f"{best.first_pose_time_s * 1e3:.1f} | {best.iterations[1:].mean():.2f} | {best.position_error_m.max() * 1e6:.3f} |")
    print(f"\n(best of 3; all runs per pose: {', '.join(f'{r.time_per_pose_ms:.4f}' for r in runs)} ms)")
    t0 = time.perf_counter()
    traj = time_law(path, best.q, sc.path.feed_m_s, sc.path.transit_speed_m_s, sc.path.acceleration_m_s2,
                    touchdown_acceleration_m_s2=sc.path.touchdown_acceleration_m_s2)
    print(f"\nTime law for the same path: {time.perf_counter() - t0:.3f} s wall for {traj.duration_s:.1f} s of motion "
          f"({len(traj.t)} samples).")


def bench_replay(sc, mesh, index, feeds):
    path = cad_path_on_true_part(sc, mesh, index, sc.path.point_spacing_m)
    nominal = build_cell(sc, "nominal", mesh)
    cell = build_replay_cell(sc, mesh)
    rows = []
    for feed in feeds:
        ik, traj = plan_joint_trajectory(nominal, path, sc.path.T_flange_tool, feed, sc.path.transit_speed_m_s,
                                         sc.path.acceleration_m_s2,
                                         touchdown_acceleration_m_s2=sc.path.touchdown_acceleration_m_s2)
        sim_s = len(traj.t) * traj.dt
        t_roll = min(_time(lambda: simulate(cell, traj.q, traj.qd, lambda *a: None)) for _ in range(3 if feed == sc.path.feed_m_s else 1))
        t0 = time.perf_counter()
        log = replay(cell, traj, path, index)
        t_all = time.perf_counter() - t0
        s = log.summary()
        rows.append((feed, sim_s, t_roll, t_all, s))
    print(f"\n## Replay at 1 ms in the true cell (tool, height-field part, contact sensors), CAD path of {len(path.T_tool)} poses\n")
    print("| feed [mm/s] | simulated [s] | rollout [s] | x real time | whole verification [s] | x real time | "
          "max deviation [mm] | RMS deviation [mm] | max tip surface error [mm] | max tracking error [mm] | unintended contacts |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for feed, sim_s, t_roll, t_all, s in rows:
        print(f"| {feed * 1e3:.0f} | {sim_s:.1f} | {t_roll:.2f} | {sim_s / t_roll:.0f} | {t_all:.2f} | {sim_s / t_all:.0f} | "
              f"{s['max_deviation_mm']:.3f} | {s['rms_deviation_mm']:.3f} | {s['tip_surface_error_max_mm']:.3f} | "
              f"{s['max_tracking_error_mm']:.3f} | {s['unintended_contacts']} |")


def _time(fn):
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def normals_table(mesh) -> str:
    out = ["| noise | cloud | points | method | RMS [deg] | 95 % [deg] | max [deg] | > 5 deg | time [s] |",
           "|---|---|---|---|---|---|---|---|---|"]
    for noise in ("off", "on"):
        sc = scenario("s_surface")
        if noise == "off":
            sc = dataclasses.replace(sc, noise=sc.noise.all_off())
        scan = run_scan(sc, mesh=mesh)
        T = scan.T_base_workpiece_true
        orient = T[:3, 2]
        raw = remove_outliers(organize_scan_lines(scan.points_base, scan.line))
        simp = prepare_scan_lines(scan.points_base, scan.line)
        fits = fit_lines(simp.lines, 0.001)
        clouds = [("raw scan lines", raw.lines), ("simplified 0.2 mm", simp.lines),
                  ("B-spline, resampled 1 mm", fits.lines)]
        for cname, lines in clouds:
            pts = np.concatenate(lines)
            p_wp = transform_points(inv_pose(T), pts)
            n_true = s_surface_normal(p_wp[:, 0], p_wp[:, 1]) @ T[:3, :3].T
            methods = [("triangulation (doc. 004)", lambda: np.concatenate(triangulation_normals(lines, orient)), False)]
            for k in (8, 16, 32, 64, 128):
                methods.append((f"PCA k = {k}", lambda k=k: pca_normals(pts, k, orient), True))
            for mname, fn, unsigned in methods:
                t0 = time.perf_counter()
                n = fn()
                dt = time.perf_counter() - t0
                a = angle_deg(n, n_true, unsigned=unsigned)
                out.append(f"| {noise} | {cname} | {len(pts)} | {mname} | {np.sqrt(np.mean(a**2)):.3f} | "
                           f"{np.percentile(a, 95):.3f} | {a.max():.2f} | {100 * np.mean(a > 5):.1f} % | {dt:.3f} |")
    return "\n".join(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("parts", nargs="*", default=["ik", "replay", "normals"])
    ap.add_argument("--feeds", default="10,30,50,100", help="feeds [mm/s] of the replay table")
    ap.add_argument("--normals-out", help="write the normals table (markdown) to this file")
    args = ap.parse_args()
    sc = scenario("s_surface")
    mesh = load_workpiece_mesh(sc)
    index = MeshIndex(mesh)
    print(f"# bench_path on {platform.processor() or platform.machine()}, {platform.python_version()}")
    if "ik" in args.parts:
        bench_ik(sc, mesh, index)
    if "replay" in args.parts:
        bench_replay(sc, mesh, index, [float(f) * 1e-3 for f in args.feeds.split(",")])
    if "normals" in args.parts:
        table = normals_table(mesh)
        print("\n## Normals against the analytic S-surface normals (full scan, 19 lines 4 mm apart)\n")
        print(table)
        if args.normals_out:
            Path(args.normals_out).write_text(table + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

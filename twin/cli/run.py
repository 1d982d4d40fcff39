"""``twin run SCENARIO --out DIR [--rrd FILE]``: scan -> localize -> path -> IK -> replay.

The loop of the twin (DESIGN.md), closed:

1. scan the part (1 ms, true cell) and rebuild the points (document 004, eq. 2);
2. localize the part against its CAD mesh (documents 000/001) from the nominal pose;
3. scan path (document 004): scan-line cloud, filters, per-line B-spline fits resampled at
   ``path.point_spacing_m``, cross-line triangulation normals, tool frames (eq. 11) and
   flange poses (eq. 13);
4. CAD path (document 003, step 5): a raster of contact points on the CAD mesh moved by the
   localization estimate;
5. each path: mink IK on the nominal cell, time law at the feed, replay in the true cell
   with the tool at 1 ms, deviation, contacts and joint limits;
6. ``DIR/report.json`` (written last and atomically; an error leaves none) and, with
   ``--rrd``, a rerun recording of the scan, the planned and replayed paths, the tool frames
   and the normals.

Units in the report are named in the keys (``_mm``, ``_um``, ``_deg``, ``_s``).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from algorithms.geometry.mesh_index import MeshIndex
from algorithms.errors import AlgorithmError
from algorithms.paths.normals import angle_deg, pca_normals, smooth_line_normals, triangulation_normals
from algorithms.paths.pointcloud import CloudParams, prepare_scan_lines
from algorithms.geometry.se3 import inv_pose, rotation_error_rad, transform_points, translation_error_m
from algorithms.paths.spline import fit_lines
from algorithms.paths.toolpath import ProcessPath, ToolSettings, build_path, cad_raster, transform_path
from twin.cell import build_cell, load_workpiece_mesh
from twin.errors import TwinError
from twin.replay import build_replay_cell, replay
from twin.report import scan_report
from twin.scan import Scan, run_scan
from twin.scenario import Scenario, load_scenario
from twin.trajectory import plan_joint_trajectory

RECORDING_GAP_S = 1.0  # sim_time between the scan and each replay in the recording


def add_parser(sub) -> None:
    p = sub.add_parser(
        "run", help="scan, localize, plan the process paths, solve IK, replay and verify",
        description="Scan the part, localize it, make a process path from the scan (document 004) "
                    "and one from the CAD model moved by the estimate (document 003), solve the joints "
                    "with mink, replay both in the true cell at 1 ms and write DIR/report.json.",
    )
    p.add_argument("scenario", help="scenario TOML file")
    p.add_argument("--out", required=True, help="output folder for report.json")
    p.add_argument("--rrd", help="also write a rerun recording to this file")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    scenario = load_scenario(args.scenario)
    report = run_loop(scenario, Path(args.out), Path(args.rrd) if args.rrd else None)
    print(json.dumps(_headline(report), indent=2))
    return 0


def _headline(report: dict) -> dict:
    keys = ("localization", "path_verification", "max_surface_error_mm", "report", "recording", "wall_s")
    out = {k: report[k] for k in keys if k in report}
    if "localization" in out:
        out["localization"] = {k: out["localization"][k] for k in ("rotation_error_deg", "translation_error_mm")}
    return out


def _say(msg: str, quiet: bool) -> None:
    if not quiet:
        print(f"[run] {msg}", flush=True)


def cloud_params(scenario: Scenario) -> CloudParams:
    p = scenario.path
    return CloudParams(outlier_window_m=p.outlier_window_m, outlier_k=p.outlier_k, max_gap_m=p.max_gap_m,
                       simplify_spacing_m=p.simplify_spacing_m, empty=p.empty_lines)


def tool_settings(scenario: Scenario) -> ToolSettings:
    p = scenario.path
    return ToolSettings(p.heading, tuple(p.heading_direction), p.axis, tuple(p.axis_direction),
                        float(np.radians(p.lead_deg)), float(np.radians(p.tilt_deg)), p.tip_radius_m,
                        p.retract_m)


def _beam_toward_sensor(scan: Scan) -> np.ndarray:
    """Mean direction from the scanned points back to the sensor, robot base frame."""
    on = scan.plan.line >= 0
    z = scan.plan.T_world_sensor[on, :3, 2].mean(axis=0)
    return -(inv_pose(scan.scenario.T_world_base)[:3, :3] @ z)


def scan_path(scan: Scan, T_base_workpiece_est: np.ndarray) -> dict:
    """Document 004's pipeline from the scan points to a process path (robot base frame).

    Returns a dict with the cloud, the fits, the normals per line, the path and diagnostics.
    """
    sc = scan.scenario
    if scan.points_base.ndim != 2:
        raise TwinError("the scan-derived path needs a point sensor (sensor.kind = 'point')")
    t0 = time.perf_counter()
    cloud = prepare_scan_lines(scan.points_base, scan.line, cloud_params(sc))
    fits = fit_lines(cloud.lines, sc.path.point_spacing_m, sc.path.knot_spacing_m)
    normals = triangulation_normals(fits.lines, orient=_beam_toward_sensor(scan))
    # The tool follows the normals smoothed along each line (see smooth_line_normals).
    tool_normals = smooth_line_normals(fits.lines, normals, 2 * sc.path.knot_spacing_m)
    path = build_path(fits.lines, tool_normals, tool_settings(sc), T_frame_ref=T_base_workpiece_est)
    return {"cloud": cloud, "fits": fits, "normals": normals, "tool_normals": tool_normals, "path": path,
            "time_s": time.perf_counter() - t0}


def cad_path(mesh, index: MeshIndex, scenario: Scenario) -> ProcessPath:
    """A raster of contact points on the CAD model, as a process path in the WORKPIECE frame."""
    p = scenario.path
    lines, normals = cad_raster(mesh, p.line_spacing_m, p.point_spacing_m, p.margin_m, p.line_axis,
                                normals=index.smooth_normals)
    return build_path(lines, normals, tool_settings(scenario))


def surface_error_m(points_base: np.ndarray, T_base_workpiece_true: np.ndarray, index: MeshIndex) -> np.ndarray:
    """Signed distance [m] of base-frame points to the TRUE part surface (positive outside)."""
    p = transform_points(inv_pose(T_base_workpiece_true), points_base)
    cp = index.query(p)
    s = np.sign(np.einsum("ij,ij->i", p - cp.foot, cp.normal))
    s[s == 0] = 1.0
    return s * cp.distance


def true_normals_base(points_base: np.ndarray, T_base_workpiece_true: np.ndarray, index: MeshIndex) -> np.ndarray:
    """Smooth normals of the TRUE surface at the feet of base-frame points, base frame."""
    p = transform_points(inv_pose(T_base_workpiece_true), points_base)
    cp = index.query(p)
    return index.smooth_normals(cp.face, cp.foot) @ T_base_workpiece_true[:3, :3].T


def sensor_sigma_m(scenario: Scenario) -> float:
    """Combined standard uncertainty of one distance (GUM): repeatability, linearity band
    (uniform, amplitude / sqrt 3) and quantisation (step / sqrt 12), for the switched-on sources."""
    s, n = scenario.sensor, scenario.noise
    var = (s.sigma_m**2 if n.gaussian else 0.0) + ((s.linearity_m / np.sqrt(3)) ** 2 if n.linearity else 0.0) \
        + ((s.resolution_m / np.sqrt(12)) ** 2 if n.quantization else 0.0)
    return float(np.sqrt(var))


def _process_and_replay(name, path, nominal, replay_cell, index, scenario, quiet) -> dict:
    p = scenario.path
    ik, traj = plan_joint_trajectory(nominal, path, p.T_flange_tool, p.feed_m_s, p.transit_speed_m_s,
                                     p.acceleration_m_s2, touchdown_acceleration_m_s2=p.touchdown_acceleration_m_s2)
    _say(f"{name}: {len(path.T_tool)} poses, IK {ik.time_per_pose_ms:.3f} ms/pose, "
         f"{traj.duration_s:.1f} s of motion", quiet)
    log = replay(replay_cell, traj, path, index)
    s = log.summary()
    _say(f"{name}: replayed, max deviation {s['max_deviation_mm']:.3f} mm, "
         f"{s['unintended_contacts']} unintended contact(s)", quiet)
    return {"ik": ik, "trajectory": traj, "log": log, "summary": s}


def _ik_dict(ik, traj) -> dict:
    return {
        "poses": int(len(ik.q)),
        "time_s": round(ik.time_s, 4),
        "time_per_pose_ms": round(ik.time_per_pose_ms, 4),
        "tracking_time_per_pose_ms": round(ik.tracking_time_per_pose_ms, 4),
        "mean_iterations": round(float(ik.iterations[1:].mean()) if len(ik.q) > 1 else 0.0, 3),
        "max_position_error_um": float(ik.position_error_m.max() * 1e6),
        "max_orientation_error_urad": float(ik.orientation_error_rad.max() * 1e6),
        "min_jacobian_sigma_mm_per_rad": float(ik.sigma_min.min() * 1e3),
        "problems": [pr.describe() for pr in ik.problems],
        "trajectory_duration_s": round(traj.duration_s, 3),
        "max_joint_velocity_ratio": round(traj.velocity_ratio, 4),
        "max_joint_acceleration_ratio": round(traj.acceleration_ratio, 4),
    }


def run_loop(scenario: Scenario, out: Path, rrd: Path | None = None, mesh=None, quiet: bool = False,
             artifacts: dict | None = None) -> dict:
    """The whole loop (module docstring); writes ``out/report.json`` and returns the report.

    ``artifacts``, when given, receives the intermediate objects (``scan``, ``replay_cell``,
    ``runs``: paths and replay logs) for callers that write more files.
    """
    t_all = time.perf_counter()
    out = Path(out)
    report_file = out / "report.json"
    if report_file.exists():
        report_file.unlink()  # a failed run must not leave an older report looking current
    timings = {}
    try:
        t0 = time.perf_counter()
        if mesh is None:
            mesh = load_workpiece_mesh(scenario)
        index = MeshIndex(mesh)
        scan = run_scan(scenario, mesh=mesh)
        timings["scan_s"] = time.perf_counter() - t0
        _say(f"scanned {len(scan.t)} samples ({scan.t[-1]:.1f} s simulated)", quiet)

        t0 = time.perf_counter()
        loc = _localize(scan, index)
        timings["localize_s"] = time.perf_counter() - t0
        T_est = loc.pop("_T")
        _say(f"localized: {loc['rotation_error_deg']:.4f} deg, {loc['translation_error_mm']:.4f} mm from the truth", quiet)

        t0 = time.perf_counter()
        nominal = build_cell(scenario, "nominal", mesh)
        replay_cell = build_replay_cell(scenario, mesh)
        timings["build_cells_s"] = time.perf_counter() - t0

        report = {"scenario": scenario.source or scenario.name, "seed": scenario.seed,
                  "scan": scan_report(scan, mesh, index), "localization": loc}
        runs = []
        t_offset = float(scan.t[-1]) + RECORDING_GAP_S

        # Scan-derived path (document 004).
        if scan.points_base.ndim == 2:
            t0 = time.perf_counter()
            sp = scan_path(scan, T_est)
            timings["scan_path_s"] = time.perf_counter() - t0
            report["scan_path"], run = _scan_path_report(sp, scan, index, scenario)
            t0 = time.perf_counter()
            res = _process_and_replay("scan path", sp["path"], nominal, replay_cell, index, scenario, quiet)
            timings["scan_path_ik_s"] = res["ik"].time_s
            timings["scan_path_replay_s"] = time.perf_counter() - t0 - res["ik"].time_s
            report["scan_path"]["ik"] = _ik_dict(res["ik"], res["trajectory"])
            report["scan_path"]["verification"] = res["summary"]
            runs.append(dict(run, log=res["log"], t_offset=t_offset))
            t_offset += res["trajectory"].duration_s + RECORDING_GAP_S
        else:
            report["scan_path"] = {"skipped": "the scan-derived path needs a point sensor (sensor.kind = 'point')"}

        # CAD path moved by the estimate (document 003, step 5).
        t0 = time.perf_counter()
        cp_wp = cad_path(mesh, index, scenario)
        cp = transform_path(T_est, cp_wp)
        cp_nominal = transform_path(scan.T_base_workpiece_nominal, cp_wp)
        timings["cad_path_s"] = time.perf_counter() - t0
        contact = cp.contact[cp.process_mask()]
        err = surface_error_m(contact, scan.T_base_workpiece_true, index)
        err_nom = surface_error_m(cp_nominal.contact[cp_nominal.process_mask()], scan.T_base_workpiece_true, index)
        t0 = time.perf_counter()
        res = _process_and_replay("CAD path", cp, nominal, replay_cell, index, scenario, quiet)
        timings["cad_path_ik_s"] = res["ik"].time_s
        timings["cad_path_replay_s"] = time.perf_counter() - t0 - res["ik"].time_s
        report["cad_path"] = {
            "lines": cp.n_lines,
            "contact_points": int(len(contact)),
            "max_surface_error_mm": float(np.max(np.abs(err)) * 1e3),
            "rms_surface_error_mm": float(np.sqrt(np.mean(err**2)) * 1e3),
            "uncompensated_max_surface_error_mm": float(np.max(np.abs(err_nom)) * 1e3),
            "uncompensated_rms_surface_error_mm": float(np.sqrt(np.mean(err_nom**2)) * 1e3),
            "note": "surface errors: signed distance of the planned contact points to the TRUE surface; "
                    "verification.tip_surface_error_*: of the replayed ball end (adds servo lag)",
            "ik": _ik_dict(res["ik"], res["trajectory"]),
            "verification": res["summary"],
        }
        runs.append(dict(name="cad_path", path=cp, log=res["log"], t_offset=t_offset,
                         normals_points=contact, normals=cp.normal[cp.process_mask()]))

        main = report["scan_path"].get("verification") or report["cad_path"]["verification"]
        report["path_verification"] = {
            "path": "scan_path" if "verification" in report["scan_path"] else "cad_path",
            "max_deviation_mm": main["max_deviation_mm"],
            "rms_deviation_mm": main["rms_deviation_mm"],
            "contacts": main["contacts"],
            "unintended_contacts": main["unintended_contacts"],
            "joint_limit_hits": main["joint_limit_hits"],
        }
        report["max_surface_error_mm"] = report["cad_path"]["max_surface_error_mm"]
        if rrd is not None:
            from twin.viz import save_run_recording
            t0 = time.perf_counter()
            save_run_recording(rrd, replay_cell, scan, runs)
            timings["recording_s"] = time.perf_counter() - t0
            report["recording"] = str(rrd)
        report["timings_s"] = {k: round(v, 3) for k, v in timings.items()}
        report["wall_s"] = round(time.perf_counter() - t_all, 2)
        report["report"] = str(report_file)
    except AlgorithmError as exc:
        raise TwinError(str(exc)) from None
    if artifacts is not None:
        artifacts.update(scan=scan, replay_cell=replay_cell, runs=runs, T_base_workpiece_est=T_est)
    out.mkdir(parents=True, exist_ok=True)
    tmp = report_file.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(report, indent=2))
    os.replace(tmp, report_file)
    return report


def _localize(scan: Scan, index: MeshIndex) -> dict:
    from algorithms.registration.local import localize

    pts = scan.valid_points_base.reshape(-1, 3)
    rows = np.nonzero(scan.valid)[0]
    on_lines = scan.line[rows] >= 0 if scan.valid.ndim == 1 else np.ones(len(pts), dtype=bool)
    res = localize(pts[on_lines], index=index, init=scan.T_base_workpiece_nominal,
                   rng=np.random.default_rng(scan.scenario.seed))
    T_true, T_nom = scan.T_base_workpiece_true, scan.T_base_workpiece_nominal
    return {
        "_T": res.T_world_workpiece,
        "method": res.method,
        "converged": bool(res.converged),
        "iterations": int(res.iterations),
        "rmse_um": float(res.rmse_m * 1e6),
        "points": int(on_lines.sum()),
        "time_s": round(float(res.time_s), 4),
        "rotation_error_deg": float(np.degrees(rotation_error_rad(res.T_world_workpiece, T_true))),
        "translation_error_mm": float(translation_error_m(res.T_world_workpiece, T_true) * 1e3),
        "nominal_rotation_error_deg": float(np.degrees(rotation_error_rad(T_nom, T_true))),
        "nominal_translation_error_mm": float(translation_error_m(T_nom, T_true) * 1e3),
    }


def _scan_path_report(sp: dict, scan: Scan, index: MeshIndex, scenario: Scenario) -> tuple[dict, dict]:
    cloud, fits, normals, path = sp["cloud"], sp["fits"], sp["normals"], sp["path"]
    pts = np.concatenate(fits.lines)
    nrm = np.concatenate(normals)
    err = surface_error_m(pts, scan.T_base_workpiece_true, index)
    n_true = true_normals_base(pts, scan.T_base_workpiece_true, index)
    a_tri = angle_deg(nrm, n_true)
    a_pca = angle_deg(pca_normals(pts, 16), n_true, unsigned=True)
    a_tool = angle_deg(np.concatenate(sp["tool_normals"]), n_true)
    sigma = sensor_sigma_m(scenario)
    bound = 3 * sigma + fits.max_error_m
    rep = {
        "lines": len(cloud.lines),
        "cloud_points": cloud.n_points,
        "removed": dict(cloud.removed),
        "fit_rms_error_um": fits.rms_error_m * 1e6,
        "fit_max_error_um": fits.max_error_m * 1e6,
        "contact_points": int(len(pts)),
        "contact_surface_error_max_um": float(np.max(np.abs(err)) * 1e6),
        "contact_surface_error_rms_um": float(np.sqrt(np.mean(err**2)) * 1e6),
        "contact_surface_bound_um": bound * 1e6,
        "sensor_sigma_um": sigma * 1e6,
        "normals_triangulation_rms_deg": float(np.sqrt(np.mean(a_tri**2))),
        "normals_triangulation_max_deg": float(a_tri.max()),
        "normals_pca_k16_rms_deg": float(np.sqrt(np.mean(a_pca**2))),
        "tool_normals_smoothed_rms_deg": float(np.sqrt(np.mean(a_tool**2))),
        "time_s": round(sp["time_s"], 4),
    }
    run = dict(name="scan_path", path=path, normals_points=pts, normals=nrm)
    return rep, run

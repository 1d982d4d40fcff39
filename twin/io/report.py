"""The report of a run (``report.json``) and of a scan: the one place SI values become the
report's unit-named fields (``_mm``, ``_um``, ``_deg``, ``_s``).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from algorithms.paths.toolpath import transform_path
from twin import evaluate
from twin.sensors.base import STATUS_NAMES

MM, UM = 1e3, 1e6
# Added to the CAD path's 3-sigma surface bound: round-off of the ray casts and of the
# tessellation (the truth and the CAD model are the same mesh in the twin).
SURFACE_BOUND_FLOOR_M = 1e-6


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2)))


def scan_report(scan, realized) -> dict:
    """Counts, point-to-true-surface residuals and servo tracking of a scan."""
    e = evaluate.scan_errors(scan, realized)
    r = e.residual_m
    counts = np.bincount(scan.status.ravel(), minlength=len(STATUS_NAMES))
    sim_s = float(len(scan.t) * (scan.t[1] - scan.t[0])) if len(scan.t) > 1 else 0.0
    return {
        "samples": int(len(scan.t)),
        "duration_s": float(scan.t[-1]),
        "sample_period_s": float(scan.t[1] - scan.t[0]) if len(scan.t) > 1 else None,
        "status_counts": {STATUS_NAMES[k]: int(v) for k, v in enumerate(counts)},
        "points_on_part": e.points_on_part,
        "points_on_table": e.points_on_table,
        "residual_rms_um": float(np.sqrt(np.mean(r**2)) * UM) if len(r) else None,
        "residual_max_um": float(r.max() * UM) if len(r) else None,
        "servo_tracking_max_mm": float(e.tracking_m.max() * MM),
        "servo_tracking_rms_mm": float(np.sqrt(np.mean(e.tracking_m**2)) * MM),
        "sim_speed_x_realtime": float(sim_s / scan.timings_s["simulate_s"]),
        "timings_s": {k: round(v, 4) for k, v in scan.timings_s.items()},
    }


def localization_report(result) -> dict:
    """The estimate, its verdict, determined and free directions, the Cramer-Rao standard
    deviations and the errors against the truth in the determined directions only."""
    loc = result.localization
    realized = result.realized
    e = evaluate.pose_errors(loc.T_world_workpiece, realized)
    d = evaluate.determined_errors(loc, realized, result.pose_covariance)
    return {
        "method": loc.method,
        "converged": bool(loc.converged),
        "status": loc.status.value,
        "trusted": evaluate.localization_trusted(loc),
        "message": loc.message,
        "observable": len(loc.free_directions) == 0,
        "free_directions": [[round(float(v), 6) for v in w] for w in loc.free_directions],
        "free_directions_part_symmetry": evaluate.free_directions_part_symmetry(loc, realized.workpiece.index),
        "determined_directions": [[round(float(v), 6) for v in w] for w in loc.determined_directions],
        "solutions": len(loc.solutions),
        "poor_fit": loc.poor_fit_reason,
        "iterations": int(loc.iterations),
        "rmse_um": float(loc.rmse_m * UM),
        "sigma_um": float(loc.sigma_m * UM),
        "points": int(len(result.scan.line_points_base)),
        "time_s": round(float(loc.time_s), 4),
        "T_base_workpiece_estimate": np.round(loc.T_world_workpiece, 12).tolist(),
        "determined_std": d["std"],
        "determined_error": d["error"],
        "determined_error_sigmas": d["sigmas"],
        "max_error_sigmas": d["max_sigmas"],
        "rotation_error_deg": float(np.degrees(e.rotation_rad)) if not len(loc.free_directions) else "free",
        "translation_error_mm": float(e.translation_m * MM) if not len(loc.free_directions) else "free",
        "nominal_rotation_error_deg": float(np.degrees(e.nominal_rotation_rad)),
        "nominal_translation_error_mm": float(e.nominal_translation_m * MM),
        "note": "determined_*: along determined_directions (unit twists [omega, v], workpiece frame), "
                "in rad for rotations and m for translations; free directions are not errors",
    }


def ik_report(ik, traj) -> dict:
    return {
        "poses": int(len(ik.q)),
        "time_s": round(ik.time_s, 4),
        "time_per_pose_ms": round(ik.time_per_pose_ms, 4),
        "tracking_time_per_pose_ms": round(ik.tracking_time_per_pose_ms, 4),
        "mean_iterations": round(float(ik.iterations[1:].mean()) if len(ik.q) > 1 else 0.0, 3),
        "max_position_error_um": float(ik.position_error_m.max() * UM),
        "max_orientation_error_urad": float(ik.orientation_error_rad.max() * UM),
        "min_jacobian_sigma_mm_per_rad": float(ik.sigma_min.min() * MM),
        "problems": [pr.describe() for pr in ik.problems],
        "trajectory_duration_s": round(traj.duration_s, 3),
        "max_joint_velocity_ratio": round(traj.velocity_ratio, 4),
        "max_joint_acceleration_ratio": round(traj.acceleration_ratio, 4),
    }


def _run_blocks(run) -> dict:
    if run is None:
        return {}
    return {"dropped": [d.to_dict() for d in run.dropped], "ik": ik_report(run.ik, run.trajectory),
            "verification": run.log.summary()}


def scan_path_report(result, sensor_sigma_m: float) -> dict:
    sp = result.scan_path
    pts = np.concatenate(sp.lines)
    e = evaluate.scan_path_errors(pts, np.concatenate(sp.normals), np.concatenate(sp.tool_normals), result.realized)
    bound = 3 * sensor_sigma_m + sp.fit_max_error_m
    return {
        "scan_lines": sp.cloud_lines,
        "lines": len(sp.lines),
        "patches": sp.patches,
        "left_out": list(sp.left_out),
        "cloud_points": sp.cloud_points,
        "removed": dict(sp.removed),
        "fit_rms_error_um": sp.fit_rms_error_m * UM,
        "fit_max_error_um": sp.fit_max_error_m * UM,
        "contact_points": int(len(pts)),
        "contact_surface_error_max_um": float(np.max(np.abs(e.surface_m)) * UM),
        "contact_surface_error_rms_um": float(np.sqrt(np.mean(e.surface_m**2)) * UM),
        "contact_surface_bound_um": bound * UM,
        "sensor_sigma_um": sensor_sigma_m * UM,
        "normals_triangulation_rms_deg": _rms(e.normals_triangulation_deg),
        "normals_triangulation_max_deg": float(e.normals_triangulation_deg.max()),
        "normals_pca_k16_rms_deg": _rms(e.normals_pca_deg),
        "tool_normals_smoothed_rms_deg": _rms(e.tool_normals_deg),
        "time_s": round(sp.time_s, 4),
        **_run_blocks(result.run("scan_path")),
    }


def cad_path_report(result) -> dict:
    realized = result.realized
    T_true, index = realized.T_base_workpiece_true, realized.workpiece.index
    run = result.run("cad_path")
    cp = transform_path(result.T_base_workpiece_estimate, result.cad_path_workpiece)
    contact = cp.contact[cp.process_mask()]
    err = evaluate.surface_error_m(contact, T_true, index)
    nominal = transform_path(realized.T_base_workpiece_nominal, result.cad_path_workpiece)
    err_nom = evaluate.surface_error_m(nominal.contact[nominal.process_mask()], T_true, index)
    bound = 3.0 * evaluate.contact_std_m(result.cad_path_workpiece, result.localization, result.pose_covariance) \
        + SURFACE_BOUND_FLOOR_M
    return {
        "lines": cp.n_lines,
        "contact_points": int(len(contact)),
        "max_surface_error_mm": float(np.max(np.abs(err)) * MM),
        "surface_error_bound_mm": float(bound * MM),
        "rms_surface_error_mm": float(np.sqrt(np.mean(err**2)) * MM),
        "uncompensated_max_surface_error_mm": float(np.max(np.abs(err_nom)) * MM),
        "uncompensated_rms_surface_error_mm": float(np.sqrt(np.mean(err_nom**2)) * MM),
        "note": "surface errors: signed distance of the planned contact points to the TRUE surface; "
                "surface_error_bound_mm: 3 x the largest standard deviation of a contact point along its "
                "normal that the pose covariance gives, plus 1 nm; "
                "verification.tip_surface_error_*: of the replayed ball end (adds servo lag)",
        **_run_blocks(run),
    }


def run_report(result, sensor_sigma_m: float) -> dict:
    """The ``report.json`` of a run (see ``twin run --help``); a run that stopped at a stage
    gets what the finished stages made, ``complete: false`` and the failing stage."""
    sc = result.realized.scenario
    report = {"scenario": sc.source or sc.name, "seed": sc.seed, "complete": result.complete}
    if result.failure is not None:
        report["failed_stage"], report["failure"] = result.failure
    if result.scan is not None:
        report["scan"] = scan_report(result.scan, result.realized)
        plan = result.scan.plan
        report["scan"]["passes"] = [p.to_dict() for p in plan.passes]
        report["scan"]["plan_notes"] = list(plan.notes)
    if result.localization is not None:
        report["localization"] = localization_report(result)
    if result.scan_path is not None:
        report["scan_path"] = scan_path_report(result, sensor_sigma_m)
    elif result.scan_path_skipped is not None:
        report["scan_path"] = {"skipped": result.scan_path_skipped}
    if result.run("cad_path") is not None:
        report["cad_path"] = cad_path_report(result)
    verified = [name for name in ("scan_path", "cad_path") if "verification" in report.get(name, {})]
    if verified:
        main = report[verified[0]]["verification"]
        report["path_verification"] = {
            "path": verified[0],
            "max_deviation_mm": main["max_deviation_mm"],
            "rms_deviation_mm": main["rms_deviation_mm"],
            "contacts": main["contacts"],
            "unintended_contacts": sum(report[n]["verification"]["unintended_contacts"] for n in verified),
            "joint_limit_hits": main["joint_limit_hits"],
        }
    if "cad_path" in report:
        report["max_surface_error_mm"] = report["cad_path"]["max_surface_error_mm"]
    report["trusted"] = bool(result.complete and report.get("localization", {}).get("trusted", False))
    report["timings_s"] = {k: round(v, 3) for k, v in result.timings_s.items()}
    return report


def headline(report: dict) -> dict:
    """The short JSON a command prints."""
    keys = ("complete", "failed_stage", "failure", "trusted", "localization", "path_verification",
            "max_surface_error_mm", "report", "recording", "wall_s")
    out = {k: report[k] for k in keys if k in report}
    if "localization" in out:
        out["localization"] = {k: out["localization"][k]
                               for k in ("status", "observable", "max_error_sigmas", "rotation_error_deg",
                                         "translation_error_mm")}
    return out


def write_json(path: Path, data: dict) -> None:
    """Write JSON atomically (a temporary file moved into place)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(data, indent=2))
    os.replace(tmp, path)

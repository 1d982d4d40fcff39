"""The report of a run (``report.json``) and of a scan: the one place SI values become the
report's unit-named fields (``_mm``, ``_um``, ``_deg``, ``_s``).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from algorithms.paths.toolpath import transform_path
from twin import evaluate
from twin.deviation import cad_deviation_m, deviation_scale, deviation_summary
from twin.pose_table import pose_table
from twin.sensors.base import STATUS_NAMES
from twin.verdicts import add_verdict, locate_checks, run_checks

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
        "rejection_review": loc.rejection_review,
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
        "pose_table": pose_table(realized.T_base_workpiece_nominal, loc.T_world_workpiece,
                                 evaluate.Evaluation(realized).T_base_workpiece, loc.determined_directions,
                                 loc.free_directions, result.pose_covariance),
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
    on = run.path.process_mask()
    tilt = np.degrees(np.arccos(np.clip(np.sum(run.path.T_tool[on, :3, 2] * run.path.normal[on], axis=1), -1.0, 1.0)))
    kept, planned = int(np.count_nonzero(on)), int(run.planned_points)
    return {"dropped": [d.to_dict() for d in run.dropped],
            # the planned contact points (before any stretch was dropped) and the share kept
            "planned_points": planned, "kept_points": kept,
            "coverage": round(kept / planned, 4) if planned else 0.0,
            "ik": ik_report(run.ik, run.trajectory),
            # the tool axis against the surface normal at the processed points (lead, tilt, max_tilt_deg)
            "max_tool_tilt_deg": round(float(tilt.max()) if len(tilt) else 0.0, 3),
            "tilted_points": int(np.count_nonzero(tilt > 0.01)),
            "verification": run.log.summary(),
            # the replay's own times (contacts, limits) start at 0: add this for the recording's sim_time
            "recording_t_offset_s": round(float(run.t_offset_s), 6)}


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
    truth = evaluate.Evaluation(realized)
    run = result.run("cad_path")
    cp = transform_path(result.T_base_workpiece_estimate, result.cad_path_workpiece)
    contact = cp.contact[cp.process_mask()]
    err = truth.surface_error_m(contact)
    nominal = transform_path(realized.T_base_workpiece_nominal, result.cad_path_workpiece)
    err_nom = truth.surface_error_m(nominal.contact[nominal.process_mask()])
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


def deviation_vs_cad(result, sensor_sigma_m: float) -> dict:
    """The scan points against the CAD model at the estimated pose (:mod:`twin.deviation`): how
    many lie within the scenario's surface tolerance, their spread and the map's scale."""
    tol = result.realized.scenario.tolerances.max_surface_deviation_m
    scale = deviation_scale(tol, sensor_sigma_m)
    dev = cad_deviation_m(result.scan.valid_points_base, result.localization.T_world_workpiece,
                          result.realized.workpiece.index)
    return deviation_summary(dev, scale)


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
        report["deviation_vs_cad"] = deviation_vs_cad(result, sensor_sigma_m)
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
    add_verdict(report, run_checks(report, sc.tolerances))
    report["timings_s"] = {k: round(v, 3) for k, v in result.timings_s.items()}
    return report


def headline(report: dict) -> dict:
    """The short JSON a command prints."""
    keys = ("complete", "failed_stage", "failure", "trusted", "passed", "localization", "path_verification",
            "max_surface_error_mm", "report", "recording", "wall_s")
    out = {k: report[k] for k in keys if k in report}
    out["failed_checks"] = failed_checks(report)
    if "localization" in out:
        out["localization"] = {k: out["localization"][k]
                               for k in ("status", "observable", "max_error_sigmas", "rotation_error_deg",
                                         "translation_error_mm")}
    return out


def failed_checks(report: dict) -> list[dict]:
    """The deciding checks of a report that failed: name and detail."""
    return [{"name": c["name"], "detail": c["detail"]} for c in report.get("checks", [])
            if c["decides"] and not c["passed"]]


def write_json(path: Path, data: dict) -> None:
    """Write JSON atomically (a temporary file moved into place)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(data, indent=2))
    os.replace(tmp, path)


def _pose_error_block(T_est, T_true, covariance=None) -> dict:
    e = evaluate.full_pose_errors(T_est, T_true, covariance)
    out: dict[str, Any] = {"rotation_error_deg": float(np.degrees(e["rotation_rad"])),
           "translation_error_mm": float(e["translation_m"] * MM)}
    if covariance is not None:
        out["std_rotation_deg"] = [float(np.degrees(v)) for v in e["std"][:3]]
        out["std_translation_um"] = [float(v * UM) for v in e["std"][3:]]
        out["error_sigmas"] = [round(float(v), 3) for v in e["sigmas"]]
        out["max_error_sigmas"] = round(float(np.max(e["sigmas"])), 3)
        out["mahalanobis"] = round(e["mahalanobis"], 3)
    return out


def _hit_row(h) -> dict:
    row = {"label": h.target.label, "hit": bool(h.hit),
           "target_m": np.round(h.target.point, 9).tolist(), "normal": np.round(h.target.normal, 9).tolist()}
    if h.hit:
        row.update({"centre_m": np.round(h.centre, 10).tolist(), "trigger_t_s": round(float(h.trigger_t_s), 6),
                    "overtravel_um": round(float(h.overtravel_m * UM), 3)})
        pretravel_m = evaluate.true_pretravel_m(h)
        if pretravel_m is not None:
            row["true_pretravel_um"] = round(float(pretravel_m * UM), 4)
    else:
        row["miss"] = h.miss
    return row


def locate_report(result) -> dict:
    """The ``report.json`` of ``twin locate`` (document 001's hierarchy): each stage's result,
    its error against the truth, the covariance, the probe hits and misses, the contacts and
    the time of each stage; a run that stopped at a stage gets what the finished stages made."""
    realized = result.realized
    sc = realized.scenario
    p = sc.probe
    T_true = evaluate.Evaluation(realized).T_base_workpiece
    report: dict = {"command": "locate", "scenario": sc.source or sc.name, "seed": sc.seed,
                    "complete": result.complete}
    if result.failure is not None:
        report["failed_stage"], report["failure"] = result.failure
    if result.scan is not None:
        report["coarse_scan"] = {"samples": int(len(result.scan.t)),
                                 "simulated_s": round(float(result.scan.t[-1] - result.scan.t[0]), 3),
                                 "line_spacing_mm": sc.locate.coarse_line_spacing_m * MM,
                                 "points_used": int(len(result.coarse_points)) if result.coarse_points is not None
                                 else 0}
    if result.T_coarse is not None:
        c = _pose_error_block(result.T_coarse, T_true)
        c.update({"method": result.coarse_method, "status": getattr(result.coarse, "status", None)
                  and result.coarse.status.value,
                  "within_1mm_1deg": bool(c["rotation_error_deg"] <= 1.0 and c["translation_error_mm"] <= 1.0),
                  "nominal_rotation_error_deg": float(np.degrees(evaluate.pose_errors(result.T_coarse, realized)
                                                                 .nominal_rotation_rad)),
                  "nominal_translation_error_mm": float(evaluate.pose_errors(result.T_coarse, realized)
                                                        .nominal_translation_m * MM),
                  "T_base_workpiece": np.round(result.T_coarse, 12).tolist()})
        cov = getattr(result.coarse, "covariance", None)
        if result.coarse_method != "ga" and cov is not None and np.shape(cov) == (6, 6):
            # the coarse method's own Cramer-Rao covariance (the laser's random noise only)
            b = _pose_error_block(result.T_coarse, T_true, cov)
            c.update({f"crlb_{k}": b[k] for k in ("std_rotation_deg", "std_translation_um", "max_error_sigmas")})
        report["coarse"] = c
    if result.qualification is not None:
        q = result.qualification
        truth = evaluate.true_effective_radius_m(p)
        report["qualification"] = {
            "points": len(q.hits), "effective_radius_mm": q.effective_radius_m * MM,
            "nominal_radius_mm": p.ball_radius_m * MM, "true_effective_radius_mm": truth * MM,
            "effective_radius_error_um": (q.effective_radius_m - truth) * UM,
            "effective_radius_std_um": q.radius_std_m * UM,
            "ball_centre_offset_um": [float(v * UM) for v in q.offset_probe_m],
            "fit_rms_um": q.rms_m * UM,
            "note": "the effective radius absorbs the mean sideways pre-travel; the axial excess of the pole "
                    "touch and any mount error go into the ball-centre offset (probe frame: z along the stylus)",
        }
    if result.plan is not None:
        pl = result.plan
        report["plan"] = {"planner": pl.planner, "points": len(pl.targets), "candidates": pl.candidates,
                          "feasible": pl.feasible, "rejected": pl.rejected,
                          "predicted_std_rotation_deg": [float(np.degrees(v)) for v in pl.predicted_std[:3]],
                          "predicted_std_translation_um": [float(v * UM) for v in pl.predicted_std[3:]]}
    if result.probing is not None:
        log = result.probing
        hits = [h for h in result.hits if h.hit]
        report["probing"] = {
            "points": len(result.hits), "hits": len(hits), "misses": [_hit_row(h) for h in result.hits if not h.hit],
            "unintended_contacts": len(log.contacts), "contacts": [c.to_dict() for c in log.contacts],
            "min_stylus_body_clearance_mm": log.min_clearance_m * MM,
            "max_overtravel_um": max((h.overtravel_m for h in result.hits if h.hit), default=0.0) * UM,
            "simulated_s": round(log.duration_s, 3), "rollout_wall_s": round(log.wall_s, 3),
            "hits_detail": [_hit_row(h) for h in result.hits],
        }
    if result.fine is not None:
        f, d = result.fine, result.fine_001
        report["fine"] = {
            "fine_001": {"status": d.status.value, "converged": bool(d.converged), "iterations": int(d.iterations),
                         "rmse_um": d.rmse_m * UM, "message": d.message},
            "status": f.status.value, "message": f.message, "rmse_um": f.rmse_m * UM,
            "compensation_rounds": int(result.compensation_rounds), "points": int(f.n_points_used),
            "sigma_point_um": result.sigma_point_m * UM,
            "T_fine": np.round(result.T_fine, 12).tolist(),
            "T_base_workpiece": np.round(result.T_final, 12).tolist(),
            "T_world_workpiece": np.round(sc.T_world_base @ result.T_final, 12).tolist(),
            "covariance_includes": "probe repeatability; pre-travel variation left after qualification (Type B); "
                                   + ("encoder noise; " if sc.noise.encoder_sigma_rad > 0 else "")
                                   + "qualification radius and offset (systematic)",
            "covariance_excludes": "robot kinematic and hand-eye errors"
                                   + (" (switched ON in this scenario: the errors may exceed it)"
                                      if sc.noise.kinematic_sigma_m > 0 or sc.noise.kinematic_sigma_rad > 0 else
                                      " (off in this scenario)"),
        }
        report["fine"].update(_pose_error_block(result.T_final, T_true, result.covariance))
        report["fine"]["pose_table"] = pose_table(realized.T_base_workpiece_nominal, result.T_final, T_true,
                                                  np.eye(6), np.zeros((0, 6)), result.covariance)
        hits = [h for h in result.hits if h.hit]
        if result.qualification is not None:
            r_eff = result.qualification.effective_radius_m
            report["fine"]["max_cosine_error_at_coarse_um"] = float(
                evaluate.cosine_errors_m(hits, result.T_coarse, r_eff, realized).max() * UM)
            report["fine"]["max_cosine_error_at_final_um"] = float(
                evaluate.cosine_errors_m(hits, result.T_final, r_eff, realized).max() * UM)
    fine_ok = result.fine is not None and result.fine.status.value == "ok" and not result.fine.poor_fit_reason
    report["trusted"] = bool(result.complete and fine_ok and report.get("probing", {}).get("unintended_contacts", 1)
                             == 0)
    add_verdict(report, locate_checks(report, sc.tolerances))
    report["timings_s"] = {k: round(v, 3) for k, v in result.timings_s.items()}
    report["simulated_s"] = {k: round(v, 3) for k, v in result.stage_t_s.items()}
    return report


def locate_headline(report: dict) -> dict:
    """The short JSON ``twin locate`` prints."""
    out = {k: report[k] for k in ("complete", "failed_stage", "failure", "trusted", "passed") if k in report}
    out["failed_checks"] = failed_checks(report)
    if "coarse" in report:
        out["coarse"] = {k: report["coarse"][k] for k in ("method", "rotation_error_deg", "translation_error_mm",
                                                          "within_1mm_1deg")}
    if "qualification" in report:
        out["effective_radius_error_um"] = report["qualification"]["effective_radius_error_um"]
    if "probing" in report:
        out["probing"] = {k: report["probing"][k] for k in ("points", "hits", "unintended_contacts")}
    if "fine" in report:
        out["fine"] = {k: report["fine"][k] for k in ("status", "rotation_error_deg", "translation_error_mm",
                                                      "max_error_sigmas")}
    for k in ("report", "recording", "wall_s"):
        if k in report:
            out[k] = report[k]
    return out

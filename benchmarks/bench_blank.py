"""Document 003 from a blank: locate a cast blank, relocate the CAM program, check the finished part.

The patent's steps on `scenarios/cast_blank.toml` (a plate whose top face is finished, two bosses
still under cast domes with stock), scanned in the cell:

1-2. the blank clamped where only the simulator knows, its points measured (the laser scan, in
     the machine frame);
3.   the coarse pre-registration: the nominal pose, moved by a random 0.5 deg / 1 mm per trial;
4.   the registration, two ways:
     * **as printed**: document 003's particle swarm (40 particles, 100 iterations, LDW, TVAC)
       on the measured points (a random 300 of them, finished and rough alike: the patent's
       "points Q_i"), fitness the squared distance to the nearest point of the finished CAD model;
     * **ours**: document 000's hybrid localization: Algorithm 2 on the finished face, Algorithm 3
       keeping every rough point at least the allowance outside the finished part;
5.   the final matrix applied to the CAM program's cutter locations (a ball-end raster finishing
     the bosses, programmed in the CAD frame: :func:`algorithms.nc.drop_cutter_raster`), the NC
     program written as G-code (:func:`algorithms.nc.write_gcode`) and read back
     (:func:`algorithms.nc.read_gcode`).

Then the finished part is checked against the truth: the stock under every cutter location of
the read-back program on the true blank (the true blank's signed distance at the ball's centre,
``stock = r - d``: negative where the finished surface would lie outside the blank, a scrapped
part), the finished datum face's error (the largest deviation of the finished top face at the
found pose from where it really is, along its normal) and the pose's distance from the blank's
nominal frame (informative: any pose that keeps the allowance is a right one).

    python -m benchmarks.bench_blank [--trials 10]     (writes benchmarks/results_blank.md)
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

import numpy as np

from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import exp_se3, inv_pose, transform_points
from algorithms.nc import drop_cutter_raster, read_gcode, relocate_tool_tips, write_gcode
from algorithms.registration.global_search import pso_refine
from algorithms.registration.hybrid import localize_hybrid
from tests.helpers import ROOT, commit_stamp, scenario

ALLOWANCE_M = 0.002
#: The finished datum face's position tolerance [m] a located blank must keep (a typical
#: position tolerance of a machined face; the scenario states none).
DATUM_TOLERANCE_M = 20e-6
TOOL_RADIUS_M = 0.004
SWARM_POINTS = 300


def cam_program(geometry: dict, finished) -> list[np.ndarray]:
    """The CAM program in the CAD frame [m]: a raster over each boss, kept where the ball touches
    the boss (its tip above the plate's top face), split into passes at the gaps."""
    top = geometry["plate"][2]
    passes = []
    for b in geometry["bosses"]:
        half = b["radius"] + TOOL_RADIUS_M
        lo, hi = np.asarray(b["axis_xy"]) - half, np.asarray(b["axis_xy"]) + half
        for p in drop_cutter_raster(finished.vertices, finished.faces, tool_radius_m=TOOL_RADIUS_M,
                                    stepover_m=0.0015, step_m=0.001, xy_min_m=tuple(lo), xy_max_m=tuple(hi)):
            on = p[:, 2] > top + 2e-4
            runs = np.split(np.arange(len(p)), np.nonzero(np.diff(on.astype(int)))[0] + 1)
            passes += [p[r] for r in runs if on[r[0]] and len(r) >= 2]
    return passes


def check(T: np.ndarray, passes_cad_m: list[np.ndarray], T_true: np.ndarray, blank_i: MeshIndex,
          top_face_cad: np.ndarray) -> dict:
    """The NC program for pose ``T`` written and read back, and the finished part checked."""
    tips = [relocate_tool_tips(p * 1e3, TOOL_RADIUS_M * 1e3, T) for p in passes_cad_m]
    safe = max(float(t[:, 2].max()) for t in tips) + 20.0
    text = write_gcode(tips, safe_z_mm=safe, title="bosses finished, located by document 003")
    cut = np.array([m.xyz_mm for m in read_gcode(text) if not m.rapid])
    planned = np.concatenate(tips)
    centres_m = (cut + [0.0, 0.0, TOOL_RADIUS_M * 1e3]) * 1e-3
    stock = TOOL_RADIUS_M - blank_i.signed_distance(transform_points(inv_pose(T_true), centres_m))
    n_true = T_true[:3, 2]
    datum = (transform_points(T, top_face_cad) - transform_points(T_true, top_face_cad)) @ n_true
    return {"read_back_um": float(np.max(np.abs(cut - planned)) * 1e3) if len(cut) == len(planned) else np.inf,
            "moves": len(cut), "lines": len(text.splitlines()), "min_stock_mm": float(stock.min() * 1e3),
            "datum_um": float(np.max(np.abs(datum)) * 1e6)}


def _pose_distance(T: np.ndarray, T_ref: np.ndarray) -> tuple[float, float]:
    D = inv_pose(T_ref) @ T
    angle = np.degrees(np.arccos(np.clip((np.trace(D[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)))
    return float(angle), float(np.linalg.norm(D[:3, 3]) * 1e3)


def run(trials: int) -> tuple[list[str], dict]:
    from twin.parts.symmetric import cast_blank, cast_blank_finished, cast_blank_geometry, classify_cast_blank_points
    from twin.scan import scan_scenario

    t0 = time.perf_counter()
    scan = scan_scenario(scenario("cast_blank"))
    P = scan.valid_points_base
    T_nom, T_true = scan.T_base_workpiece_nominal, scan.T_base_workpiece_true
    lab = classify_cast_blank_points(transform_points(inv_pose(T_nom), P))
    F, R = P[lab == "finished"], P[lab == "rough"]
    g = cast_blank_geometry()
    a = g["bosses"][0]
    Rn = transform_points(inv_pose(T_nom), R)
    groups = np.where(np.linalg.norm(Rn[:, :2] - a["dome_center"][:2], axis=1) < a["dome_base_radius"],
                      "boss_a", "boss_b")
    fin = cast_blank_finished()
    fin_i, blank_i = MeshIndex(fin), MeshIndex(cast_blank())
    passes = cam_program(g, fin)
    top = np.array([[x, y, g["plate"][2]] for x in np.linspace(-0.06, 0.06, 13) for y in (-0.035, 0.0, 0.035)])
    setup = {"scan_s": time.perf_counter() - t0, "finished": len(F), "rough": len(R), "passes": len(passes),
             "points": sum(len(p) for p in passes)}
    rows = []
    for trial in range(trials):
        rng = np.random.default_rng(np.random.SeedSequence(3003, spawn_key=(trial,)))
        xi = np.concatenate([rng.normal(0, np.radians(0.5) / np.sqrt(3), 3), rng.normal(0, 0.001 / np.sqrt(3), 3)])
        start = T_nom @ exp_se3(xi)
        pick = rng.choice(len(P), SWARM_POINTS, replace=False)
        t1 = time.perf_counter()
        T_pso, _ = pso_refine(P[pick], start, index=fin_i, rng=rng)
        t_pso = time.perf_counter() - t1
        t1 = time.perf_counter()
        hyb = localize_hybrid(F, R, fin, ALLOWANCE_M, groups=groups, init=start, index=fin_i)
        t_hyb = time.perf_counter() - t1
        for name, T, status, secs in (("printed", T_pso, "ok", t_pso), ("ours", hyb.T_world_workpiece,
                                                                         hyb.status.value, t_hyb)):
            angle, dist = _pose_distance(T, T_true)
            rows.append({"trial": trial, "method": name, "status": status, "time_s": secs, "angle_deg": angle,
                         "distance_mm": dist, **check(T, passes, T_true, blank_i, top)})
    return rows, setup


def report(rows: list[dict], setup: dict, trials: int, seconds: float) -> str:
    out = ["# Document 003 from a cast blank: located, the NC program relocated, the finished part checked", "",
           f"Command: `python -m benchmarks.bench_blank --trials {trials}`; commit {commit_stamp()}; "
           f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, {seconds:.0f} s.", "",
           f"`scenarios/cast_blank.toml` scanned in the cell once ({setup['finished']} points on the finished top "
           f"face, {setup['rough']} on the cast domes; {setup['scan_s']:.1f} s). The CAM program: a ball-end raster "
           f"(tool radius {TOOL_RADIUS_M * 1e3:g} mm) over the two bosses, {setup['passes']} passes, "
           f"{setup['points']} cutter locations. Machining allowance {ALLOWANCE_M * 1e3:g} mm. As printed: the "
           f"swarm on {SWARM_POINTS} of the measured points; ours: the hybrid localization on all of them "
           "(module docstring of `benchmarks/bench_blank.py`).", "",
           "`min stock`: the least stock under the read-back program's cutter locations on the true blank "
           "(negative: the finished surface lies outside the blank there, the part is scrap); `machinable`: "
           f"trials whose min stock is at least 0; `right`: machinable with the datum face within "
           f"{DATUM_TOLERANCE_M * 1e6:g} um; `datum error`: the finished top face at the found pose "
           "against where it is; `read back`: the largest difference between the program's cutter locations "
           "and those read back from its G-code text.", "",
           "| method | trials | status ok | machinable | right | min stock, worst [mm] | min stock, median [mm] | "
           "datum error, worst [um] | from the blank's frame, median (deg / mm) | read back, worst [um] | "
           "G-code lines | median time [s] |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name in ("printed", "ours"):
        r = [x for x in rows if x["method"] == name]
        stock = np.array([x["min_stock_mm"] for x in r])
        right = sum(x["min_stock_mm"] >= 0 and x["datum_um"] <= DATUM_TOLERANCE_M * 1e6 for x in r)
        out.append(f"| {name} | {len(r)} | {sum(x['status'] == 'ok' for x in r)} of {len(r)} | "
                   f"{int(np.sum(stock >= 0))} of {len(r)} | {right} of {len(r)} | {stock.min():+.3f} | "
                   f"{np.median(stock):+.3f} | "
                   f"{max(x['datum_um'] for x in r):.1f} | {np.median([x['angle_deg'] for x in r]):.3f} / "
                   f"{np.median([x['distance_mm'] for x in r]):.3f} | {max(x['read_back_um'] for x in r):.2f} | "
                   f"{r[0]['lines']} | {np.median([x['time_s'] for x in r]):.2f} |")
    out += ["", "Per trial:", "", "| trial | method | status | min stock [mm] | datum error [um] | "
            "from the blank's frame (deg / mm) |", "|---|---|---|---|---|---|"]
    out += [f"| {x['trial']} | {x['method']} | {x['status']} | {x['min_stock_mm']:+.3f} | {x['datum_um']:.1f} | "
            f"{x['angle_deg']:.3f} / {x['distance_mm']:.3f} |" for x in rows]
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=10)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results_blank.md"))
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    rows, setup = run(args.trials)
    text = report(rows, setup, args.trials, time.perf_counter() - t0)
    Path(args.out).write_text(text, encoding="utf-8")
    print(text)


if __name__ == "__main__":
    main()

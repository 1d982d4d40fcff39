"""Document 001's hierarchy over seeded trials: coarse accuracy, the qualified radius, the
final error against its reported covariance, contacts; and the fine-point planners compared.

Each trial of a locate scenario draws, from its seed, where the part really is: the
scenario's nominal pose moved by 20-40 mm in a random direction on the table and turned by
10-30 degrees (either way) about the vertical, as document 001's "tens of millimetres and
degrees"; the sensor's and the probe's noise come from the same seed. Then ``twin.workflows.locate``
runs the whole hierarchy in the twin.

Sections:

* ``trials``: per scenario, N trials with the default coarse method (the scenario's
  ``locate.coarse``): the coarse rate within 1 mm and 1 deg, the final errors in standard
  deviations of the reported covariance (per twist component and Mahalanobis), the
  effective radius against its truth, unintended contacts, misses;
* ``ga``: the same trial poses, coarse stage only, with document 001's genetic algorithm
  in one run (its constants, as the document runs it): its rate within 1 mm and 1 deg;
* ``planners``: D-optimal, evenly spread and random fine points of the same count on the
  same trials (one scenario): the predicted pose standard deviations and the measured
  errors.

Run from the repository root, e.g. ``python -m benchmarks.bench_locate --trials 20``
(writes ``benchmarks/results_locate.md``; ``--section``, ``--scenario`` and ``--workers``
narrow or spread it). Trials run in worker processes; each trial's numbers depend only on
its seed.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ("locate_hemisphere_punch", "locate_bottle_punch", "locate_s_surface")
SHIFT_M = (0.020, 0.040)
YAW_DEG = (10.0, 30.0)


def trial_scenario(name: str, seed: int):
    """The scenario with this trial's true pose and seed."""
    from scipy.spatial.transform import Rotation

    from twin.scenario import load_scenario

    sc = load_scenario(ROOT / "scenarios" / f"{name}.toml", {"seed": seed})
    rng = np.random.default_rng([seed, 1])
    shift = rng.uniform(*SHIFT_M)
    ang = rng.uniform(0, 2 * np.pi)
    yaw = rng.uniform(*YAW_DEG) * rng.choice([-1.0, 1.0])
    T = sc.workpiece.T_world_workpiece_nominal.copy()
    T_true = T.copy()
    T_true[:3, 3] += [shift * np.cos(ang), shift * np.sin(ang), 0.0]
    T_true[:3, :3] = Rotation.from_euler("z", yaw, degrees=True).as_matrix() @ T[:3, :3]
    wp = dataclasses.replace(sc.workpiece, T_world_workpiece_true=T_true)
    return dataclasses.replace(sc, workpiece=wp)


def run_trial(args) -> dict:
    name, seed, coarse, planner, coarse_only = args
    from twin import evaluate
    from twin.io.report import locate_report
    from twin.realize import realize
    from twin.workflows.locate import coarse_pose, coarse_scan

    realized = realize(trial_scenario(name, seed))
    t0 = time.perf_counter()
    if coarse_only:
        from twin.cell import build_cell

        _, pts = coarse_scan(realized, build_cell(realized, "nominal"), build_cell(realized, "true"))
        T, _ = coarse_pose(pts, realized, coarse)
        e = evaluate.full_pose_errors(T, realized.T_base_workpiece_true, None)
        return {"scenario": name, "seed": seed, "coarse": coarse,
                "coarse_rot_deg": float(np.degrees(e["rotation_rad"])),
                "coarse_trans_mm": float(e["translation_m"] * 1e3), "wall_s": time.perf_counter() - t0}
    from twin.workflows.locate import locate

    res = locate(realized, coarse=coarse, planner=planner)
    rep = locate_report(res)
    out = {"scenario": name, "seed": seed, "coarse": coarse, "planner": planner, "complete": rep["complete"],
           "failed_stage": rep.get("failed_stage"), "failure": rep.get("failure"), "wall_s": time.perf_counter() - t0}
    if "coarse" in rep:
        out.update(coarse_rot_deg=rep["coarse"]["rotation_error_deg"],
                   coarse_trans_mm=rep["coarse"]["translation_error_mm"])
    if "qualification" in rep:
        out["radius_error_um"] = rep["qualification"]["effective_radius_error_um"]
    if "probing" in rep:
        out.update(hits=rep["probing"]["hits"], points=rep["probing"]["points"],
                   contacts=rep["probing"]["unintended_contacts"])
    if "fine" in rep:
        f = rep["fine"]
        out.update(final_rot_deg=f["rotation_error_deg"], final_trans_um=f["translation_error_mm"] * 1e3,
                   max_sigmas=f["max_error_sigmas"], mahalanobis=f["mahalanobis"], status=f["status"],
                   pred_rot_deg=max(rep["plan"]["predicted_std_rotation_deg"]),
                   pred_trans_um=max(rep["plan"]["predicted_std_translation_um"]))
    return out


def _pool(jobs, workers):
    if workers <= 1:
        return [run_trial(j) for j in jobs]
    with ProcessPoolExecutor(workers) as ex:
        return list(ex.map(run_trial, jobs))


def _rate(rows, key_rot="coarse_rot_deg", key_tr="coarse_trans_mm") -> str:
    ok = [r for r in rows if key_rot in r and r[key_rot] <= 1.0 and r[key_tr] <= 1.0]
    return f"{len(ok)}/{len(rows)} ({100.0 * len(ok) / max(len(rows), 1):.0f} %)"


def section_trials(names, trials, workers, lines):
    from twin.scenario import load_scenario

    lines += ["## Trials (default coarse method)", "",
              "| scenario | coarse | within 1 mm & 1 deg | coarse err max (deg / mm) | complete | "
              "final max err (sigma) | max Mahalanobis | final err max (deg / um) | radius err max (um) | "
              "hits | contacts | wall per trial (s) |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name in names:
        coarse = load_scenario(ROOT / "scenarios" / f"{name}.toml").locate.coarse
        rows = _pool([(name, s, coarse, "d_optimal", False) for s in range(trials)], workers)
        done = [r for r in rows if r.get("complete")]
        fails = [f"seed {r['seed']}: {r['failed_stage']} ({r['failure']})" for r in rows if not r.get("complete")]
        worst_rot = max(r.get("coarse_rot_deg", np.nan) for r in rows)
        worst_tr = max(r.get("coarse_trans_mm", np.nan) for r in rows)
        lines.append(
            f"| {name} | {coarse} | {_rate(rows)} | {worst_rot:.3f} / {worst_tr:.3f} | "
            f"{len(done)}/{len(rows)} | {max((r['max_sigmas'] for r in done), default=np.nan):.2f} | "
            f"{max((r['mahalanobis'] for r in done), default=np.nan):.2f} | "
            f"{max((r['final_rot_deg'] for r in done), default=np.nan):.5f} / "
            f"{max((r['final_trans_um'] for r in done), default=np.nan):.2f} | "
            f"{max((abs(r['radius_error_um']) for r in rows if 'radius_error_um' in r), default=np.nan):.3f} | "
            f"{sum(r.get('hits', 0) for r in rows)}/{sum(r.get('points', 0) for r in rows)} | "
            f"{sum(r.get('contacts', 0) for r in rows)} | {np.mean([r['wall_s'] for r in rows]):.1f} |")
        print(lines[-1], flush=True)
        if fails:
            lines.append(f"|  | failed: {'; '.join(fails)} |||||||||||")
            print(lines[-1], flush=True)
    lines.append("")


def section_ga(names, trials, workers, lines):
    lines += ["## Document 001's genetic algorithm, one run (coarse stage only)", "",
              "| scenario | within 1 mm & 1 deg | median err (deg / mm) | max err (deg / mm) | wall per trial (s) |",
              "|---|---|---|---|---|"]
    for name in names:
        rows = _pool([(name, s, "ga", "d_optimal", True) for s in range(trials)], workers)
        rot = np.array([r["coarse_rot_deg"] for r in rows])
        tr = np.array([r["coarse_trans_mm"] for r in rows])
        lines.append(f"| {name} | {_rate(rows)} | {np.median(rot):.2f} / {np.median(tr):.2f} | "
                     f"{rot.max():.2f} / {tr.max():.2f} | {np.mean([r['wall_s'] for r in rows]):.1f} |")
        print(lines[-1], flush=True)
    lines.append("")


def section_planners(name, trials, workers, lines):
    from twin.scenario import load_scenario

    coarse = load_scenario(ROOT / "scenarios" / f"{name}.toml").locate.coarse
    lines += [f"## Fine-point planners on {name} (12 points each, the same trials)", "",
              "| planner | predicted std max (deg / um) | measured err rms (deg / um) | measured err max (deg / um) | "
              "complete |", "|---|---|---|---|---|"]
    for planner in ("d_optimal", "spread", "random"):
        rows = _pool([(name, s, coarse, planner, False) for s in range(trials)], workers)
        done = [r for r in rows if r.get("complete")]
        rot = np.array([r["final_rot_deg"] for r in done])
        tr = np.array([r["final_trans_um"] for r in done])
        lines.append(f"| {planner} | {np.mean([r['pred_rot_deg'] for r in done]):.5f} / "
                     f"{np.mean([r['pred_trans_um'] for r in done]):.2f} | {np.sqrt(np.mean(rot**2)):.5f} / "
                     f"{np.sqrt(np.mean(tr**2)):.2f} | {rot.max():.5f} / {tr.max():.2f} | {len(done)}/{len(rows)} |")
        print(lines[-1], flush=True)
    lines.append("")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=20)
    ap.add_argument("--planner-trials", type=int, default=10)
    ap.add_argument("--section", choices=("trials", "ga", "planners", "all"), default="all")
    ap.add_argument("--scenario", choices=SCENARIOS, action="append")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results_locate.md"))
    a = ap.parse_args()
    names = a.scenario or list(SCENARIOS)
    lines = ["# Document 001's hierarchy in the twin", "",
             f"`python -m benchmarks.bench_locate {' '.join(sys.argv[1:])}`; "
             f"{platform.processor() or platform.machine()}, "
             f"{os.cpu_count()} cores, {a.workers} worker process(es). Each trial: the part {SHIFT_M[0] * 1e3:.0f}-"
             f"{SHIFT_M[1] * 1e3:.0f} mm and {YAW_DEG[0]:.0f}-{YAW_DEG[1]:.0f} deg away from its nominal pose "
             "(drawn from the seed), the scenario's noise.", ""]
    t0 = time.perf_counter()
    if a.section in ("trials", "all"):
        section_trials(names, a.trials, a.workers, lines)
    if a.section in ("ga", "all"):
        section_ga(names, a.trials, a.workers, lines)
    if a.section in ("planners", "all"):
        section_planners(names[-1], a.planner_trials, a.workers, lines)
    lines.append(f"Total wall time {time.perf_counter() - t0:.0f} s.")
    Path(a.out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

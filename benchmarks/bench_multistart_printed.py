"""Document 000's Algorithm 5 as printed against ours: does the multistart find the true pose
from any orientation?

The claim (section 8): Algorithm 1 converges from within 45 deg, so a table of starts at 30 deg
steps, stopping at the first start that passes all of step 5's tests, finds the global minimum.
Run on workpieces A and B with the basin studies' point sets (``studies/doc000_basin.toml``,
``studies/doc000_basin_B.toml``: 150 points drawn per trial on the hemisphere and two side
faces, or on the half bottle and the plate top; noise sigma 5 um on each coordinate), each trial
with the part's true orientation drawn uniformly from SO(3) (its position the scenario's):

* ``printed``: ``global_localize(..., variant="printed")``: the 36 Euler starts
  ``Rz(alpha0) Ry(beta0)``, stop at the first start that passes (the descents, the verification
  and the polish are ours);
* ``ours``: the default: the 60 icosahedral starts, every start run and its minimum verified.

Success: within 0.5 deg / 0.5 mm of the truth. ``ok outside`` counts the answers the verdict
called ``ok`` that are not (a wrong pose called good).

    python -m benchmarks.bench_multistart_printed [--trials 40] [--out benchmarks/results_multistart_printed.md]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from algorithms.geometry.se3 import make_pose, rotation_error_rad, translation_error_m
from algorithms.registration import global_localize
from tests.helpers import ROOT, commit_stamp
from twin.scenario import load_scenario
from twin.studies.point_sets import measured_points, model_points
from twin.studies.spec import load_study
from twin.studies.trials import part_design

PARTS = {"A (hemisphere punch)": "doc000_basin.toml", "B (bottle punch)": "doc000_basin_B.toml"}
VARIANTS = ("printed", "ours")
ANGLE_DEG, DISTANCE_M = 0.5, 0.0005
SIGMA_M = 5e-6   # the studies' points.noise_sigma_m


def _part(study_file: str):
    """The study's part (its mesh index and true position) and point-set settings and design."""
    study = load_study(ROOT / "studies" / study_file)
    settings = study.cell_settings(0)
    spec = settings.points
    realized, design = part_design(load_scenario(settings.scenario_path, settings.overrides, machine="arm"), spec)
    return realized.workpiece.index, realized.scenario.workpiece.T_world_workpiece_true[:3, 3], spec, design


def _trials(study_file: str, trials: int, seed: int):
    """Each trial's (index, measured points (150, 3) [m], T_true), the true orientation uniform."""
    index, position, spec, design = _part(study_file)
    rng = np.random.default_rng(seed)
    for _ in range(trials):
        T_true = make_pose(Rotation.random(random_state=rng).as_matrix(), position)
        x = model_points(index.mesh, design, spec, "none", rng)
        cp = index.query(x)
        yield index, measured_points(x, index.smooth_normals(cp.face, cp.foot), T_true, spec, rng), T_true


def _trial_points(study_file: str, seed: int, trial: int):
    """Trial ``trial``'s (index, points, T_true) of a run with ``seed`` (for a test to replay one)."""
    for i, out in enumerate(_trials(study_file, trial + 1, seed)):
        if i == trial:
            return out
    raise ValueError(f"no trial {trial}")


def run_part(study_file: str, trials: int, seed: int) -> dict[str, list[dict]]:
    rows: dict[str, list[dict]] = {v: [] for v in VARIANTS}
    for index, pts, T_true in _trials(study_file, trials, seed):
        for variant in VARIANTS:
            t0 = time.perf_counter()
            res = global_localize(pts, index=index, noise_sigma_m=SIGMA_M, variant=variant,
                                  rng=np.random.default_rng(0))
            dt = time.perf_counter() - t0
            right = (np.degrees(rotation_error_rad(res.T_world_workpiece, T_true)) <= ANGLE_DEG
                     and translation_error_m(res.T_world_workpiece, T_true) <= DISTANCE_M)
            rows[variant].append({"right": right, "ok": res.status.value == "ok", "time_s": dt,
                                  "starts": res.diagnostics.n_starts})
    return rows


def report(results: dict, trials: int, seed: int, wall_s: float) -> str:
    lines = ["# Algorithm 5 as printed against ours", "",
             f"Command: `python -m benchmarks.bench_multistart_printed --trials {trials} --seed {seed}`; commit "
             f"{commit_stamp()}; {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}; "
             f"{wall_s:.0f} s.", "",
             f"{trials} trials per part, the true orientation uniform in SO(3); the basin studies' 150-point sets, "
             f"noise 5 um. Right: within {ANGLE_DEG} deg / {DISTANCE_M * 1e3:g} mm of the truth. "
             "`ok outside`: called ok, not right (module docstring).", "",
             "| part | variant | right | ok | ok outside | starts run (median) | median time [ms] |",
             "|---|---|---|---|---|---|---|"]
    for part, rows in results.items():
        for variant in VARIANTS:
            r = rows[variant]
            right = sum(x["right"] for x in r)
            ok = sum(x["ok"] for x in r)
            outside = sum(x["ok"] and not x["right"] for x in r)
            lines.append(f"| {part} | {variant} | {right} of {len(r)} | {ok} of {len(r)} | {outside} | "
                         f"{statistics.median(x['starts'] for x in r):g} | "
                         f"{1e3 * statistics.median(x['time_s'] for x in r):.0f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=40)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results_multistart_printed.md"))
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    results = {part: run_part(f, a.trials, a.seed) for part, f in PARTS.items()}
    text = report(results, a.trials, a.seed, time.perf_counter() - t0)
    Path(a.out).write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Localization on real-like dense partial scans and on 150-point free-form sets, against
small_gicp's GICP on the same points from the same starts.

The scans behave like a laser scanner's partial views of a real part, not like samples of the
model the fit uses:

- the part: document 000's bottle punch (a plate and half a bottle of Bezier patches); the
  model the fits use is tessellated at ``MODEL_RESOLUTION_M`` (about 60,000 triangles), the
  truth the rays hit at ``TRUTH_RESOLUTION_M`` (a finer tessellation: the model's facets are
  a form error of the scan);
- each view: a grid of parallel rays from one direction of the upper hemisphere over the
  part's bounding circle (``RAYS_PER_SIDE`` squared rays), the first hit on the true part, or
  else on the table around it (``TABLE_MARGIN_M``): points off the model's edges;
- noise along the ray: Gaussian ``NOISE_M``, with ``TAIL_SHARE`` of the points drawn with
  ``TAIL_FACTOR`` times that sigma (a heavy tail);
- the part placed at a random pose; each fit starts ``START_DEG`` / ``START_M`` off it (a
  random axis and direction).

Each scan is fitted at full density, as a ``VOXEL_M`` voxel subset (the first point of each
voxel) and as ``SMALL_N`` points drawn from it (the free-form 150-point case), each once as
scanned and once with the table cropped as a cell crops its known table (the points within
``TABLE_CROP_M`` of its plane dropped). With the table, ours rejects the table's points and
reports the fit a poor fit (the model leaves a coherent patch unexplained: the table is no part
of it); the ``not ok`` column counts the fits ours did not call ``ok``. Both methods run as the studies run them
(:func:`twin.studies.methods.run_method`):
ours, ``algorithms.registration.localize`` (its default method and robust rule, the noise
sigma given); the peer, small_gicp GICP against a dense sample of the model (0.5 mm, normals
and covariances from 20 neighbours, prepared once), the source's covariances estimated in each
call, correspondences up to 3x the start's distance, run to convergence. Times are the fits'
own (the model index and the peer's target prepared before), medians over the views; errors
against the true pose. small_gicp is optional (``pip install small_gicp``); without it only
ours is timed.

    python -m benchmarks.bench_dense_scans [--views 10] [--out benchmarks/results_dense_scans.md]
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.raycast import raycast_parallel
from algorithms.geometry.se3 import exp_se3, rotation_error_rad, transform_points, translation_error_m
from algorithms.registration.local import DEFAULT_METHOD
from tests.helpers import ROOT, commit_stamp
from twin.parts import make_workpiece
from twin.realize import Workpiece
from twin.studies.methods import Outcome, run_method

PART = "bottle_punch"
MODEL_RESOLUTION_M = 0.0006
TRUTH_RESOLUTION_M = 0.0004
RAYS_PER_SIDE = 280
TABLE_MARGIN_M = 0.003
NOISE_M = 1e-4
TAIL_SHARE = 0.03
TAIL_FACTOR = 10.0
START_DEG = 5.0
START_M = 0.005
VOXEL_M = 0.001
TABLE_CROP_M = 0.0005
SMALL_N = 150


def _view_directions(n: int, rng: np.random.Generator) -> np.ndarray:
    """n unit directions the rays travel along: from above, 0-60 deg off the vertical."""
    tilt = np.radians(rng.uniform(0.0, 60.0, n))
    azimuth = rng.uniform(0.0, 2.0 * np.pi, n)
    up = np.column_stack([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), np.cos(tilt)])
    return -up


def scan_view(truth, direction: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One partial view of the part (workpiece frame): the rays' first hits on the true part,
    else on the table (z = 0) within the margin of the part's footprint, with noise along the ray."""
    lo, hi = truth.bounds
    centre = 0.5 * (lo + hi)
    radius = 0.5 * float(np.linalg.norm(hi - lo))
    e1 = np.cross(direction, [1.0, 0.0, 0.0] if abs(direction[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(direction, e1)
    u = np.linspace(-radius, radius, RAYS_PER_SIDE) + 1.234e-5
    a, b = np.meshgrid(u, u)
    origins = centre - 2.0 * radius * direction + a.reshape(-1, 1) * e1 + b.reshape(-1, 1) * e2
    hit, points, _ = raycast_parallel(truth.vertices, truth.faces, origins, direction)
    # the table: rays that miss the part, where they meet z = 0 near its footprint
    t = -origins[~hit, 2] / direction[2]
    table = origins[~hit] + t[:, None] * direction
    near = np.all((table[:, :2] > lo[:2] - TABLE_MARGIN_M) & (table[:, :2] < hi[:2] + TABLE_MARGIN_M), axis=1)
    pts = np.vstack([points[hit], table[near]])
    sigma = np.where(rng.uniform(size=len(pts)) < TAIL_SHARE, TAIL_FACTOR * NOISE_M, NOISE_M)
    return pts + (rng.normal(size=len(pts)) * sigma)[:, None] * direction


def voxel_subset(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """The first point of each occupied voxel."""
    keys = np.floor(points / voxel_m).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return points[np.sort(first)]


def random_start(T_true: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """T_true moved by START_DEG about a random axis through the part and START_M along a random direction."""
    w = rng.normal(size=3)
    v = rng.normal(size=3)
    xi = np.r_[np.radians(START_DEG) * w / np.linalg.norm(w), START_M * v / np.linalg.norm(v)]
    return T_true @ exp_se3(xi)


def _fit(method: str, points: np.ndarray, workpiece: Workpiece, T_init: np.ndarray) -> Outcome:
    """One fit as the studies run it (``twin.studies.methods.run_method``)."""
    out = run_method(method, points, workpiece, T_init, NOISE_M, np.random.default_rng(0), START_M)
    if isinstance(out, str):
        raise RuntimeError(f"{method}: {out}")
    return out


def _errors(who: str, out: Outcome, T_true: np.ndarray) -> dict:
    return {f"{who}_um": translation_error_m(out.T_world_workpiece, T_true) * 1e6,
            f"{who}_urad": rotation_error_rad(out.T_world_workpiece, T_true) * 1e6}


def run(views: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    model = make_workpiece(PART, resolution_m=MODEL_RESOLUTION_M)
    truth = make_workpiece(PART, resolution_m=TRUTH_RESOLUTION_M)
    workpiece = Workpiece(model, MeshIndex(model))
    has_peer = importlib.util.find_spec("small_gicp") is not None
    names = ("full density", "table cropped", f"{VOXEL_M * 1e3:g} mm voxels", f"{SMALL_N} points",
             f"table cropped, {VOXEL_M * 1e3:g} mm voxels", f"table cropped, {SMALL_N} points")
    rows: dict[str, list[dict]] = {name: [] for name in names}
    for direction in _view_directions(views, rng):
        scan_wp = scan_view(truth, direction, rng)
        T_true = exp_se3(np.r_[rng.normal(scale=0.3, size=3), rng.normal(scale=0.1, size=3)])
        scan = transform_points(T_true, scan_wp)
        cropped = scan[scan_wp[:, 2] > TABLE_CROP_M]   # the part rests on the table (z = 0 of its frame)
        sets = dict(zip(names, (scan, cropped, voxel_subset(scan, VOXEL_M),
                                scan[rng.choice(len(scan), SMALL_N, replace=False)], voxel_subset(cropped, VOXEL_M),
                                cropped[rng.choice(len(cropped), SMALL_N, replace=False)]), strict=True))
        T_init = random_start(T_true, rng)
        for name, pts in sets.items():
            ours = _fit(DEFAULT_METHOD, pts, workpiece, T_init)
            row = {"n": len(pts), "ours_s": ours.time_s, "status": ours.status, **_errors("ours", ours, T_true)}
            if has_peer:
                peer = _fit("small_gicp", pts, workpiece, T_init)
                row |= {"peer_s": peer.time_s, **_errors("peer", peer, T_true)}
            rows[name].append(row)
    return {"rows": rows, "model_faces": len(model.faces), "truth_faces": len(truth.faces), "peer": has_peer}


def report(out: dict, views: int, seed: int, wall_s: float) -> str:
    med = statistics.median
    lines = [
        "# Dense partial scans and 150-point sets: ours against small_gicp GICP",
        "",
        f"Command: `python -m benchmarks.bench_dense_scans --views {views} --seed {seed}`; commit {commit_stamp()}; "
        f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}; {wall_s:.0f} s.",
        "",
        f"{PART}: model {out['model_faces']:,} triangles, truth {out['truth_faces']:,}; {views} views, "
        f"{RAYS_PER_SIDE}x{RAYS_PER_SIDE} rays each (table within {TABLE_MARGIN_M * 1e3:g} mm of the part), "
        f"noise {NOISE_M * 1e3:g} mm along the ray ({TAIL_SHARE:.0%} at {TAIL_FACTOR:g}x); starts "
        f"{START_DEG:g} deg / {START_M * 1e3:g} mm off. Medians over the views (module docstring).",
        "",
        "| points | n (median) | ours [ms] | GICP [ms] | ours / GICP | ours: error [um, urad] | GICP: error [um, urad] "
        "| ours not ok |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, rows in out["rows"].items():
        ours_ms = med(r["ours_s"] for r in rows) * 1e3
        bad = sum(r["status"] != "ok" for r in rows)
        ours_err = f"{med(r['ours_um'] for r in rows):.1f}, {med(r['ours_urad'] for r in rows):.0f}"
        if out["peer"]:
            peer_ms = med(r["peer_s"] for r in rows) * 1e3
            peer_err = f"{med(r['peer_um'] for r in rows):.1f}, {med(r['peer_urad'] for r in rows):.0f}"
            ratio = f"{ours_ms / peer_ms:.2f}"
        else:
            peer_ms, peer_err, ratio = float("nan"), "not installed", ""
        lines.append(f"| {name} | {med(r['n'] for r in rows):,.0f} | {ours_ms:.1f} | {peer_ms:.1f} | {ratio} | "
                     f"{ours_err} | {peer_err} | {bad} of {len(rows)} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, default=10)
    ap.add_argument("--seed", type=int, default=31)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results_dense_scans.md"))
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    out = run(args.views, args.seed)
    text = report(out, args.views, args.seed, time.perf_counter() - t0)
    Path(args.out).write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Numbers behind the symmetric/hybrid localization bar (document 000, Algorithms 2 and 3).

    python -m benchmarks.bench_symmetric [--trials N]     (from the repository root)
    python -m benchmarks.bench_symmetric --trials 1 --sections algorithm2 cube   # a smoke run

Writes ``benchmarks/results_symmetric.md``: for every feature of the table, Algorithm 2's error
in the fixed directions and the free directions it reports; the automatic detection's hit rate over seeded trials at the
default noise (2 um) and at 10x that; the cube's equally good poses; and the hybrid result on
the cast-blank scenario scanned in the cell, checked against the true part.
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
from algorithms.registration.hybrid import envelope_distances, localize_hybrid
from algorithms.registration.symmetric import FEATURE_TABLE, FEATURE_TYPES, algorithm2, localize_symmetric
from tests.helpers import ROOT, commit_stamp, scenario
from tests.test_features import example_features, sample_feature
from tests.test_symmetric import SYMMETRIC_MESHES, _cube_faces, _random_pose, _scan_like


def bar_algorithm2() -> list[str]:
    rows = ["## Algorithm 2 on every feature", "",
            "200 exact points of the feature, a random pose, the start about 2 deg / 4 mm off. `free`: the "
            "directions Algorithm 2 reports free, against the dimension of G_0 in the document's table; the "
            "errors are measured in the directions the feature fixes; the rank is that of the Tangent / "
            "Hong-Tan linear system (document 000, section 4: singular on a symmetric feature).", "",
            "| feature | free | table | fixed-direction rotation error [rad] | fixed-direction translation error [m] "
            "| Tangent/Hong-Tan rank | full rank | rank deficit |", "|---|---|---|---|---|---|---|---|"]
    for kind in FEATURE_TYPES:
        rng = np.random.default_rng(FEATURE_TYPES.index(kind) + 100)
        f = example_features()[kind]
        X = sample_feature(f, 200, rng)
        T = _random_pose(rng, f.planar)
        xi0 = (np.array([0, 0, 0.05, 0.004, -0.003, 0]) if f.planar
               else np.concatenate([rng.normal(0, 0.04, 3), rng.normal(0, 0.004, 3)]))
        res = algorithm2(transform_points(T, X), f, init=T @ exp_se3(xi0))
        ang, dist = f.group.distance(inv_pose(T) @ res.T_world_workpiece)
        rows.append(f"| {kind} | {res.free_dofs} | {FEATURE_TABLE[kind].group_dim} | {ang:.2e} | {dist:.2e} | "
                    f"{res.general_system_rank} | {3 if f.planar else 6} | "
                    f"{(3 if f.planar else 6) - res.general_system_rank} |")
    return rows


def bar_detection(trials: int) -> list[str]:
    rows = ["## Automatic detection", "",
            f"{trials} seeded trials per feature and noise level: 300 points on a mesh of the feature, a random "
            "pose, the start about 2 deg / 2 mm off; a hit is the right feature type and number of free "
            "directions.", "",
            "| sigma [um] | feature | hit rate | time per trial [ms] |", "|---|---|---|---|"]
    for sigma in (2e-6, 2e-5):
        for kind, (make, select, r) in SYMMETRIC_MESHES.items():
            mesh = make()
            faces = np.nonzero(select(mesh))[0]
            hits, t0 = 0, time.perf_counter()
            for seed in range(trials):
                rng = np.random.default_rng(seed)
                X = _scan_like(mesh, faces, 300, rng, sigma)
                T = _random_pose(rng)
                init = T @ exp_se3(np.concatenate([rng.normal(0, 0.03, 3), rng.normal(0, 0.002, 3)]))
                res = localize_symmetric(transform_points(T, X), mesh, init=init)
                hits += (res.feature, res.free_dofs) == (kind, r)
            rows.append(f"| {sigma * 1e6:.0f} | {kind} | {hits} of {trials} | "
                        f"{(time.perf_counter() - t0) / trials * 1e3:.0f} |")
    return rows


def bar_cube() -> list[str]:
    import trimesh

    cube = trimesh.creation.box([0.04, 0.04, 0.04])
    rows = ["## A cube: equally good poses by measured faces", "",
            "| faces measured | solutions | free directions | feature | status |", "|---|---|---|---|---|"]
    for which, name in (([(0, 1), (1, 1), (2, 1)], "three"), ([(0, 1), (2, 1)], "two"), ([(2, 1)], "one")):
        rng = np.random.default_rng(5)
        T = _random_pose(rng)
        Y = transform_points(T, _cube_faces(rng, which)) + rng.normal(0, 2e-6, (100 * len(which), 3))
        res = localize_symmetric(Y, cube, init=T @ exp_se3([0.03, -0.02, 0.02, 0.002, 0.001, -0.002]))
        rows.append(f"| {name} | {len(res.solutions)} | {res.free_dofs} | {res.feature} | {res.status.value} |")
    return rows


def bar_hybrid() -> list[str]:
    from twin.parts.symmetric import (
        cast_blank,
        cast_blank_finished,
        cast_blank_geometry,
        cast_blank_rough_points,
        classify_cast_blank_points,
    )
    from twin.scan import scan_scenario

    sc = scenario("cast_blank")
    t0 = time.perf_counter()
    scan = scan_scenario(sc)
    P = scan.valid_points_base
    T_nom, T_true = scan.T_base_workpiece_nominal, scan.T_base_workpiece_true
    lab = classify_cast_blank_points(transform_points(inv_pose(T_nom), P))
    F, R = P[lab == "finished"], P[lab == "rough"]
    a = cast_blank_geometry()["bosses"][0]
    Rn = transform_points(inv_pose(T_nom), R)
    groups = np.where(np.linalg.norm(Rn[:, :2] - a["dome_center"][:2], axis=1) < a["dome_base_radius"],
                      "boss_a", "boss_b")
    fin = cast_blank_finished()
    fin_i = MeshIndex(fin)
    blank_i = MeshIndex(cast_blank())
    rows = ["## Hybrid localization of the cast blank (Algorithm 3)", "",
            f"`scenarios/cast_blank.toml` scanned in the cell ({len(F)} points on the finished top face, "
            f"{len(R)} on the rough domes; scan {time.perf_counter() - t0:.1f} s), Algorithm 2 on the face, "
            "Algorithm 3 keeping each rough point at least the allowance outside the finished part. Margins are "
            "the distance outside the finished part at the found pose, less the allowance: measured (the scanned "
            "points), true (the true blank surface under each measured point) and over 20000 samples of the "
            "domes' true surface.", "",
            "| allowance [mm] | status | feasible | measured min margin [mm] | true min margin [mm] | "
            "dense min margin [mm] | best achievable [mm] | min stock per group [mm] | free | LPs | time [s] |",
            "|---|---|---|---|---|---|---|---|---|---|---|"]
    for allowance in (0.001, 0.0025, 0.0035):
        t1 = time.perf_counter()
        res = localize_hybrid(F, R, fin, allowance, groups=groups, init=T_nom, index=fin_i)
        feet = transform_points(T_true, blank_i.query(transform_points(inv_pose(T_true), R)).foot)
        d_true, _, _ = envelope_distances(feet, res.T_world_workpiece, fin_i)
        Zd, _ = cast_blank_rough_points(20000, np.random.default_rng(9))
        d_dense, _, _ = envelope_distances(transform_points(T_true, Zd), res.T_world_workpiece, fin_i)
        stock = ", ".join(f"{k} {v * 1e3:.4f}" for k, v in res.min_allowance_m.items())
        rows.append(f"| {allowance * 1e3:.1f} | {res.status.value} | {res.feasible} | "
                    f"{res.margin_m.min() * 1e3:+.6f} | "
                    f"{(d_true.min() - allowance) * 1e3:+.4f} | {(d_dense.min() - allowance) * 1e3:+.4f} | "
                    f"{res.best_min_margin_m * 1e3:+.4f} | {stock} | {res.free_dofs} | {res.lp_solves} | "
                    f"{time.perf_counter() - t1:.2f} |")
    return rows


SECTIONS = ("algorithm2", "detection", "cube", "hybrid")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=50)
    ap.add_argument("--sections", nargs="+", choices=SECTIONS, default=list(SECTIONS))
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results_symmetric.md"))
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    body: list[str] = []
    for name, run in (("algorithm2", bar_algorithm2), ("detection", lambda: bar_detection(args.trials)),
                      ("cube", bar_cube), ("hybrid", bar_hybrid)):
        if name in args.sections:
            body += run() + [""]
    command = "python -m benchmarks.bench_symmetric" + (f" --trials {args.trials}" if args.trials != 50 else "")
    head = ["# Symmetric and hybrid localization (document 000, Algorithms 2 and 3)", "",
            f"Command: `{command}`; commit {commit_stamp()}; {platform.machine()}, {os.cpu_count()} cores, "
            f"Python {platform.python_version()}, {time.perf_counter() - t0:.0f} s.", ""]
    text = "\n".join(head + body)
    Path(args.out).write_text(text, encoding="utf-8")
    print(text)


if __name__ == "__main__":
    main()

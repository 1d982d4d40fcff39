"""Numbers behind the symmetric/hybrid localization bar (document 000, Algorithms 2 and 3).

    python -m benchmarks.bench_symmetric [--trials N]     (from the repository root)
    python -m benchmarks.bench_symmetric --trials 1 --sections algorithm2 cube   # a smoke run

Prints, for every feature of the table, Algorithm 2's error in the fixed directions and the
free directions it reports; the automatic detection's hit rate over seeded trials at the
default noise (2 um) and at 10x that; the cube's equally good poses; and the hybrid result on
the cast-blank scenario scanned in the cell, checked against the true part.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import exp_se3, inv_pose, transform_points
from algorithms.registration.hybrid import envelope_distances, localize_hybrid
from algorithms.registration.symmetric import FEATURE_TABLE, FEATURE_TYPES, algorithm2, localize_symmetric
from tests.helpers import scenario
from tests.test_features import example_features, sample_feature
from tests.test_symmetric import SYMMETRIC_MESHES, _cube_faces, _random_pose, _scan_like


def bar_algorithm2():
    print("Algorithm 2 on every feature (200 exact points, random pose, init off by ~2 deg / 4 mm):")
    print(f"  {'feature':9s} {'free':>4s} {'table':>5s} {'fixed-dir error [rad, m]':>28s} "
          f"{'Tangent/Hong-Tan rank':>22s}")
    for kind in FEATURE_TYPES:
        rng = np.random.default_rng(FEATURE_TYPES.index(kind) + 100)
        f = example_features()[kind]
        X = sample_feature(f, 200, rng)
        T = _random_pose(rng, f.planar)
        xi0 = (np.array([0, 0, 0.05, 0.004, -0.003, 0]) if f.planar
               else np.concatenate([rng.normal(0, 0.04, 3), rng.normal(0, 0.004, 3)]))
        res = algorithm2(transform_points(T, X), f, init=T @ exp_se3(xi0))
        ang, dist = f.group.distance(inv_pose(T) @ res.T_world_workpiece)
        amb = 3 if f.planar else 6
        print(f"  {kind:9s} {res.free_dofs:4d} {FEATURE_TABLE[kind].group_dim:5d} {ang:14.2e} {dist:12.2e} "
              f"{res.general_system_rank:>14d} of {amb}")


def bar_detection(trials: int):
    print(f"Automatic detection, {trials} seeded trials per feature (300 points on a mesh):")
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
            print(f"  sigma {sigma * 1e6:4.0f} um  {kind:9s} {hits}/{trials} "
                  f"({(time.perf_counter() - t0) / trials * 1e3:.0f} ms per trial)")


def bar_cube():
    import trimesh

    cube = trimesh.creation.box([0.04, 0.04, 0.04])
    print("Cube, equally good poses by measured faces:")
    for which, name in (([(0, 1), (1, 1), (2, 1)], "three faces"), ([(0, 1), (2, 1)], "two faces"),
                        ([(2, 1)], "one face")):
        rng = np.random.default_rng(5)
        T = _random_pose(rng)
        Y = transform_points(T, _cube_faces(rng, which)) + rng.normal(0, 2e-6, (100 * len(which), 3))
        res = localize_symmetric(Y, cube, init=T @ exp_se3([0.03, -0.02, 0.02, 0.002, 0.001, -0.002]))
        print(f"  {name:11s}: {len(res.solutions)} solutions, free_dofs {res.free_dofs} ({res.feature}), "
              f"status {res.status.value}")


def bar_hybrid():
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
    print(f"Hybrid on the cast_blank scan ({len(F)} finished, {len(R)} rough points; scan "
          f"{time.perf_counter() - t0:.1f} s):")
    for allowance in (0.001, 0.0025, 0.0035):
        t1 = time.perf_counter()
        res = localize_hybrid(F, R, fin, allowance, groups=groups, init=T_nom, index=fin_i)
        feet = transform_points(T_true, blank_i.query(transform_points(inv_pose(T_true), R)).foot)
        d_true, _, _ = envelope_distances(feet, res.T_world_workpiece, fin_i)
        Zd, _ = cast_blank_rough_points(20000, np.random.default_rng(9))
        d_dense, _, _ = envelope_distances(transform_points(T_true, Zd), res.T_world_workpiece, fin_i)
        print(f"  allowance {allowance * 1e3:.1f} mm: {res.status.value}, feasible={res.feasible}, measured min margin "
              f"{res.margin_m.min() * 1e3:+.6f} mm, true min margin (measured points' true surface) "
              f"{(d_true.min() - allowance) * 1e3:+.4f} mm, (visible domes, 20000 samples) "
              f"{(d_dense.min() - allowance) * 1e3:+.4f} mm, best achievable {res.best_min_margin_m * 1e3:+.4f} mm, "
              f"min stock per group {', '.join(f'{k} {v * 1e3:.4f}' for k, v in res.min_allowance_m.items())} mm, "
              f"limiting points {res.limiting_points.tolist()}, free_dofs {res.free_dofs}, "
              f"{res.lp_solves} LPs, {time.perf_counter() - t1:.2f} s")


SECTIONS = ("algorithm2", "detection", "cube", "hybrid")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=50)
    ap.add_argument("--sections", nargs="+", choices=SECTIONS, default=list(SECTIONS))
    args = ap.parse_args(argv)
    if "algorithm2" in args.sections:
        bar_algorithm2()
    if "detection" in args.sections:
        bar_detection(args.trials)
    if "cube" in args.sections:
        bar_cube()
    if "hybrid" in args.sections:
        bar_hybrid()


if __name__ == "__main__":
    main()

"""Speed and accuracy of the localization inner loop and of localization itself.

Run as a module from the repository root:

    python -m benchmarks.bench_closest_point                 # every section
    python -m benchmarks.bench_closest_point --section closest
    python -m benchmarks.bench_closest_point --section localize --repeats 30
    python -m benchmarks.bench_closest_point --section crlb --trials 100
    python -m benchmarks.bench_closest_point --section basin --trials 100   # 20 starts per part
    python -m benchmarks.bench_closest_point --section basin --trials 5 --parts hemisphere_punch  # smoke

Sections:
  closest   MeshIndex.query (numba and numpy backends) against trimesh.proximity.closest_point
            on the documents' workpieces (metres): time per query of points 0.05 mm off the
            surface, in Z-order as localize() passes them (numba also with hints, as in
            localize()'s iterations), and the largest error on points sampled ON the mesh
            (exact answer: distance 0).
  localize  wall time of localize() (hong_tan and every other method) for 150, 1,000 and
            20,000 points, from a start 0.5 degree / 1 mm off, with noise 0.05 mm.
  crlb      RMS pose error over trials in units of the Cramer-Rao bound, whitened
            (sqrt(mean xi^T C^-1 xi / 6): 1.0 attains the bound) and per component, for
            sigma 0.05 mm and 0.005 mm at 150, 1,000 and 20,000 points.
  basin     success rate of each method from random starts up to 45 degrees (about the
            part) and 20 % of the part size, 150 noise-free points; a start that is not
            recovered is counted by its verdict (with sigma = 1 um stated: poor_fit or
            not_converged; never ok). Figures: benchmarks/results_closest_point.md.

Timings are medians over repeats after a warm-up call (numba compiles on first use); they
depend on the machine and its load: the project's machines have 2 cores.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from algorithms.geometry.bvh_kernels import HAVE_NUMBA
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import make_pose, transform_points
from algorithms.registration import Status
from algorithms.registration.local import METHODS, _morton_order, localize
from algorithms.registration.uncertainty import crlb, pose_error_twist, whitened_error
from tests.helpers import pose_errors, random_pose, sample_surface
from twin.parts import make_workpiece

PARTS = ("s_surface", "hemisphere_punch", "bottle_punch")
#: The noise sigma stated with the exact points of the basin section (a sensor's floor).
BASIN_SIGMA_M = 1e-6


def median_time(fn, repeats):
    fn()
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts))


def section_closest(parts, repeats):
    print("\n== closest points: time per query [ms], largest distance of on-mesh points [m] ==")
    print(f"{'part':18s} {'faces':>6s} {'N':>6s} {'numba':>9s} {'+hint':>9s} {'numpy':>9s} {'trimesh':>9s}"
          f" {'err ours':>9s} {'err trimesh':>11s}")
    rng = np.random.default_rng(0)
    for name in parts:
        mesh = make_workpiece(name)
        backends = {"numpy": MeshIndex(mesh, backend="numpy")}
        if HAVE_NUMBA:
            backends["numba"] = MeshIndex(mesh, backend="numba")
        for n in (150, 1000, 20000):
            on, _ = sample_surface(mesh, n, rng)
            on = on[_morton_order(on)]  # spatially coherent order, as localize() uses
            pts = on + rng.normal(size=on.shape) * 5e-5  # a scan: 0.05 mm off the surface
            row = {}
            for b, idx in backends.items():
                row[b] = median_time(lambda idx=idx, pts=pts: idx.query(pts),
                                     repeats if n < 20000 else max(3, repeats // 5))
            row["hint"] = float("nan")
            if HAVE_NUMBA:
                # as in localize() iterations: last iteration's faces as hints
                hint = backends["numba"].query(pts + 2e-5).face
                row["hint"] = median_time(lambda nb=backends["numba"], pts=pts, hint=hint: nb.query(pts, hint=hint),
                                          repeats if n < 20000 else max(3, repeats // 5))
            tm_reps = 1 if n >= 20000 else 3
            row["trimesh"] = median_time(lambda mesh=mesh, pts=pts: trimesh.proximity.closest_point(mesh, pts),
                                         tm_reps)
            ours = max(b.query(on).distance.max() for b in backends.values())
            _, d_tm, _ = trimesh.proximity.closest_point(mesh, on)
            print(f"{name:18s} {len(mesh.faces):6d} {n:6d} "
                  f"{row.get('numba', float('nan')) * 1e3:9.3f} {row['hint'] * 1e3:9.3f} {row['numpy'] * 1e3:9.3f} "
                  f"{row['trimesh'] * 1e3:9.1f} {ours:9.1e} {d_tm.max():11.1e}")


def _noisy_scan(mesh, n, sigma, rng, T_true):
    X, f = sample_surface(mesh, n, rng)
    nrm = mesh.face_normals[f]
    return X, nrm


def section_localize(parts, repeats):
    print("\n== localize(): median wall time [ms], start 0.5 deg / 1 mm off, noise 0.05 mm ==")
    rng = np.random.default_rng(1)
    for name in parts:
        mesh = make_workpiece(name)
        idx = MeshIndex(mesh)
        for n in (150, 1000, 20000):
            X, f = sample_surface(mesh, n, rng)
            nrm = mesh.face_normals[f]
            T_true = random_pose(rng, X.mean(axis=0), float(mesh.extents.max()), max_deg=30)
            Y = transform_points(T_true, X + nrm * rng.normal(size=(n, 1)) * 5e-5)
            T0 = T_true @ make_pose(Rotation.from_rotvec(rng.normal(size=3) * np.radians(0.5) / np.sqrt(3)).as_matrix(),
                                    rng.normal(size=3) * 1e-3 / np.sqrt(3))
            cells = []
            for method in METHODS:
                if method in ("icp", "va", "fine_001") and n == 20000:
                    continue
                reps = repeats if method in ("hong_tan", "tangent", "menq") else 3
                res = localize(Y, index=idx, init=T0, method=method)
                t = median_time(lambda Y=Y, idx=idx, T0=T0, method=method: localize(Y, index=idx, init=T0,
                                                                                     method=method), reps)
                cells.append(f"{method} {t * 1e3:.1f} ({res.iterations} it)")
            print(f"{name:18s} N={n:6d}: " + ", ".join(cells))


def section_crlb(parts, trials):
    print("\n== accuracy vs Cramer-Rao bound (hong_tan): RMS error / bound, whitened and per component ==")
    rng = np.random.default_rng(2)
    for name in parts:
        mesh = make_workpiece(name)
        idx = MeshIndex(mesh)
        for n in (150, 1000, 20000):
            X, f = sample_surface(mesh, n, rng)
            nrm = mesh.face_normals[f]
            T_true = random_pose(rng, X.mean(axis=0), float(mesh.extents.max()), max_deg=30)
            for sigma in (5e-5, 5e-6):
                C = crlb(X, nrm, sigma)
                errs, times = [], []
                k = trials if n < 20000 else max(10, trials // 4)
                for _ in range(k):
                    Y = transform_points(T_true, X + nrm * rng.normal(size=(n, 1)) * sigma)
                    T0 = T_true @ make_pose(Rotation.from_rotvec(rng.normal(size=3) * 0.01).as_matrix(),
                                            rng.normal(size=3) * 1e-3)
                    res = localize(Y, index=idx, init=T0)
                    errs.append(pose_error_twist(res.T_world_workpiece, T_true))
                    times.append(res.time_s)
                E = np.array(errs)
                ratio = np.sqrt(whitened_error(E, C).mean() / 6.0)
                comp = np.sqrt((E**2).mean(axis=0) / np.diag(C))
                print(f"{name:18s} N={n:6d} sigma={sigma * 1e3:.3f} mm trials={k:4d}: "
                      f"whitened {ratio:.3f}, per component [{' '.join(f'{c:.2f}' for c in comp)}], "
                      f"bound 1-sigma rot {np.sqrt(np.trace(C[:3, :3])) * 1e6:.2f} urad, "
                      f"trans {np.sqrt(np.trace(C[3:, 3:])) * 1e6:.3f} um, median {np.median(times) * 1e3:.1f} ms")


def section_basin(parts, trials):
    print("\n== convergence from random starts (<= 45 deg about the part, <= 20 % size), 150 points ==")
    for name in parts:
        mesh = make_workpiece(name)
        idx = MeshIndex(mesh)
        rng = np.random.default_rng(3)
        ok = {m: 0 for m in METHODS}
        missed: dict[str, list[str]] = {m: [] for m in METHODS}
        for _ in range(trials):
            X, _ = sample_surface(mesh, 150, rng)
            T_true = random_pose(rng, X.mean(axis=0), float(mesh.extents.max()))
            Y = transform_points(T_true, X)
            for m in METHODS:
                r = localize(Y, index=idx, method=m, sigma=BASIN_SIGMA_M)
                et, er = pose_errors(r.T_world_workpiece, T_true)
                if et < 1e-6 and er < 1e-6:
                    ok[m] += 1
                else:
                    missed[m].append(r.status.value + (" (!)" if r.status is Status.OK else ""))
        print(f"{name:18s} " + ", ".join(
            f"{m} {ok[m]}/{trials}" + (f" [missed: {', '.join(missed[m])}]" if missed[m] else "") for m in METHODS))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--section", choices=["all", "closest", "localize", "crlb", "basin"], default="all")
    ap.add_argument("--parts", default=",".join(PARTS))
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--trials", type=int, default=100)
    args = ap.parse_args(argv)
    parts = args.parts.split(",")
    print(f"numba backend: {'yes' if HAVE_NUMBA else 'no (numpy only)'}; cores: {os.cpu_count()}")
    if args.section in ("all", "closest"):
        section_closest(parts, args.repeats)
    if args.section in ("all", "localize"):
        section_localize(parts, args.repeats)
    if args.section in ("all", "crlb"):
        section_crlb(parts, args.trials)
    if args.section in ("all", "basin"):
        section_basin(parts, max(1, args.trials // 5))


if __name__ == "__main__":
    main()

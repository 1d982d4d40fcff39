"""The ideas of issue 16, each measured by a paired A/B in one process (not a test).

* ``near``: the certified near-face query (``MeshIndex.query_near``) against the hinted tree
  query (``MeshIndex.query`` with the previous faces as hints), for 1,000 points sampled on the
  benchmark parts (20 um noise) after a rigid motion of the given size; microseconds a point,
  and how many points had to search the tree again;
* ``step``: a whole ``localize`` call with the compiled parts of the iteration (the normal
  equations, the 6x6 minimum-norm solve and the plain Hong-Tan iterations) against the numpy
  path, 5 deg / 10 mm starts, CPU time of the calling thread, median of the paired ratios;
* ``far``: a whole ``localize`` call with the far points' closest points looked up to within
  ``local.FAR_REL_ERROR`` of their distance (the default) against exact look-ups throughout
  (``FAR_REL_ERROR = 0``), the same starts, timing and ratio; and the largest difference of the
  two results in units of the pose's standard deviation;
* ``stop``: a whole ``localize`` call with Hong-Tan's ``local.STOP_SIGMAS`` rule (stop before
  an update that would move the pose by less than 0.01 of its standard deviation, the default)
  against the relative-decrease rule alone (``STOP_SIGMAS = 0``), the same starts, timing,
  ratio and difference; both tables also give the mean iterations (A / B);
* ``order``: a whole ``localize`` call at 150 points (no subset stage, where the Morton order is
  not used) against the same call with the points put in Morton order first (what the code
  did below 500 points before), the same starts, timing and ratio.

Run from the repository root: ``python -m benchmarks.bench_speed_ideas`` (prints markdown).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import trimesh

import algorithms.registration.local as local
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import exp_se3
from algorithms.registration import localize
from algorithms.registration.uncertainty import pose_error_twist, whitened_error
from benchmarks.bench_localization import random_world_pose, sample_design, start_pose
from twin.parts import make_workpiece

PARTS = ("hemisphere_punch", "s_surface")


def near_vs_tree(rows, reps=7):
    for name in PARTS:
        mesh = make_workpiece(name)
        index = MeshIndex(mesh)
        p0, _ = trimesh.sample.sample_surface(mesh, 1000, seed=1)
        p0 = p0[local._morton_order(p0)] + np.random.default_rng(0).normal(0, 20e-6, p0.shape)
        c = p0.mean(axis=0)
        rng = np.random.default_rng(1)
        for step_m in (1e-3, 3e-4, 1e-4, 3e-5, 1e-5):
            tn, tt, rebuilt = [], [], []
            for _ in range(reps):
                xi = rng.normal(0, step_m, 6)
                xi[:3] /= 0.05  # rotations of about step_m at 50 mm
                T = exp_se3(xi)
                p = (p0 - c) @ T[:3, :3].T + T[:3, 3] + c
                cp0, near = index.query_near(p0)
                t0 = time.thread_time()
                cp, near = index.query_near(p, near)
                t1 = time.thread_time()
                index.query(p, hint=cp0.face)
                t2 = time.thread_time()
                tn.append(t1 - t0)
                tt.append(t2 - t1)
                rebuilt.append(near.n_rebuilt)
            rows.append(f"| {name} | {step_m * 1e3:g} | {np.median(tn) * 1e3:.2f} | {np.median(tt) * 1e3:.2f} | "
                        f"{np.median(rebuilt):.0f} |")


def _starts(index, mesh, name, n, trials, sigma):
    feet, _ = sample_design(mesh, index, name, n, 2024)
    c_model = mesh.center_mass if mesh.is_watertight else mesh.centroid
    rng = np.random.default_rng(7)
    cases = []
    for _ in range(trials):
        T_true = random_world_pose(rng)
        T0 = start_pose(T_true, c_model, 5.0, rng)
        cases.append((feet @ T_true[:3, :3].T + T_true[:3, 3] + rng.normal(0.0, sigma, feet.shape), T0))
    return cases


def compiled_vs_numpy(rows, trials=16):
    kernels = (local._nb_plane_system, local._nb_solve, local._nb_run)
    for name in PARTS:
        mesh = make_workpiece(name)
        index = MeshIndex(mesh)
        for n in (150, 1000):
            cases = _starts(index, mesh, name, n, trials, 5e-6)
            localize(cases[0][0], index=index, init=cases[0][1], sigma=5e-6)
            ta, tb = [], []
            for y, T0 in cases:
                local._nb_plane_system, local._nb_solve, local._nb_run = None, None, None
                t0 = time.thread_time()
                localize(y, index=index, init=T0, sigma=5e-6)
                t1 = time.thread_time()
                local._nb_plane_system, local._nb_solve, local._nb_run = kernels
                localize(y, index=index, init=T0, sigma=5e-6)
                t2 = time.thread_time()
                ta.append(t1 - t0)
                tb.append(t2 - t1)
            ratio = float(np.median(np.array(tb) / np.array(ta)))
            rows.append(f"| {name} | {n} | {np.median(ta) * 1e3:.2f} | {np.median(tb) * 1e3:.2f} | {ratio:.2f} |")


def _setting_ab(rows, attr, off, trials=20, sigma=50e-6):
    """A whole ``localize`` call with ``local.<attr>`` set to ``off`` (A) against its default
    (B), paired: times, their ratio, the largest difference of the two results in pose standard
    deviations, and the mean iterations of each."""
    default = getattr(local, attr)
    for name in PARTS:
        mesh = make_workpiece(name)
        index = MeshIndex(mesh)
        for n in (150, 1000):
            cases = _starts(index, mesh, name, n, trials, sigma)
            localize(cases[0][0], index=index, init=cases[0][1], sigma=sigma)
            ta, tb, diff, it_a, it_b = [], [], [], [], []
            try:
                for y, T0 in cases:
                    setattr(local, attr, off)
                    t0 = time.thread_time()
                    a = localize(y, index=index, init=T0, sigma=sigma)
                    t1 = time.thread_time()
                    setattr(local, attr, default)
                    b = localize(y, index=index, init=T0, sigma=sigma)
                    t2 = time.thread_time()
                    ta.append(t1 - t0)
                    tb.append(t2 - t1)
                    it_a.append(a.iterations)
                    it_b.append(b.iterations)
                    xi = pose_error_twist(b.T_world_workpiece, a.T_world_workpiece)
                    diff.append(float(np.sqrt(whitened_error(xi, a.covariance)[0])))
            finally:
                setattr(local, attr, default)
            ratio = float(np.median(np.array(tb) / np.array(ta)))
            rows.append(f"| {name} | {n} | {np.median(ta) * 1e3:.2f} | {np.median(tb) * 1e3:.2f} | {ratio:.2f} | "
                        f"{max(diff):.3f} | {np.mean(it_a):.2f} / {np.mean(it_b):.2f} |")


def morton_vs_none(rows, trials=20, sigma=50e-6):
    for name in PARTS:
        mesh = make_workpiece(name)
        index = MeshIndex(mesh)
        cases = _starts(index, mesh, name, 150, trials, sigma)
        localize(cases[0][0], index=index, init=cases[0][1], sigma=sigma)
        ta, tb = [], []
        for y, T0 in cases:
            t0 = time.thread_time()
            localize(y[local._morton_order(y)], index=index, init=T0, sigma=sigma)
            t1 = time.thread_time()
            localize(y, index=index, init=T0, sigma=sigma)
            t2 = time.thread_time()
            ta.append(t1 - t0)
            tb.append(t2 - t1)
        ratio = float(np.median(np.array(tb) / np.array(ta)))
        rows.append(f"| {name} | 150 | {np.median(ta) * 1e3:.2f} | {np.median(tb) * 1e3:.2f} | {ratio:.2f} |")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sections", nargs="+", default=["near", "step", "far", "stop", "order"],
                    choices=["near", "step", "far", "stop", "order"])
    args = ap.parse_args(argv)
    if "near" in args.sections:
        rows = ["| part | motion [mm] | near-face query [ms / 1000 points] | hinted tree query [ms] | "
                "points searched again |", "|---|---|---|---|---|"]
        near_vs_tree(rows)
        print("\n".join(rows) + "\n")
    if "step" in args.sections and local._nb_plane_system is not None:
        rows = ["| part | N | numpy update [ms / call] | compiled update [ms / call] | paired ratio |",
                "|---|---|---|---|---|"]
        compiled_vs_numpy(rows)
        print("\n".join(rows) + "\n")
    settings = {"far": ("FAR_REL_ERROR", "exact look-ups", "far ones within FAR_REL_ERROR"),
                "stop": ("STOP_SIGMAS", "relative decrease rule only", "and STOP_SIGMAS")}
    for section, (attr, off_label, default_label) in settings.items():
        if section in args.sections:
            rows = [f"| part | N | {off_label} [ms / call] | {default_label} [ms / call] | paired ratio | "
                    "largest difference [pose standard deviations] | iterations |", "|---|---|---|---|---|---|---|"]
            _setting_ab(rows, attr, 0.0)
            print("\n".join(rows) + "\n")
    if "order" in args.sections:
        rows = ["| part | N | Morton order first [ms / call] | as given [ms / call] | paired ratio |",
                "|---|---|---|---|---|"]
        morton_vs_none(rows)
        print("\n".join(rows))


if __name__ == "__main__":
    main()

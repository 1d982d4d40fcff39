"""Localization benchmark: this library against Open3D and small_gicp on the same problems.

Not a test: a script that measures and writes a table. Run as a module from the repository
root:

    python -m benchmarks.bench_localization                 # full run (about 10-20 minutes)
    python -m benchmarks.bench_localization --trials 3      # quicker, noisier numbers
    python -m benchmarks.bench_localization --problems s_surface --sizes 150 --sigmas-mm 0.05 \
        --trials 1 --far-trials 1 --no-global --out /tmp/smoke.md   # a smoke run

Problems (document 000's workpiece A and document 004's S-surface part, from
``twin.parts``):

* ``hemisphere_punch``: points on the hemisphere and two adjacent side faces of the plate
  (document 000, section 9.2);
* ``s_surface``: points on the S-shaped top surface (what the robot's laser scans).

For each problem, noise sigma in {0.05 mm, 0.005 mm} (isotropic Gaussian added to points
sampled exactly on the mesh), N in {150, 1000, 20000} points (one fixed point set per (problem,
N), fresh noise per trial: the Cramer-Rao bound is for that design).

Local methods start from the true pose disturbed by a rotation about the model centroid (5,
90 or 180 degrees about a random axis) and a 10 mm translation in a random direction. Global
methods get no start; the true orientation is random per trial.

Methods:

* ours, local: ``algorithms.registration.local.localize(method="hong_tan")`` with a prebuilt index.
* ours, global: ``algorithms.registration.global_search.global_localize`` with ``"multistart"``,
  ``"genetic"``, ``"pso"`` (noise sigma given).
* Open3D point-to-plane ICP (``registration_icp``) against a dense sample of the CAD model
  (0.5 mm spacing, exact face normals); Open3D builds the target's KD-tree inside every call,
  which is counted in its time (the build alone is reported below the table).
* small_gicp ``PLANE_ICP`` and ``GICP`` against the same dense sample, target preprocessed once
  (normals, covariances, KD-tree); the source's covariances (GICP) are estimated per call.
* Open3D FPFH + RANSAC (global; the Open3D tutorial pipeline: voxel downsampling, normals,
  FPFH, RANSAC with mutual filter, edge-length and distance checkers) refined by its
  point-to-plane ICP.

Peers run with tight convergence settings (1e-12 relative changes, 100 iterations) so that
their accuracy is not limited by early stops; their correspondence distance is 3x the start's
translation error for local methods.

Reported per (problem, sigma, N, start, method): success rate (rotation error < 0.5 degree and
translation error < 0.5 mm: the right basin), RMS pose error relative to the Cramer-Rao bound
over the successes (``sqrt(mean(xi^T C^-1 xi) / 6)``, 1.00 = attains the bound; C from
``algorithms.registration.uncertainty.crlb`` at the true pose with smooth normals), and the median time per
call. Targets: ours within 1.1x of the bound; local method under 2 / 8 / 40 ms for 150 /
1,000 / 20,000 points and faster than small_gicp GICP at 1,000 and 20,000 points, within 1.5x
at 150 (issue 16); global success 100 % in under 100 ms for 1,000 points.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import inv_pose
from algorithms.registration import global_localize, localize
from algorithms.registration.uncertainty import crlb, observability, pose_error_twist, whitened_error
from tests.helpers import ROOT, pose_errors
from twin.parts import make_workpiece

try:
    import open3d as o3d

    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
except Exception:  # pragma: no cover - optional peer
    o3d = None
try:
    import small_gicp
except Exception:  # pragma: no cover - optional peer
    small_gicp = None

SUCCESS_ROT_RAD = math.radians(0.5)
SUCCESS_TRANS_M = 0.5e-3
START_TRANS_M = 0.010
TARGET_SPACING_M = 0.0005
PROBLEMS = ("hemisphere_punch", "s_surface")
SIGMAS_M = (50e-6, 5e-6)
SIZES = (150, 1000, 20000)
STARTS_DEG = (5.0, 90.0, 180.0)


# ------------------------------------------------------------------ problems
def _selector(name):
    if name == "hemisphere_punch":
        # the part's defaults: plate 120 x 100 x 20 mm, hemisphere R 35 mm at (10, 0, 20) mm
        def sel(p, n):
            on_hemi = (p[:, 2] > 0.0201) & (np.linalg.norm(p[:, :2] - [0.01, 0.0], axis=1) < 0.0351)
            sides = (n[:, 0] > 0.99) | (n[:, 1] < -0.99)  # two adjacent side faces (+x, -y)
            return on_hemi | sides

        return sel

    def sel(p, n):  # the S-shaped top (its normals point up; the bottom is at z = 0)
        return (n[:, 2] > 0.05) & (p[:, 2] > 1e-3)

    return sel


def sample_design(mesh, index, name, n, seed):
    """n model points on the scanned surfaces, their smooth normals (workpiece frame)."""
    sel = _selector(name)
    pts, fi = trimesh.sample.sample_surface(mesh, max(40 * n, 20000), seed=seed)
    keep = sel(pts, mesh.face_normals[fi])
    pts = pts[keep]
    rng = np.random.default_rng(seed)
    pts = pts[rng.choice(len(pts), n, replace=False)]
    cp = index.query(pts)
    normals = index.smooth_normals(cp.face, cp.foot)
    return cp.foot, normals


def dense_target(mesh, spacing=TARGET_SPACING_M):
    n = int(min(400_000, mesh.area / spacing**2))
    pts, fi = trimesh.sample.sample_surface_even(mesh, n, seed=0)
    return pts, np.asarray(mesh.face_normals)[fi]


def random_world_pose(rng):
    """A uniformly random orientation somewhere in the cell (not a small motion)."""
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()
    T[:3, 3] = rng.uniform(-0.3, 0.3, 3) + [0.5, 0.0, 0.2]
    return T


def start_pose(T_true, c_model, angle_deg, rng):
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    R = Rotation.from_rotvec(axis * math.radians(angle_deg)).as_matrix()
    D = np.eye(4)
    D[:3, :3] = R
    D[:3, 3] = c_model - R @ c_model  # rotation about the model centroid
    T = T_true @ D
    d = rng.normal(size=3)
    T[:3, 3] += START_TRANS_M * d / np.linalg.norm(d)
    return T


# ------------------------------------------------------------------ peers
class Peers:
    def __init__(self, target_pts, target_normals):
        self.target_pts = target_pts
        self.available = []
        if o3d is not None:
            self.o3d_target = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(target_pts))
            self.o3d_target.normals = o3d.utility.Vector3dVector(target_normals)
            self.available += ["open3d_icp_plane", "open3d_fpfh_ransac"]
            self._fpfh_cache = {}
        if small_gicp is not None:
            self.sg_target = small_gicp.PointCloud(target_pts)
            self.sg_tree = small_gicp.KdTree(self.sg_target)
            small_gicp.estimate_normals_covariances(self.sg_target, self.sg_tree, num_neighbors=20)
            self.available += ["small_gicp_plane", "small_gicp_gicp"]

    def o3d_icp(self, y, T_init_world_workpiece, max_corr):
        src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(y))
        res = o3d.pipelines.registration.registration_icp(
            src,
            self.o3d_target,
            max_corr,
            inv_pose(T_init_world_workpiece),
            o3d.pipelines.registration.TransformationEstimationPointToPlane(),
            o3d.pipelines.registration.ICPConvergenceCriteria(1e-12, 1e-12, 100),
        )
        return inv_pose(np.asarray(res.transformation))

    def small_gicp(self, y, T_init, max_corr, kind):
        src = small_gicp.PointCloud(y)
        if kind == "GICP":
            small_gicp.estimate_covariances(src, num_neighbors=min(20, len(y) - 1))
        res = small_gicp.align(
            self.sg_target,
            src,
            self.sg_tree,
            init_T_target_source=inv_pose(T_init),
            registration_type=kind,
            max_correspondence_distance=max_corr,
            max_iterations=100,
            rotation_epsilon=1e-12,
            translation_epsilon=1e-12,
        )
        return inv_pose(np.asarray(res.T_target_source))

    def _target_fpfh(self, voxel):
        if voxel not in self._fpfh_cache:
            down = self.o3d_target.voxel_down_sample(voxel)
            down.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
            f = o3d.pipelines.registration.compute_fpfh_feature(
                down, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100)
            )
            self._fpfh_cache[voxel] = (down, f)
        return self._fpfh_cache[voxel]

    def fpfh_ransac(self, y, voxel, rng_seed):
        reg = o3d.pipelines.registration
        o3d.utility.random.seed(int(rng_seed))
        tgt, tgt_f = self._target_fpfh(voxel)
        src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(y))
        src = src.voxel_down_sample(voxel)
        src.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
        src_f = reg.compute_fpfh_feature(src, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100))
        dist = 1.5 * voxel
        res = reg.registration_ransac_based_on_feature_matching(
            src,
            tgt,
            src_f,
            tgt_f,
            True,
            dist,
            reg.TransformationEstimationPointToPoint(False),
            3,
            [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(dist)],
            reg.RANSACConvergenceCriteria(100000, 0.999),
        )
        T = inv_pose(np.asarray(res.transformation))
        return self.o3d_icp(y, T, dist)


# ------------------------------------------------------------------ one configuration
def run_config(name, mesh, index, peers, sigma, n, trials, seed, methods_local, methods_global, log, far_trials=4,
               starts=STARTS_DEG):
    feet, normals = sample_design(mesh, index, name, n, seed)
    C = crlb(feet, normals, sigma)
    obs = observability(feet, normals)
    c_model = mesh.center_mass if mesh.is_watertight else mesh.centroid
    rows = []
    rng = np.random.default_rng(seed + 1)
    spacing = math.sqrt(mesh.area / max(n, 1))

    def record(method, start, errs, times, extra="", cpu=None):
        ok = [e for e in errs if e is not None and e[0] < SUCCESS_ROT_RAD and e[1] < SUCCESS_TRANS_M]
        succ = len(ok) / len(errs)
        ratio = float(np.sqrt(np.mean(whitened_error(np.array([e[2] for e in ok]), C)) / 6.0)) if ok else float("nan")
        rows.append(
            dict(
                problem=name,
                sigma_mm=sigma * 1e3,
                n=n,
                start=start,
                method=method,
                success=succ,
                crlb_ratio=ratio,
                time_ms=float(np.median(times)) * 1e3 if times else float("nan"),
                time_min_ms=float(np.min(times)) * 1e3 if times else float("nan"),
                cpu_ms=float(np.median(cpu)) * 1e3 if cpu else float("nan"),
                note=extra,
            )
        )
        log(f"  {name:17s} s={sigma * 1e3:.3f}mm N={n:6d} {start:>5s} {method:20s} "
            f"succ={succ:4.0%} rms/CRLB={ratio:6.2f} t={rows[-1]['time_ms']:8.2f} ms {extra}")

    def err(T_est, T_true):
        if T_est is None or not np.all(np.isfinite(T_est)):
            return None
        et, er = pose_errors(T_est, T_true)
        return er, et, pose_error_twist(T_est, T_true)

    # local methods from each start
    for start in starts:
        cases = []
        n_trials = trials if start <= 45 else max(1, min(trials, far_trials))
        for _ in range(n_trials):
            T_true = random_world_pose(rng)
            T0 = start_pose(T_true, c_model, start, rng)
            y = feet @ T_true[:3, :3].T + T_true[:3, 3] + rng.normal(0.0, sigma, feet.shape)
            cases.append((T_true, T0, y))
        for method in methods_local:
            errs, times, cpu = [], [], []
            for T_true, T0, y in cases:
                c0 = time.thread_time()
                t0 = time.perf_counter()
                T = _run_local(method, peers, index, y, T0, sigma, log)
                times.append(time.perf_counter() - t0)
                cpu.append(time.thread_time() - c0)
                errs.append(err(T, T_true))
            record(method, f"{start:.0f}", errs, times, cpu=cpu)

    # global methods: random true orientation, no start
    cases = []
    for _ in range(trials):
        T_true = random_world_pose(rng)
        y = feet @ T_true[:3, :3].T + T_true[:3, 3] + rng.normal(0.0, sigma, feet.shape)
        cases.append((T_true, y))
    for method in methods_global:
        errs, times, notes = [], [], []
        for k, (T_true, y) in enumerate(cases):
            t0 = time.perf_counter()
            T, note = _run_global(method, peers, index, y, sigma, spacing, n, seed + k, log)
            times.append(time.perf_counter() - t0)
            errs.append(err(T, T_true))
            notes.append(note)
        summary = ""
        if any(notes):
            vals, counts = np.unique([x for x in notes if x], return_counts=True)
            summary = "status " + ", ".join(f"{v} {c}" for v, c in zip(vals, counts, strict=True))
        record(method, "any", errs, times, summary)
    return rows, obs


def _run_local(method, peers, index, y, T0, sigma, log):
    """One local fit from ``T0``: ours or a peer's pose, None when the method raised (a failure)."""
    try:
        if method == "ours_hong_tan":
            return localize(y, index=index, method="hong_tan", init=T0, sigma=sigma).T_world_workpiece
        if method == "open3d_icp_plane":
            return peers.o3d_icp(y, T0, 3 * START_TRANS_M)
        if method == "small_gicp_plane":
            return peers.small_gicp(y, T0, 3 * START_TRANS_M, "PLANE_ICP")
        if method == "small_gicp_gicp":
            return peers.small_gicp(y, T0, 3 * START_TRANS_M, "GICP")
        raise ValueError(method)
    except Exception as exc:  # a peer failing counts as a failure
        log(f"    {method} raised {type(exc).__name__}: {exc}")
        return None


def _run_global(method, peers, index, y, sigma, spacing, n, seed, log):
    """One global search: (pose or None when the method raised, our status or "")."""
    try:
        if method.startswith("ours_"):
            r = global_localize(y, index=index, method=method[5:], noise_sigma_m=sigma,
                                rng=np.random.default_rng(seed))
            return r.T_world_workpiece, r.status.value
        if method == "open3d_fpfh_ransac":
            voxel = max(0.0025, 1.5 * spacing if n < 2000 else 0.0025)
            return peers.fpfh_ransac(y, voxel, seed), ""
        raise ValueError(method)
    except Exception as exc:
        log(f"    {method} raised {type(exc).__name__}: {exc}")
        return None, ""


PEER = "small_gicp_gicp"


def markdown(rows):
    """The table; each local row's time also as a ratio to small_gicp GICP's in the same
    (problem, sigma, N, start) of the same run (wall clock and this thread's CPU time)."""
    peer = {(r["problem"], r["sigma_mm"], r["n"], r["start"]): r for r in rows if r["method"] == PEER}
    out = [
        "| problem | sigma [mm] | N | start [deg] | method | success | RMS error / CRLB | median time [ms] "
        f"| min time [ms] | time / {PEER} (wall, CPU) | notes |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        ratio = "-" if not np.isfinite(r["crlb_ratio"]) else f"{r['crlb_ratio']:.2f}"
        p = peer.get((r["problem"], r["sigma_mm"], r["n"], r["start"]))
        vs = "-"
        if p is not None and np.isfinite(r.get("cpu_ms", np.nan)):
            vs = f"{r['time_ms'] / p['time_ms']:.2f}, {r['cpu_ms'] / p['cpu_ms']:.2f}"
        out.append(
            f"| {r['problem']} | {r['sigma_mm']:.3f} | {r['n']} | {r['start']} | {r['method']} | "
            f"{r['success']:.0%} | {ratio} | {r['time_ms']:.2f} | {r['time_min_ms']:.2f} | {vs} | {r['note']} |"
        )
    return "\n".join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--trials", type=int, default=8, help="trials per (problem, sigma, N, start, method)")
    ap.add_argument("--far-trials", type=int, default=4,
                    help="trials for the 90 and 180 degree starts of local methods")
    ap.add_argument("--seed", type=int, default=2024)
    ap.add_argument("--problems", nargs="+", default=list(PROBLEMS), choices=PROBLEMS)
    ap.add_argument("--sizes", nargs="+", type=int, default=list(SIZES))
    ap.add_argument("--sigmas-mm", nargs="+", type=float, default=[s * 1e3 for s in SIGMAS_M])
    ap.add_argument("--no-global", action="store_true", help="skip the global methods")
    ap.add_argument("--global-methods", nargs="+", default=["multistart", "genetic", "pso"],
                    choices=["multistart", "genetic", "pso"], help="our global methods to run")
    ap.add_argument("--starts", nargs="+", type=float, default=list(STARTS_DEG),
                    help="start angles [deg] of the local methods")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results_localization.md"))
    args = ap.parse_args(argv)


    def log(msg):
        print(msg, flush=True)

    all_rows = []
    notes = []
    t_all = time.perf_counter()
    load0 = os.getloadavg() if hasattr(os, "getloadavg") else None
    for name in args.problems:
        mesh = make_workpiece(name)
        t0 = time.perf_counter()
        index = MeshIndex(mesh)
        t_index = time.perf_counter() - t0
        tp, tn = dense_target(mesh)
        peers = Peers(tp, tn)
        if o3d is not None:
            t0 = time.perf_counter()
            o3d.geometry.KDTreeFlann(peers.o3d_target)
            t_kd = time.perf_counter() - t0
            notes.append(
                f"{name}: {len(mesh.faces)} faces; MeshIndex build {t_index * 1e3:.0f} ms (once); "
                f"dense target for the peers {len(tp)} points; Open3D KD-tree build on it "
                f"{t_kd * 1e3:.1f} ms (inside every Open3D ICP call)"
            )
        methods_local = ["ours_hong_tan"] + [m for m in peers.available if m != "open3d_fpfh_ransac"]
        # warm-up (compilation, caches), not recorded
        ours_global = [] if args.no_global else [f"ours_{m}" for m in args.global_methods]
        run_config(name, mesh, index, peers, 50e-6, 150, 1, args.seed + 99, methods_local,
                   ours_global, lambda m: None, far_trials=1, starts=args.starts)
        methods_global = list(ours_global)
        if "open3d_fpfh_ransac" in peers.available and not args.no_global:
            methods_global.append("open3d_fpfh_ransac")
        for sigma_mm in args.sigmas_mm:
            for n in args.sizes:
                rows, obs = run_config(
                    name, mesh, index, peers, sigma_mm * 1e-3, n, args.trials, args.seed, methods_local,
                    methods_global, log, far_trials=args.far_trials, starts=args.starts,
                )
                all_rows.extend(rows)
                if sigma_mm == args.sigmas_mm[0]:
                    notes.append(
                        f"{name}, N={n}: smallest relative information eigenvalue "
                        f"{obs.relative_eigenvalues[0]:.2e} (observable: {obs.observable})"
                    )
    total = time.perf_counter() - t_all
    load = os.getloadavg() if hasattr(os, "getloadavg") else None
    table = markdown(all_rows)
    cmd = " ".join(["python -m benchmarks.bench_localization"] + (argv if argv is not None else sys.argv[1:]))
    peers_v = []
    if o3d is not None:
        peers_v.append(f"open3d {o3d.__version__}")
    if small_gicp is not None:
        peers_v.append("small_gicp " + getattr(small_gicp, "__version__", "(version not exposed)"))
    try:
        import numba

        nb = f"numba {numba.__version__} (MeshIndex backend)"
    except Exception:
        nb = "numba not installed (numpy MeshIndex backend)"
    header = [
        "# Localization benchmark",
        "",
        f"Produced by `{cmd}` (from the repository root) in {total / 60:.1f} min on "
        f"{platform.node() or 'this machine'}: {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} CPUs, Python {platform.python_version()}, numpy {np.__version__}, "
        f"{', '.join(peers_v) or 'no peers installed'}, {nb}.",
        "",
        f"Load average (1 / 5 / 15 min) at the start {load0[0]:.1f} / {load0[1]:.1f} / {load0[2]:.1f}, "
        f"at the end {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} on {os.cpu_count()} CPUs; "
        "other processes share this machine, so times are indicative.",
        "",
        "Success: rotation error < 0.5 deg and translation error < 0.5 mm. RMS error / CRLB: "
        "`sqrt(mean(xi^T C^-1 xi) / 6)` over the successes, C the Cramer-Rao bound of that "
        "point set (1.00 attains the bound). Local methods start 5 / 90 / 180 deg and 10 mm "
        "from the truth (the 90 and 180 deg rows use `--far-trials` trials); global methods ('any') "
        "get no start. Times per call: median and minimum over the trials (the minimum is the "
        f"least disturbed by other processes); the ratio to {PEER} divides medians of the same "
        "(problem, sigma, N, start) in this run, by wall clock and by the CPU time of the calling "
        "thread (less disturbed by other processes; both are single-threaded below 4,000 points).",
        "",
        table,
        "",
        "Notes:",
        "",
    ] + [f"- {x}" for x in notes]
    text = "\n".join(header) + "\n"
    Path(args.out).write_text(text)
    print()
    print(text)
    print(f"written to {args.out}")


if __name__ == "__main__":
    main()

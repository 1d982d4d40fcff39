"""The poor-fit check without a sigma: RMS / point-to-point noise, and the outlier fraction,
for every part's points fitted to every part's model.

    python -m benchmarks.bench_fit_check [--section sampled|scans|all] [--points N]

``sampled``: each part sampled at N points (default 2,000) uniformly on the faces seen from
above, 5 um isotropic noise, fitted (hong_tan, from the model's centre moved onto the points'
centroid) to each model. ``scans``: each scenario's own simulated scan (``twin.scan.run_scan``,
every sensor and robot error of the scenario), subsampled to about 20,000 points, fitted from
the nominal pose. A cell reads ``ratio/outlier fraction``; ``algorithms.registration.fit_check``
calls a fit poor above ``POOR_FIT_WHITE_SIGMAS`` or ``MAX_OUTLIER_FRACTION``.
"""

from __future__ import annotations

import argparse
import platform

import numpy as np

from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import inv_pose, transform_points
from algorithms.registration import localize
from algorithms.registration.fit_check import MAX_OUTLIER_FRACTION, POOR_FIT_WHITE_SIGMAS, white_noise_sigma_m
from twin.parts import WORKPIECE_NAMES, make_workpiece

SCENARIO_PARTS = ("s_surface", "hemisphere_punch", "bottle_punch", "inner_sphere", "through_hole",
                  "bore_and_face", "sphere", "cube", "cast_blank")


def sample_top(mesh, n: int, rng: np.random.Generator) -> np.ndarray:
    w = mesh.area_faces * (mesh.face_normals[:, 2] > -0.3)
    f = rng.choice(len(w), size=n, p=w / w.sum())
    u = rng.uniform(size=(n, 2))
    flip = u.sum(axis=1) > 1
    u[flip] = 1 - u[flip]
    t = mesh.triangles[f]
    return t[:, 0] + u[:, :1] * (t[:, 1] - t[:, 0]) + u[:, 1:] * (t[:, 2] - t[:, 0])


def cell(points: np.ndarray, index: MeshIndex, T0: np.ndarray) -> tuple[float, float, str]:
    r = localize(points, index=index, init=T0)
    x = transform_points(inv_pose(r.T_world_workpiece), points[r.inliers])
    q = index.query(x)
    s = np.einsum("ij,ij->i", x - q.foot, q.normal)
    return r.rmse_m / white_noise_sigma_m(x, s), r.n_outliers / len(points), r.status.value


def centred(T_nominal: np.ndarray, points: np.ndarray, mesh) -> np.ndarray:
    T0 = T_nominal.copy()
    T0[:3, 3] += points.mean(axis=0) - transform_points(T_nominal, mesh.bounds.mean(axis=0)[None])[0]
    return T0


def table(rows: dict[str, dict[str, tuple[float, float, str]]], models: list[str]) -> None:
    print("| points \\ model | " + " | ".join(models) + " |")
    print("|---" * (len(models) + 1) + "|")
    for a, row in rows.items():
        print(f"| {a} | " + " | ".join(f"{row[b][0]:.1f}/{row[b][1]:.2f}" for b in models) + " |")
    own = [rows[a][a] for a in rows if a in models]
    other = [v for a in rows for b, v in rows[a].items() if b != a]
    flagged = sum(v[2] == "poor_fit" for v in other)
    print(f"\nown model: ratio {min(v[0] for v in own):.1f}-{max(v[0] for v in own):.1f}, outlier fraction "
          f"<= {max(v[1] for v in own):.2f}, statuses {sorted({v[2] for v in own})}; another model: "
          f"{flagged} of {len(other)} fits poor_fit (ratio above {POOR_FIT_WHITE_SIGMAS:g} or outlier "
          f"fraction above {MAX_OUTLIER_FRACTION:g})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--section", choices=("sampled", "scans", "all"), default="all")
    ap.add_argument("--points", type=int, default=2000)
    args = ap.parse_args()
    print(f"machine: {platform.processor() or platform.machine()}, python {platform.python_version()}")
    meshes = {n: make_workpiece(n) for n in WORKPIECE_NAMES}
    index = {n: MeshIndex(m) for n, m in meshes.items()}
    if args.section in ("sampled", "all"):
        print(f"\n## sampled: {args.points} points, 5 um noise\n")
        rng = np.random.default_rng(1)
        rows = {}
        for a in WORKPIECE_NAMES:
            pts = sample_top(meshes[a], args.points, rng) + rng.normal(0, 5e-6, (args.points, 3))
            rows[a] = {b: cell(pts, index[b], centred(np.eye(4), pts, meshes[b])) for b in WORKPIECE_NAMES}
        table(rows, list(WORKPIECE_NAMES))
    if args.section in ("scans", "all"):
        from twin.cell import build_cell
        from twin.realize import realize
        from twin.robot import MODELS_DIR
        from twin.scan import run_scan
        from twin.scenario import load_scenario

        print("\n## scans: each scenario's simulated scan, about 20,000 points\n")
        rows = {}
        for a in SCENARIO_PARTS:
            realized = realize(load_scenario(MODELS_DIR.parent / "scenarios" / f"{a}.toml"))
            scan = run_scan(realized, build_cell(realized, "nominal"), build_cell(realized, "true"))
            pts = scan.line_points_base
            pts = pts[:: max(1, len(pts) // 20000)]
            Tn = realized.T_base_workpiece_nominal
            rows[a] = {b: cell(pts, index[b], Tn if b == a else centred(Tn, pts, meshes[b])) for b in SCENARIO_PARTS}
        table(rows, list(SCENARIO_PARTS))


if __name__ == "__main__":
    main()

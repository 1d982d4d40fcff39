"""``twin localize --model MESH --points PLY [...] --json``: find the workpiece's pose.

Frames: the points are in the world (robot base) frame, the mesh in the workpiece (CAD)
frame; the printed ``T_world_workpiece`` maps workpiece coordinates to world coordinates
(``points ~= T_world_workpiece @ model_points``). Mesh and points are read in the same units
(``--units``, metres by default); everything printed is in metres and radians.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from algorithms.registration.symmetric.features import FEATURE_TYPES
from algorithms.registration.local import DEFAULT_METHOD, METHODS, localize
from algorithms.geometry.se3 import as_pose
from twin.errors import TwinError

UNIT_SCALE = {"m": 1.0, "mm": 1e-3}


def add_parser(sub) -> None:
    p = sub.add_parser(
        "localize",
        help="find T_world_workpiece from measured points and the CAD mesh",
        description=(
            "Localize a workpiece: fit its CAD mesh (workpiece frame) to measured points "
            "(world/robot base frame) with Algorithm 1 of document 000 and print the pose "
            "T_world_workpiece (maps workpiece coordinates to world), the residual, the "
            "iteration diagnostics and the estimated covariance of the pose twist "
            "[omega, v] (workpiece frame; rad^2, rad m, m^2). Output is in metres."
        ),
    )
    p.add_argument("--model", required=True, help="workpiece mesh (STL, OBJ or PLY), workpiece frame")
    p.add_argument("--points", required=True, help="measured points (PLY), world frame")
    p.add_argument("--method", default=DEFAULT_METHOD, choices=METHODS,
                   help=f"pose update of Algorithm 1 (default {DEFAULT_METHOD})")
    p.add_argument("--init", default=None,
                   help="initial pose: 'global' (multistart search) or a JSON file holding a 4x4 "
                        "list or a previous output of this command (its T_world_workpiece); "
                        "metres; default identity")
    p.add_argument("--sigma", type=float, default=None,
                   help="noise sigma along the normals, in --units (default: estimated from residuals)")
    p.add_argument("--units", choices=sorted(UNIT_SCALE), default="m",
                   help="units of the mesh and point files (default m)")
    p.add_argument("--max-iterations", type=int, default=None, help="cap on pose updates (default per method)")
    p.add_argument("--tolerance", type=float, default=None,
                   help="delta of 1 - e_k/e_(k-1) < delta (d of the step rule for fine_001)")
    p.add_argument("--outlier", default="mad",
                   help="'mad' (robust 5-sigma cut, default), 'none', or a maximum distance in --units")
    p.add_argument("--seed", type=int, default=0, help="seed of the global search (with --init global)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    # symmetric and hybrid localization (document 000, Algorithms 2 and 3)
    p.add_argument("--symmetric", default=None, metavar="auto|none|FEATURE",
                   help="symmetry of the measured features: 'none' (Algorithm 1 alone; the default "
                        "without --allowance), 'auto' (found from the points' Fisher information, then "
                        "Algorithm 2; the default with --allowance), or a feature type of document "
                        "000's table (" + ", ".join(FEATURE_TYPES) + ") fitted to the measured faces. "
                        "The JSON gains free_dofs, free_directions and solutions (every equally good "
                        "pose of a discretely symmetric part)")
    p.add_argument("--allowance", default=None, metavar="FILE",
                   help="rough-surface points for hybrid (envelopment) localization, world frame, in "
                        "--units: a CSV with a header naming x, y, z and optionally allowance (the "
                        "machining allowance of each point) and group (a label), or a PLY of points; "
                        "--points then holds the finished-surface points only")
    p.add_argument("--allowance-value", type=float, default=None, metavar="VALUE",
                   help="machining allowance in --units for rough points without an allowance column")
    p.add_argument("--stock", type=float, default=None, metavar="VALUE",
                   help="nominal stock in --units: rough points inside the finished model by more are "
                        "refused (default: the 10th percentile of the rough points' stock)")
    p.set_defaults(run=run)


def _load_mesh(path: str, units: str):
    try:
        from twin.parts import load_mesh
    except ImportError:  # pragma: no cover - the module is part of the package
        load_mesh = None
    if load_mesh is not None:
        return load_mesh(path, units)
    import trimesh  # pragma: no cover

    p = Path(path)  # pragma: no cover
    if not p.is_file():  # pragma: no cover
        raise TwinError(f"mesh file not found: {path}")
    mesh = trimesh.load(str(p), force="mesh")  # pragma: no cover
    mesh.apply_scale(UNIT_SCALE[units])  # pragma: no cover
    return mesh  # pragma: no cover


def _load_points(path: str, units: str) -> np.ndarray:
    p = Path(path)
    if not p.is_file():
        raise TwinError(f"points file not found: {path}")
    if p.suffix.lower() != ".ply":
        raise TwinError(f"points must be a PLY file, got {p.name!r}")
    from twin.io import read_points_ply

    return read_points_ply(p) * UNIT_SCALE[units]


def read_init(path: str) -> np.ndarray:
    """A 4x4 pose [m] from a JSON file: a bare nested list or an object with T_world_workpiece."""
    p = Path(path)
    if not p.is_file():
        raise TwinError(f"--init file not found: {path} (give 'global' or a JSON file)")
    try:
        data = json.loads(p.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise TwinError(f"--init file {path} is not valid JSON: {exc}") from None
    if isinstance(data, dict):
        if "T_world_workpiece" not in data:
            raise TwinError(f"--init file {path} holds an object without T_world_workpiece")
        data = data["T_world_workpiece"]
    try:
        T = np.asarray(data, dtype=np.float64)
    except (TypeError, ValueError):
        raise TwinError(f"--init file {path} must hold a 4x4 list of numbers") from None
    if T.shape != (4, 4):
        raise TwinError(f"--init file {path} must hold a 4x4 matrix, got shape {T.shape}")
    return as_pose(T, name=f"--init pose from {path}")


def _finite_or_none(x):
    if x is None:
        return None
    arr = np.asarray(x, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        return None
    return arr.tolist()


def result_to_json(res) -> dict:
    """The JSON object printed by ``twin localize --json`` (metres, radians, seconds)."""
    return {
        "T_world_workpiece": np.asarray(res.T_world_workpiece).tolist(),
        "rmse_m": float(res.rmse_m),
        "iterations": int(res.iterations),
        "converged": bool(res.converged),
        "observable": bool(res.observable),
        "status": res.status,
        "method": res.method,
        "time_s": float(res.time_s),
        "covariance": _finite_or_none(res.covariance),
        "covariance_frame": "error twist [omega, v] of T_est = T_true exp(xi), workpiece frame; rad^2, rad m, m^2",
        "sigma_m": float(res.sigma_m) if math.isfinite(res.sigma_m) else None,
        "weak_directions": np.asarray(res.weak_directions).tolist(),
        "n_points_used": int(res.n_points_used),
        "n_dropped_nonfinite": int(res.n_dropped_nonfinite),
        "n_outliers": int(res.n_outliers),
        "history_rmse_m": [float(h) for h in res.history],
    }


def run(args: argparse.Namespace) -> int:
    scale = UNIT_SCALE[args.units]
    mesh = _load_mesh(args.model, args.units)
    points = _load_points(args.points, args.units)
    if args.init is None:
        init = None
    elif args.init == "global":
        init = "global"
    else:
        init = read_init(args.init)
    sigma = None
    if args.sigma is not None:
        if not (math.isfinite(args.sigma) and args.sigma > 0):
            raise TwinError(f"--sigma must be a positive number, got {args.sigma}")
        sigma = args.sigma * scale
    outlier = args.outlier
    if outlier not in ("mad", "none"):
        try:
            outlier = float(outlier) * scale
        except ValueError:
            raise TwinError(f"--outlier must be 'mad', 'none' or a distance, got {args.outlier!r}") from None
    rng = np.random.default_rng(args.seed)
    symmetric = _symmetric_choice(args)
    if symmetric != "none" or args.allowance is not None:
        return _run_symmetric(args, mesh, points, init, rng, sigma, outlier, symmetric, scale)
    res = localize(
        points,
        mesh,
        method=args.method,
        init=init,
        rng=rng,
        sigma=sigma,
        max_iterations=args.max_iterations,
        tolerance=args.tolerance,
        outlier=outlier,
    )
    out = result_to_json(res)
    weak = _unit_twists(res.weak_directions)
    out["free_dofs"] = int(len(weak))
    out["free_directions"] = weak.tolist()
    out["solutions"] = [np.asarray(res.T_world_workpiece).tolist()]
    if args.json:
        print(json.dumps(out))
    else:
        T = np.asarray(res.T_world_workpiece)
        print(f"method {res.method}: {res.status}")
        print(f"iterations {res.iterations}, rmse {res.rmse_m * 1e6:.3f} um, "
              f"{res.n_points_used} points used, {res.n_outliers} outliers, "
              f"{res.n_dropped_nonfinite} non-finite dropped, {res.time_s * 1e3:.1f} ms")
        print("T_world_workpiece [m]:")
        for row in T:
            print("  " + " ".join(f"{v: .9f}" for v in row))
        if res.covariance is not None:
            sd = np.sqrt(np.diag(res.covariance))
            print("1-sigma (workpiece frame): rotation [urad] "
                  + " ".join(f"{v * 1e6:.3f}" for v in sd[:3])
                  + ", translation [um] " + " ".join(f"{v * 1e6:.3f}" for v in sd[3:]))
    return 0


# ------------------------------------------------------------------ symmetric and hybrid
def _symmetric_choice(args) -> str:
    choice = args.symmetric
    if choice is None:
        return "auto" if args.allowance is not None else "none"
    if choice not in ("auto", "none") and choice not in FEATURE_TYPES:
        raise TwinError(
            f"--symmetric must be auto, none or a feature type ({', '.join(FEATURE_TYPES)}); got {choice!r}"
        )
    if choice == "none" and args.allowance is not None:
        raise TwinError("--allowance needs the finished features' symmetry: use --symmetric auto or a feature type")
    return choice


def _unit_twists(W) -> np.ndarray:
    """Rows scaled to |omega| = 1 (rotations) or |v| = 1 (translations)."""
    W = np.asarray(W, dtype=np.float64).reshape(-1, 6)
    out = W.copy()
    for i, x in enumerate(W):
        nw, nv = np.linalg.norm(x[:3]), np.linalg.norm(x[3:])
        out[i] = x / (nw if nw > 1e-9 * max(nv, 1e-300) else nv)
    return out


def read_allowance(path: str, units: str, default_value: float | None):
    """Rough-surface points, allowances and groups from a CSV (header x, y, z[, allowance][, group])
    or a PLY file; returns (points (M, 3) [m], allowance (M,) [m], groups (M,))."""
    scale = UNIT_SCALE[units]
    p = Path(path)
    if not p.is_file():
        raise TwinError(f"--allowance file not found: {path}")
    if default_value is not None and not math.isfinite(default_value):
        raise TwinError(f"--allowance-value must be a finite number, got {default_value}")
    suffix = p.suffix.lower()
    if suffix == ".ply":
        from twin.io import read_points_ply

        pts = read_points_ply(p) * scale
        allowance = None
        groups = np.full(len(pts), "rough")
    elif suffix in (".csv", ".txt"):
        import csv

        try:
            with p.open(newline="") as fh:
                rows = [r for r in csv.reader(line for line in fh if line.strip() and not line.startswith("#"))]
        except (OSError, UnicodeDecodeError, csv.Error) as exc:
            raise TwinError(f"--allowance file {path} cannot be read: {exc}") from None
        if not rows:
            raise TwinError(f"--allowance file {path} is empty")
        header = [h.strip().lower() for h in rows[0]]
        missing = [c for c in ("x", "y", "z") if c not in header]
        if missing:
            raise TwinError(f"--allowance file {path}: header must name x, y, z (optionally allowance, "
                            f"group); missing {', '.join(missing)}")
        body = rows[1:]
        if not body:
            raise TwinError(f"--allowance file {path} holds no points")
        col = {h: i for i, h in enumerate(header)}

        def column(name):
            try:
                return np.array([float(r[col[name]]) for r in body])
            except (ValueError, IndexError):
                raise TwinError(f"--allowance file {path}: column {name!r} must hold a number on every row") from None

        pts = np.column_stack([column("x"), column("y"), column("z")]) * scale
        allowance = column("allowance") * scale if "allowance" in col else None
        groups = np.array([r[col["group"]].strip() if len(r) > col["group"] else "" for r in body]) \
            if "group" in col else np.full(len(pts), "rough")
    else:
        raise TwinError(f"--allowance must be a CSV or PLY file, got {p.name!r}")
    if allowance is None:
        if default_value is None:
            raise TwinError(f"give the machining allowance: an 'allowance' column in {path} or --allowance-value")
        allowance = np.full(len(pts), default_value * scale)
    elif default_value is not None:
        raise TwinError(f"{path} has an allowance column; --allowance-value would be ignored, drop it")
    return pts, allowance, groups


def _symmetric_json(sym, hybrid=None) -> dict:
    """JSON fields of a symmetric (Algorithm 2) or hybrid (Algorithm 3) result, metres."""
    res = hybrid if hybrid is not None else sym
    T = np.asarray(res.T_world_workpiece)
    cov6 = None
    if sym.free_dofs == 0 and sym.covariance_fixed is not None and hybrid is None:
        B = np.asarray(sym.fixed_directions)
        cov6 = B.T @ sym.covariance_fixed @ B  # twists xi = B^T m
    out = {
        "T_world_workpiece": T.tolist(),
        "rmse_m": float(sym.rmse_m),
        "iterations": int(sym.iterations),
        "converged": bool(sym.converged if hybrid is None else hybrid.converged),
        "observable": bool((hybrid.free_dofs if hybrid is not None else sym.free_dofs) == 0),
        "status": res.status,
        "method": "algorithm3" if hybrid is not None else ("algorithm2" if sym.algorithm == "2" else "hong_tan"),
        "time_s": float(res.time_s),
        "covariance": _finite_or_none(cov6),
        "covariance_frame": "error twist [omega, v] of T_est = T_true exp(xi), workpiece frame; rad^2, rad m, m^2",
        "sigma_m": float(sym.sigma_m) if math.isfinite(sym.sigma_m) else None,
        "weak_directions": np.asarray(sym.free_directions).tolist(),
        "n_points_used": int(sym.n_points_used),
        "n_dropped_nonfinite": int(len(sym.inliers) - sym.n_points_used - sym.n_outliers),
        "n_outliers": int(sym.n_outliers),
        "history_rmse_m": [float(h) for h in sym.history],
        "feature": sym.feature,
        "symmetry_group": sym.group.describe(),
        "detection_tol": float(sym.detection_tol),
        "relative_eigenvalues": np.asarray(sym.relative_eigenvalues).tolist(),
        "fixed_directions": np.asarray(sym.fixed_directions).tolist(),
        "covariance_fixed": _finite_or_none(sym.covariance_fixed),
        "free_dofs": int(sym.free_dofs),
        "free_directions": np.asarray(sym.free_directions).tolist(),
        "solutions": [np.asarray(S).tolist() for S in sym.solutions],
        "solution_rmse_m": [float(v) for v in sym.solution_rmse_m],
    }
    if hybrid is not None:
        out.update({
            "free_dofs": int(hybrid.free_dofs),
            "free_directions": np.asarray(hybrid.free_directions).tolist(),
            "solutions": [T.tolist()],
            "feasible": bool(hybrid.feasible),
            "min_allowance_m": {str(k): float(v) for k, v in hybrid.min_allowance_m.items()},
            "best_min_margin_m": float(hybrid.best_min_margin_m),
            "limiting_points": [int(i) for i in hybrid.limiting_points],
            "T_max_min": np.asarray(hybrid.T_max_min).tolist(),
            "envelope_rmse_m": float(hybrid.envelope_rmse_m),
            "lp_solves": int(hybrid.lp_solves),
            "symmetric_status": sym.status,
        })
    return out


def _run_symmetric(args, mesh, points, init, rng, sigma, outlier, symmetric, scale) -> int:
    from algorithms.registration.symmetric import localize_symmetric

    if args.allowance is None:
        if args.allowance_value is not None or args.stock is not None:
            raise TwinError("--allowance-value and --stock apply with --allowance only")
        sym = localize_symmetric(points, mesh, symmetric=symmetric, init=init, rng=rng, sigma=sigma,
                                 outlier=outlier, method=args.method)
        out = _symmetric_json(sym)
        hybrid = None
    else:
        from algorithms.registration.hybrid import localize_hybrid

        rough, allowance, groups = read_allowance(args.allowance, args.units, args.allowance_value)
        stock = None
        if args.stock is not None:
            if not (math.isfinite(args.stock) and args.stock > 0):
                raise TwinError(f"--stock must be a positive number, got {args.stock}")
            stock = args.stock * scale
        if isinstance(init, str):
            from algorithms.registration.local import localize as _loc

            init = _loc(points, mesh, init="global", rng=rng).T_world_workpiece
        hybrid = localize_hybrid(points, rough, mesh, allowance, groups=groups, symmetric=symmetric,
                                 init=init, stock_m=stock, sigma=sigma, outlier=outlier)
        sym = hybrid.symmetric
        out = _symmetric_json(sym, hybrid)
    if args.json:
        print(json.dumps(out))
        return 0
    print(f"{out['method']}: {out['status']}")
    print(f"G_0: {out['symmetry_group']}; free directions {out['free_dofs']} "
          f"(twists [omega, v], workpiece frame):")
    for w in out["free_directions"]:
        print("  " + " ".join(f"{v: .6f}" for v in w))
    print(f"rmse {sym.rmse_m * 1e6:.3f} um, {sym.n_points_used} points used, {sym.n_outliers} outliers, "
          f"{out['time_s'] * 1e3:.1f} ms")
    if hybrid is not None:
        print("smallest stock per group [mm]: "
              + ", ".join(f"{k} {v * 1e3:.4f}" for k, v in out["min_allowance_m"].items()))
    for k, S in enumerate(out["solutions"]):
        title = "T_world_workpiece [m]:" if k == 0 else f"equally good pose {k + 1} of {len(out['solutions'])} [m]:"
        print(title)
        for row in S:
            print("  " + " ".join(f"{v: .9f}" for v in row))
    return 0

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

from algorithms.localization import DEFAULT_METHOD, METHODS, localize
from algorithms.se3 import as_pose
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
    p.set_defaults(run=run)


def _load_mesh(path: str, units: str):
    try:
        from twin.workpieces import load_mesh
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

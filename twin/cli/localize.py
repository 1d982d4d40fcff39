"""``twin localize --model MESH --points PLY|--scan DIR [...] --json``: find the workpiece's pose.

Frames: the points are in the world (robot base) frame, the mesh in the workpiece (CAD)
frame; the printed ``T_world_workpiece`` maps workpiece coordinates to world coordinates
(``points ~= T_world_workpiece @ model_points``). Mesh and points are read in the same units
(``--units``, metres by default); everything printed is in metres and radians.

Uncertainty (the JSON's ``uncertainty``): from bare points the covariance is the fit's, the
residuals taken as independent white noise (``random only``). From a folder ``twin scan`` wrote
(``--scan``; its points on the scan lines, robot base frame, metres) sigma is the scan's sensor
and encoder noise (:func:`twin.scan_uncertainty.point_sigma_m`) and the covariance adds the
sensor's linearity curve as a systematic effect of unknown phase
(:func:`twin.scan_uncertainty.scan_covariance`: ``random and systematic``). Its 95 % region is
``m^T C^-1 m <= mahalanobis2_max``: from a scan, the propagated distribution's 95 % quantile
(JCGM 101 Monte Carlo, :func:`twin.scan_uncertainty.coverage_region_m2`); from bare points,
``chi2_0.95(q)``. How often it holds the true error is measured by
``benchmarks/bench_coverage.py``. Its ``note`` says what the covariance leaves out: robot-side
errors and, where the points leave directions free, the model's facets along them (the line
``not in the covariance:`` in the text output).

``--nc PROGRAM --nc-out FILE --tool-radius VALUE`` is document 003's last step: the CAM
program's cutter locations (G-code in the model's frame, a ball-end tool) moved to the found
pose (:func:`algorithms.nc.relocate_program`) and written, only when the pose is trusted; when
it is not, nothing is written and the exit status is ``EXIT_UNTRUSTED``.

From a start (``--init FILE``) the local method runs (document 000's Algorithm 1); without
``--init`` (or with ``--init global``) every orientation is searched first
(:func:`algorithms.registration.global_search.global_localize`: Algorithm 5's multistart from
p0 = mean(y), with ``--sigma`` and the outlier rule), and every equally good pose of a
symmetric part is printed. ``--symmetric`` and ``--allowance`` run Algorithms 2 and 3 from
that pose.

Exit status: 0 when the result can be trusted (status ``ok``; with ``--symmetric`` or
``--allowance`` also ``unobservable`` and ``ambiguous``, the answers symmetric handling
expects); 2 for bad input (nothing printed on stdout); ``EXIT_UNTRUSTED`` (3) when the
command finished but the result cannot be trusted as one determined pose (``not_converged``,
``poor_fit``, ``unobservable``, ``ambiguous``, ``failed``, ``infeasible``): the result is
printed all the same.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import as_pose
from algorithms.registration.local import DEFAULT_METHOD, METHODS, STOP_SIGMAS
from algorithms.registration.result import RegistrationResult, Status
from algorithms.registration.review import localize
from algorithms.registration.symmetric.groups import FEATURE_TYPES
from twin.cli import COMMANDS
from twin.cli.common import EXIT_UNTRUSTED, non_negative_int, positive_float, positive_int
from twin.errors import TwinError
from twin.formats.meshes import MeshArrays, read_mesh

if TYPE_CHECKING:
    from algorithms.registration.hybrid import HybridResult
    from algorithms.registration.symmetric import SymmetricResult

__all__ = ["EXIT_UNTRUSTED", "add_parser", "read_init", "result_to_json", "run"]
UNIT_SCALE = {"m": 1.0, "mm": 1e-3}


def add_parser(sub) -> None:
    p = sub.add_parser(
        "localize",
        help=COMMANDS["localize"],
        description=(
            "Localize a workpiece: fit its CAD mesh (workpiece frame) to measured points "
            "(world/robot base frame) with Algorithm 1 of document 000 and print the pose "
            "T_world_workpiece (maps workpiece coordinates to world), the residual, the "
            "iteration diagnostics and the estimated covariance of the pose twist "
            "[omega, v] (workpiece frame; rad^2, rad m, m^2). Output is in metres."
        ),
        epilog=(
            f"exit status: 0 a trusted result (status ok; with --symmetric or --allowance also unobservable "
            f"and ambiguous); 2 bad input; {EXIT_UNTRUSTED} finished, but the result cannot be trusted as "
            "one determined pose (not_converged, poor_fit, unobservable, ambiguous, failed, infeasible): "
            "it is printed all the same"
        ),
    )
    p.add_argument("--model", required=True,
                   help="workpiece mesh (STL, OBJ or PLY) or STEP part (its own units), workpiece frame")
    p.add_argument("--points", default=None, help="measured points (PLY), world frame")
    p.add_argument("--scan", default=None, metavar="DIR",
                   help="instead of --points: a folder written by 'twin scan' (the points on its scan lines, "
                        "robot base frame, metres; --units applies to the model only); sigma then defaults to "
                        "the scan's sensor and encoder noise, and the covariance adds the sensor's linearity "
                        "curve as a systematic effect (Type B)")
    p.add_argument("--method", default=DEFAULT_METHOD, choices=METHODS,
                   help=f"pose update of Algorithm 1 (default {DEFAULT_METHOD})")
    p.add_argument("--init", default=None,
                   help="initial pose: 'global' (the default: search every orientation with document "
                        "000's multistart from p0 = mean(points), verified) or a JSON file holding a 4x4 "
                        "list of 16 finite numbers or a previous output of this command (its "
                        "T_world_workpiece); metres")
    p.add_argument("--sigma", type=positive_float, default=None,
                   help="noise sigma along the normals, in --units (default: estimated from residuals); "
                        "a residual far above it is reported (poor_fit; failed with --init global)")
    p.add_argument("--units", choices=sorted(UNIT_SCALE), default="m",
                   help="units of the mesh and point files (default m)")
    p.add_argument("--max-iterations", type=positive_int, default=None,
                   help="cap on pose updates (default per method)")
    p.add_argument("--tolerance", type=positive_float, default=None,
                   help="delta of 1 - e_k/e_(k-1) < delta (d of the step rule for fine_001); "
                        f"hong_tan also stops before an update of less than {STOP_SIGMAS:g} standard "
                        "deviations")
    p.add_argument("--outlier", default="mad",
                   help="'mad' (robust 5-sigma cut, default), 'none', or a maximum distance in --units")
    p.add_argument("--seed", type=non_negative_int, default=0,
                   help="seed of the global search (a non-negative integer; default 0)")
    p.add_argument("--global-method", default="multistart", choices=("multistart", "genetic", "pso"),
                   help="global search without --init (default multistart)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    # symmetric and hybrid localization (document 000, Algorithms 2 and 3)
    p.add_argument("--symmetric", default=None, metavar="auto|none|FEATURE",
                   help="symmetry of the measured features: 'none' (Algorithm 1 alone; the default "
                        "without --allowance), 'auto' (found from the points' Fisher information, then "
                        "Algorithm 2; the default with --allowance), or a feature type of document "
                        "000's table (" + ", ".join(FEATURE_TYPES) + ") fitted to the measured faces. "
                        "The JSON gains the feature and its symmetry group; solutions lists every "
                        "equally good pose of a discretely symmetric part")
    p.add_argument("--allowance", default=None, metavar="FILE",
                   help="rough-surface points for hybrid (envelopment) localization, world frame, in "
                        "--units: a CSV with a header naming x, y, z and optionally allowance (the "
                        "machining allowance of each point) and group (a label), or a PLY of points; "
                        "--points then holds the finished-surface points only")
    p.add_argument("--allowance-value", type=float, default=None, metavar="VALUE",
                   help="machining allowance in --units for rough points without an allowance column")
    p.add_argument("--stock", type=positive_float, default=None, metavar="VALUE",
                   help="nominal stock in --units: rough points inside the finished model by more are "
                        "refused (default: the 10th percentile of the rough points' stock)")
    p.add_argument("--nc", default=None, metavar="PROGRAM",
                   help="a G-code CAM program written in the model's frame (3 axes, straight moves; document "
                        "003's last step): with --nc-out, its cutter locations are moved to where the part is "
                        "and the program written there, only when the result is trusted")
    p.add_argument("--nc-out", default=None, metavar="FILE", help="where the relocated program is written")
    p.add_argument("--tool-radius", type=positive_float, default=None, metavar="VALUE",
                   help="the ball-end tool's radius in --units (the program's tips are relocated about the "
                        "ball's centre)")
    p.set_defaults(run=run)


def _as_trimesh(mesh: MeshArrays):
    """The mesh as the trimesh the global search and the symmetric and hybrid fits take."""
    import trimesh

    return trimesh.Trimesh(vertices=mesh.vertices, faces=mesh.faces, process=False)


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
    rows_ok = isinstance(data, list) and len(data) == 4 and all(isinstance(r, list) and len(r) == 4 for r in data)
    if not rows_ok:
        raise TwinError(f"--init file {path} must hold a 4x4 list (4 rows of 4 numbers)")
    values = [v for r in data for v in r]
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
        raise TwinError(f"--init file {path} must hold 16 numbers (no booleans, strings or nulls)")
    T = np.asarray(values, dtype=np.float64).reshape(4, 4)
    if not np.all(np.isfinite(T)):
        raise TwinError(f"--init file {path} holds a non-finite number; 16 finite numbers are needed")
    return as_pose(T, name=f"--init pose from {path}")


def _finite_or_none(x):
    if x is None:
        return None
    arr = np.asarray(x, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        return None
    return arr.tolist()


def _instance(res: object, module: str, name: str) -> bool:
    """``isinstance(res, algorithms.registration.<module>.<name>)`` without importing the module
    (a result of a class whose module was never loaded cannot be one): a fit from a start
    does not load the global searches, the symmetric or the hybrid fits."""
    home = sys.modules.get(f"algorithms.registration.{module}")
    return home is not None and isinstance(res, getattr(home, name))


def result_to_json(res) -> dict:
    """The JSON object printed by ``twin localize --json`` (metres, radians, seconds): the
    fields every registration result has, then those of its kind (global search, symmetric,
    hybrid)."""
    out = {
        "T_world_workpiece": np.asarray(res.T_world_workpiece).tolist(),
        "status": res.status.value,
        "message": res.message,
        "trusted": bool(res.trusted),
        "rejection_review": res.rejection_review,
        "method": res.method,
        "rmse_m": float(res.rmse_m),
        "iterations": int(res.iterations),
        "converged": bool(res.converged),
        "observable": bool(res.observable),
        "time_s": float(res.time_s),
        "determined_directions": np.asarray(res.determined_directions).tolist(),
        "covariance": _finite_or_none(res.covariance),
        "covariance_frame": "coordinates m of the error twist xi = determined_directions^T m, "
                            "T_est = T_true exp(xi), [omega, v] in the workpiece frame; rad^2, rad m, m^2",
        "sigma_m": float(res.sigma_m) if math.isfinite(res.sigma_m) else None,
        "free_dofs": int(res.free_dofs),
        "free_directions": np.asarray(res.free_directions).tolist(),
        "solutions": [np.asarray(S).tolist() for S in res.solutions],
        "relative_eigenvalues": np.asarray(res.relative_eigenvalues).tolist(),
        "n_points_used": int(res.n_points_used),
        "n_dropped_nonfinite": int(res.n_dropped_nonfinite),
        "n_outliers": int(res.n_outliers),
        "history_rmse_m": [float(h) for h in res.history],
    }
    if _instance(res, "global_search", "GlobalLocalizationResult"):
        d = res.diagnostics
        out["candidates"] = [{"T_world_workpiece": np.asarray(T).tolist(), "rmse_m": float(r)}
                             for T, r in res.candidates]
        out["global"] = {
            "method": d.method,
            "n_starts": int(d.n_starts),
            "starts_accepted": int(d.starts_accepted),
            "selection": d.selection,
            "sigma_eff_m": float(d.sigma_eff_m),
            "rms_verify_m": float(d.rms_verify_m),
            "n_verify": int(d.n_verify),
            "polish": d.polish,
            "polish_status": d.polish_status.value,
        }
    hybrid = _instance(res, "hybrid", "HybridResult")
    sym = res.symmetric if hybrid else res
    if _instance(sym, "symmetric", "SymmetricResult"):
        out.update({
            "feature": sym.feature,
            "symmetry_group": sym.group.describe(),
            "detection_tol": float(sym.detection_tol),
            "solution_rmse_m": [float(v) for v in sym.solution_rmse_m] if sym is res else [float(res.rmse_m)],
        })
    if hybrid:
        out.update({
            "feasible": bool(res.feasible),
            "min_allowance_m": {str(k): float(v) for k, v in res.min_allowance_m.items()},
            "best_min_margin_m": float(res.best_min_margin_m),
            "limiting_points": [int(i) for i in res.limiting_points],
            "T_max_min": np.asarray(res.T_max_min).tolist(),
            "envelope_rmse_m": float(res.envelope_rmse_m),
            "lp_solves": int(res.lp_solves),
            "symmetric_status": res.symmetric.status.value,
            "symmetric_message": res.symmetric.message,
        })
    return out


def _exit_code(res, symmetric_asked: bool) -> int:
    """0 for a trusted result, and for the answers symmetric handling expects when it was asked for."""
    if res.trusted:
        return 0
    if symmetric_asked and res.status in (Status.UNOBSERVABLE, Status.AMBIGUOUS):
        return 0
    return EXIT_UNTRUSTED


def run(args: argparse.Namespace) -> int:
    scale = UNIT_SCALE[args.units]
    if (args.points is None) == (args.scan is None):
        raise TwinError("give the measured points: exactly one of --points PLY or --scan DIR")
    mesh = read_mesh(args.model, args.units)   # arrays: trimesh only where the method needs it
    index = MeshIndex(mesh)
    readings = None
    if args.scan is not None:
        from twin.io.scan_files import read_scan_readings

        readings = read_scan_readings(args.scan)
        points = readings.points_base
        if len(points) == 0:
            raise TwinError(f"the scan in {args.scan} has no valid point on its scan lines: nothing to localize")
    else:
        points = _load_points(args.points, args.units)
    search = args.init is None or args.init == "global"
    init = None if search else read_init(args.init)
    sigma = None if args.sigma is None else args.sigma * scale
    if sigma is None and readings is not None:
        from twin.scan_uncertainty import point_sigma_m

        sigma = point_sigma_m(readings.sensor, readings.noise, readings.q, points,
                              readings.T_base_workpiece_nominal, index)
    outlier = args.outlier
    if outlier not in ("mad", "none"):
        try:
            outlier = float(outlier) * scale
        except ValueError:
            raise TwinError(f"--outlier must be 'mad', 'none' or a distance, got {args.outlier!r}") from None
    symmetric = _symmetric_choice(args)
    program = _read_nc(args)
    found = None
    if search:
        from algorithms.registration.global_search import global_localize

        found = global_localize(points, _as_trimesh(mesh), args.global_method, rng=np.random.default_rng(args.seed),
                                noise_sigma_m=sigma, outlier=outlier, polish=args.method)
        init = found.T_world_workpiece
    symmetric_asked = symmetric != "none" or args.allowance is not None
    res: RegistrationResult
    if symmetric_asked:
        res = _symmetric_result(args, _as_trimesh(mesh), points, init, sigma, outlier, symmetric, scale)
    elif found is not None:
        res = found
    else:
        res = localize(points, method=args.method, init=init, sigma=sigma, index=index,
                       max_iterations=args.max_iterations, tolerance=args.tolerance, outlier=outlier)
    res, uncertainty = _with_uncertainty(res, readings, index, sigma, sigma_given=args.sigma is not None)
    out = result_to_json(res)
    out["uncertainty"] = uncertainty
    if program is not None:
        out["nc_program"] = _write_nc(args, program, res, scale)
    _print(res, out, args.json)
    if program is not None and not out["nc_program"]["written"]:
        return EXIT_UNTRUSTED
    return _exit_code(res, symmetric_asked)


def _read_nc(args: argparse.Namespace):
    """The CAM program of ``--nc`` read before any work (refused: exit 2), or None."""
    given = [args.nc is not None, args.nc_out is not None, args.tool_radius is not None]
    if not any(given):
        return None
    if not all(given):
        raise TwinError("--nc PROGRAM, --nc-out FILE and --tool-radius VALUE go together")
    from algorithms.nc import GCodeError, read_gcode

    try:
        text = Path(args.nc).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise TwinError(f"--nc {args.nc}: cannot read it as a UTF-8 text file ({e.__class__.__name__})") from None
    try:
        moves = read_gcode(text)
    except GCodeError as e:
        raise TwinError(f"--nc {args.nc}: {e}") from None
    if not any(m.complete for m in moves):
        raise TwinError(f"--nc {args.nc}: no move with X, Y and Z known: nothing to relocate")
    out = Path(args.nc_out)
    if not out.parent.is_dir():
        raise TwinError(f"--nc-out {args.nc_out}: its folder does not exist")
    return moves


def _write_nc(args: argparse.Namespace, moves, res: RegistrationResult, scale: float) -> dict:
    """The relocated program written to ``--nc-out`` (atomically) when the pose is trusted."""
    if not res.trusted:
        return {"written": False, "path": args.nc_out,
                "why": f"the pose is not trusted (status {res.status.value}): an NC program is written only "
                       "from a trusted pose"}
    from algorithms.nc import program_text, relocate_program

    moved = relocate_program(moves, args.tool_radius * scale * 1e3, res.T_world_workpiece)
    text = program_text(moved, title=f"{Path(args.nc).name} relocated to the localized pose")
    target = Path(args.nc_out)
    tmp = target.with_name(f".{target.name}.partial")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, target)
    return {"written": True, "path": args.nc_out, "moves": len(moved)}


def _with_uncertainty(res, readings, index: MeshIndex, sigma: float | None, sigma_given: bool):
    """The result with the covariance the input supports, and what that covariance holds.

    From a scan folder: the random sources (repeatability, quantisation, encoder noise, from
    the fit's Cramer-Rao covariance) and the sensor's linearity curve as a systematic effect
    (:func:`twin.scan_uncertainty.linearity_covariance`). From bare points: the fit's covariance,
    the residuals taken as independent white noise (a scan's systematic effects are not in it).
    A ``--sigma`` given with a scan folder is taken as the random sources' sigma.
    """
    region = {"coverage_probability": 0.95, "mahalanobis2_max": None,
              "rule": "the true error's coordinates m lie inside m^T C^-1 m <= mahalanobis2_max with this probability "
                      "(chi-square quantile, q = the determined directions)"}
    D = np.asarray(res.determined_directions, dtype=np.float64).reshape(-1, 6)
    if res.covariance is not None and len(D):
        from scipy.special import chdtri  # scipy.stats would load scipy.spatial: start-up time

        region["mahalanobis2_max"] = float(chdtri(len(D), 0.05))
    scan = None
    if readings is not None and sigma:
        from twin.scan_uncertainty import scan_covariance

        scan = scan_covariance(res, readings, index, sigma, sigma_given)
    if scan is None:
        kind = "random only" if res.covariance is not None else "none"
        words = ("the residuals taken as independent white noise: correlated errors (a sensor's linearity curve, "
                 "robot-side errors) are not in it; from a scan folder (--scan) the sensor's are")
        return res, {"kind": kind, "sources": ["white noise (fit sigma)"], "note": words + _free_facets_note(res),
                     "coverage_region": region}
    from dataclasses import replace

    region.update(mahalanobis2_max=scan.region_m2,
                  rule="the true error's coordinates m lie inside m^T C^-1 m <= mahalanobis2_max with this "
                       "probability under the propagated distribution (JCGM 101 Monte Carlo: the random part "
                       "Gaussian, the linearity curve's phase uniform)")
    out = {"kind": scan.kind, "sources": list(scan.sources), "covariance_random": scan.random.tolist(),
           "note": "robot-side systematic errors (kinematics, hand-eye, time skew) are not in it"
                   + _free_facets_note(res),
           "coverage_region": region}
    return replace(res, covariance=scan.total), out


def _free_facets_note(res) -> str:
    """What a fit with free directions leaves out of its covariance ('' when none are free)."""
    if not len(np.asarray(res.free_directions).reshape(-1, 6)):
        return ""
    return ("; nor the model's facets along the free directions: a tessellated surface is not quite invariant "
            "under the motions the points leave free, the estimate keeps the start's position along them, and "
            "where the model's facets then sit against the part's moves the determined coordinates, on a "
            "tessellated sphere or bore beyond the stated region (benchmarks/results_coverage.md)")


def _print(res, out: dict, as_json: bool) -> None:
    """One JSON object, or the result for a reader (every equally good pose included)."""
    if as_json:
        print(json.dumps(out))
        return
    words = out["status"].replace("_", " ")
    said = out["message"].startswith((out["status"], words))
    print(f"{out['method']}: {out['message']}" if said else f"{out['method']}: {out['status']}: {out['message']}")
    if "symmetry_group" in out:
        print(f"G_0: {out['symmetry_group']}")
    if out["free_dofs"]:
        print(f"free directions {out['free_dofs']} (twists [omega, v], workpiece frame):")
        for w in out["free_directions"]:
            print("  " + " ".join(f"{v: .6f}" for v in w))
    print(f"iterations {res.iterations}, rmse {res.rmse_m * 1e6:.3f} um, "
          f"{res.n_points_used} points used, {res.n_outliers} outliers, "
          f"{res.n_dropped_nonfinite} non-finite dropped, {res.time_s * 1e3:.1f} ms")
    if "nc_program" in out:
        nc = out["nc_program"]
        print(f"NC program written to {nc['path']} ({nc['moves']} moves)" if nc["written"]
              else f"NC program NOT written: {nc['why']}")
    if "min_allowance_m" in out:
        print("smallest stock per group [mm]: "
              + ", ".join(f"{k} {v * 1e3:.4f}" for k, v in out["min_allowance_m"].items()))
    C = res.covariance_twist
    if C is not None:
        sd = np.sqrt(np.clip(np.diag(C), 0.0, None))
        kind = out.get("uncertainty", {}).get("kind", "random only")
        print(f"1-sigma (workpiece frame; {kind}): rotation [urad] "
              + " ".join(f"{v * 1e6:.3f}" for v in sd[:3])
              + ", translation [um] " + " ".join(f"{v * 1e6:.3f}" for v in sd[3:]))
        if out["free_dofs"] and "uncertainty" in out:
            print(f"not in the covariance: {out['uncertainty']['note']}")
    n = len(out["solutions"])
    for k, S in enumerate(out["solutions"]):
        title = "T_world_workpiece [m]:" if k == 0 else f"equally good pose {k + 1} of {n} [m]:"
        print(title)
        for row in S:
            print("  " + " ".join(f"{v: .9f}" for v in row))


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


def _symmetric_result(args, mesh, points, init, sigma, outlier, symmetric, scale):
    from algorithms.registration.symmetric import localize_symmetric

    res: SymmetricResult | HybridResult
    if args.allowance is None:
        if args.allowance_value is not None or args.stock is not None:
            raise TwinError("--allowance-value and --stock apply with --allowance only")
        res = localize_symmetric(points, mesh, symmetric=symmetric, init=init, sigma=sigma,
                                 outlier=outlier, method=args.method)
    else:
        from algorithms.registration.hybrid import localize_hybrid

        rough, allowance, groups = read_allowance(args.allowance, args.units, args.allowance_value)
        stock = None if args.stock is None else args.stock * scale
        res = localize_hybrid(points, rough, mesh, allowance, groups=groups, symmetric=symmetric,
                              init=init, stock_m=stock, sigma=sigma, outlier=outlier)
    return res

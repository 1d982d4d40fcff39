"""Helpers shared by the tests and the benchmarks (``from tests.helpers import ...``).

Benchmarks run as modules from the repository root (``python -m benchmarks.NAME``), so
``tests`` imports as a package there too.
"""

from __future__ import annotations

import subprocess
import tomllib
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from algorithms.geometry.se3 import make_pose, rotation_error_rad, translation_error_m
from twin.scenario import load_scenario, merge_tables

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = ROOT / "scenarios"
MODELS = ROOT / "models"
merge = merge_tables


def raw_scenario(name: str) -> dict:
    return tomllib.loads((SCENARIOS / f"{name}.toml").read_text())


def scenario(name: str = "s_surface", **over):
    """Load a scenario file with nested overrides, e.g. ``scan={"max_lines": 2}``."""
    return load_scenario(SCENARIOS / f"{name}.toml", over)


def sample_surface(mesh, n: int, rng: np.random.Generator, min_nz: float = -0.3):
    """n points uniform by area on the faces seen from above (normal z > ``min_nz``): a scan.

    Returns ((n, 3) points [m] in the mesh frame, (n,) face index of each point).
    """
    w = mesh.area_faces * (mesh.face_normals[:, 2] > min_nz)
    f = rng.choice(len(w), size=n, p=w / w.sum())
    u = rng.uniform(size=(n, 2))
    flip = u.sum(axis=1) > 1
    u[flip] = 1 - u[flip]
    t = mesh.triangles[f]
    return t[:, 0] + u[:, :1] * (t[:, 1] - t[:, 0]) + u[:, 1:] * (t[:, 2] - t[:, 0]), f


def random_pose(rng: np.random.Generator, center, size: float, max_deg: float = 45.0,
                max_frac: float = 0.2) -> np.ndarray:
    """A rotation of up to ``max_deg`` about ``center`` (the part), then a translation of up to
    ``max_frac * size`` [m]: the part itself is turned and moved by those amounts."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    R = Rotation.from_rotvec(axis * np.radians(max_deg) * rng.uniform(0.3, 1.0)).as_matrix()
    t = rng.normal(size=3)
    t *= max_frac * size * rng.uniform(0.3, 1.0) / np.linalg.norm(t)
    center = np.asarray(center, dtype=np.float64)
    return make_pose(R, center - R @ center + t)


def pose_errors(T_est, T_ref) -> tuple[float, float]:
    """(translation error [m], rotation error [rad]) between two poses."""
    return translation_error_m(T_est, T_ref), rotation_error_rad(T_est, T_ref)


def assert_pose_close(T_est, T_ref, tol_m: float, tol_rad: float, what: str = "pose") -> None:
    """Fail with the translation [m] and rotation [rad] errors reported separately."""
    et, er = pose_errors(T_est, T_ref)
    assert et <= tol_m and er <= tol_rad, (
        f"{what}: translation error {et:.3e} m (tolerance {tol_m:.1e} m), "
        f"rotation error {er:.3e} rad (tolerance {tol_rad:.1e} rad)"
    )


def commit_stamp() -> str:
    """The checkout's short commit, with a note when tracked files differ from it (the stamp a
    benchmark's results file carries)."""
    rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=ROOT)
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True,
                           text=True, cwd=ROOT).stdout.strip()
    return rev.stdout.strip() + (" with uncommitted changes" if dirty else "")


def tiered(values, default, ids=str) -> list:
    """Parameters of a sweep: those whose id is in ``default`` run in the default suite, the
    others in the slow tier (``pytest -m slow``, which CI runs after the default suite)."""
    import pytest

    return [pytest.param(v, id=ids(v), marks=() if ids(v) in default else pytest.mark.slow) for v in values]


def run_cli(*args):
    """``twin ARGS`` in this process: ``twin.cli.main`` with stdout and stderr captured, as a
    ``CompletedProcess`` (``returncode``, ``stdout``, ``stderr``). What a user sees but a call
    cannot show (start-up, signals, a closed pipe, the entry point) is tested with
    :func:`run_cli_process`."""
    import contextlib
    import io
    import subprocess

    from twin.cli import main

    out, err = io.StringIO(), io.StringIO()
    argv = [str(a) for a in args]
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return subprocess.CompletedProcess(["twin", *argv], code, out.getvalue(), err.getvalue())


def run_cli_process(*args):
    """``python -m twin.cli ARGS`` in a subprocess (stdout, stderr and exit code as a user sees them)."""
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-m", "twin.cli", *map(str, args)], capture_output=True, text=True)


def with_path_keys(text: str, keys: dict) -> str:
    """The scenario text with ``keys`` set in its [path] table (added when missing)."""
    out, in_path = [], False
    for ln in text.splitlines():
        stripped = ln.strip()
        if stripped.startswith("["):
            in_path = stripped == "[path]"
        if in_path and stripped.split("=")[0].strip() in keys:
            continue
        out.append(ln)
        if stripped == "[path]":
            out += [f"{k} = {v}" for k, v in keys.items()]
    if "[path]" not in text:
        out += ["", "[path]"] + [f"{k} = {v}" for k, v in keys.items()]
    return "\n".join(out) + "\n"

"""Start-up of the command line: how long a user waits for ``twin --help`` and for a
1,000-point ``twin localize`` with a start, against the limits of issue 31 (0.5 s, 1.5 s) and
against the interpreter's own start and NumPy's import measured in the same run.

Each command runs ``--repeats`` times in a fresh process after one run that fills the caches
(numba's compiled kernels, the file system); the table gives the median and the fastest wall
time. The notes list ``python -X importtime``'s largest imports of ``twin.cli.localize`` (the
module a localize run loads) and the split of one localize run into import, reading and fit.

    python -m benchmarks.bench_startup [--repeats 7] [--out benchmarks/results_startup.md]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from algorithms.geometry.se3 import transform_points
from tests.helpers import ROOT, commit_stamp, random_pose, sample_surface
from twin.io import write_points_ply
from twin.parts import make_workpiece

LIMITS_S = {"twin --help": 0.5, "twin localize (1,000 points, --init)": 1.5}
PART = "hemisphere_punch"
N_POINTS = 1000
NOISE_M = 5e-6


def _problem(folder: Path) -> list[str]:
    """The part's mesh, 1,000 scan points moved by up to 5 deg / 5 mm, and a start (identity)."""
    mesh = make_workpiece(PART)
    rng = np.random.default_rng(31)
    X, _ = sample_surface(mesh, N_POINTS, rng)
    T = random_pose(rng, X.mean(axis=0), 0.1, max_deg=5.0, max_frac=0.05)
    write_points_ply(folder / "points.ply", transform_points(T, X) + rng.normal(0.0, NOISE_M, X.shape))
    mesh.export(folder / "part.stl")
    (folder / "init.json").write_text(json.dumps(np.eye(4).tolist()))
    return ["localize", "--model", str(folder / "part.stl"), "--points", str(folder / "points.ply"),
            "--init", str(folder / "init.json"), "--sigma", str(NOISE_M), "--json"]


def _wall_s(argv: list[str], repeats: int) -> list[float]:
    subprocess.run(argv, capture_output=True, check=True, cwd=ROOT)      # caches filled
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        subprocess.run(argv, capture_output=True, check=True, cwd=ROOT)
        times.append(time.perf_counter() - t0)
    return times


def _largest_imports(module: str, n: int = 12) -> list[tuple[str, float]]:
    """``python -X importtime -c 'import MODULE'``: the n largest imports at the top level and
    one level below (cumulative [s]; what a module imports first is counted where it is first
    imported)."""
    err = subprocess.run([sys.executable, "-X", "importtime", "-c", f"import {module}"],
                         capture_output=True, text=True, check=True, cwd=ROOT).stderr
    rows = []
    for line in err.splitlines():
        if not line.startswith("import time:") or "|" not in line:
            continue
        _, cumulative, name = line.split("|")
        depth = (len(name) - len(name.lstrip()) - 1) // 2     # two spaces a level
        if cumulative.strip().isdigit() and depth <= 1:       # the module and what it imports itself
            rows.append((name.strip(), int(cumulative) * 1e-6))
    return sorted(rows, key=lambda r: -r[1])[:n]


_STAGES = """
import sys, time, json
import numpy as np
t = [time.perf_counter()]
import numba, scipy.linalg.cython_blas  # what numba loads itself at its first compiled call
t.append(time.perf_counter())
import twin.cli.localize as cli
t.append(time.perf_counter())
mesh = cli.read_mesh(sys.argv[1], "m")
points = cli._load_points(sys.argv[2], "m")
t.append(time.perf_counter())
from algorithms.geometry.bvh_kernels import compile_kernels
compile_kernels(announce=False)
t.append(time.perf_counter())
index = cli.MeshIndex(mesh)
t.append(time.perf_counter())
cli.localize(points, index=index, init=np.eye(4), sigma=float(sys.argv[3]))
t.append(time.perf_counter())
print(json.dumps(np.diff(t).tolist()))
"""
STAGE_NAMES = ("import numba (with scipy.linalg, which numba loads at its first call)",
               "import twin.cli.localize (the rest)", "read the mesh and the points",
               "numba's first call: its registries, the kernels from its cache", "build the mesh index",
               "the fit (its first run in the process)")


def _stages_s(folder: Path, repeats: int) -> list[float]:
    """Median seconds of each stage of one localize run, in a fresh process each time."""
    runs = [json.loads(subprocess.run([sys.executable, "-c", _STAGES, str(folder / "part.stl"),
                                       str(folder / "points.ply"), str(NOISE_M)], capture_output=True, text=True,
                                      check=True, cwd=ROOT).stdout) for _ in range(repeats)]
    return [statistics.median(r[k] for r in runs) for k in range(len(STAGE_NAMES))]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results_startup.md"))
    args = ap.parse_args(argv)
    py = sys.executable
    with tempfile.TemporaryDirectory() as tmp:
        localize_args = _problem(Path(tmp))
        commands = {
            "python -c pass (the interpreter)": [py, "-c", "pass"],
            "python -c 'import numpy'": [py, "-c", "import numpy"],
            "twin --help": [py, "-m", "twin.cli", "--help"],
            "twin localize --help": [py, "-m", "twin.cli", "localize", "--help"],
            "twin localize (1,000 points, --init)": [py, "-m", "twin.cli", *localize_args],
        }
        rows = {name: _wall_s(cmd, args.repeats) for name, cmd in commands.items()}
        stages = _stages_s(Path(tmp), args.repeats)
        result = json.loads(subprocess.run(commands["twin localize (1,000 points, --init)"], capture_output=True,
                                           text=True, check=True, cwd=ROOT).stdout)
    imports = _largest_imports("twin.cli.localize")
    text = [
        "# Start-up of the command line",
        "",
        f"Command: `python -m benchmarks.bench_startup --repeats {args.repeats}`; commit {commit_stamp()}; "
        f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
        f"load average {os.getloadavg()[0]:.2f} at the end.",
        "",
        f"Each command in a fresh process, {args.repeats} times after one run that fills the caches. "
        f"The localize run fits {PART} ({N_POINTS:,} points, {NOISE_M * 1e6:g} um noise, moved up to "
        f"5 deg / 5 mm) from the identity: status {result['status']}, {result['iterations']} iterations, "
        f"fit {result['time_s'] * 1e3:.0f} ms inside the command.",
        "",
        "| command | median [s] | fastest [s] | limit [s] | median / limit |",
        "|---|---|---|---|---|",
    ]
    for name, times in rows.items():
        med = statistics.median(times)
        limit = LIMITS_S.get(name)
        tail = f"{limit:g} | {med / limit:.2f}" if limit else " | "
        text.append(f"| {name} | {med:.3f} | {min(times):.3f} | {tail} |")
    text += ["", "Where a localize run's time goes (the same problem, each stage timed in a fresh process, "
             f"median of {args.repeats}; the interpreter and NumPy as above):", "",
             "| stage | [s] |", "|---|---|"]
    text += [f"| {name} | {s:.3f} |" for name, s in zip(STAGE_NAMES, stages, strict=True)]
    text += ["", "Largest imports of `twin.cli.localize` and of the modules it imports itself "
             "(`python -X importtime -c 'import twin.cli.localize'`, cumulative, one run):", "",
             "| module | [s] |", "|---|---|"]
    text += [f"| {name} | {s:.3f} |" for name, s in imports]
    Path(args.out).write_text("\n".join(text) + "\n")
    print("\n".join(text))
    return 0


if __name__ == "__main__":
    sys.exit(main())

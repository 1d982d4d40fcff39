"""What an installation and a run take from the machine: disk and memory.

    python -m benchmarks.bench_footprint [--out benchmarks/results_footprint.md]

- the size on disk of the environment the command runs in (every installed package, the
  default install's or with extras, as found);
- the peak resident memory of ``twin localize`` on a scan, ``twin demo`` and ``twin locate``,
  each in a fresh process (``resource.getrusage`` of the child).

The getting-started page quotes these figures from the file this writes.
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import sysconfig
import tempfile
import time
from importlib import metadata
from pathlib import Path

from tests.helpers import ROOT, commit_stamp

GB = 1024**3


def _tree_bytes(path: Path) -> int:
    """Bytes of every file below ``path`` (links not followed)."""
    total = 0
    for folder, _, files in os.walk(path):
        for name in files:
            p = Path(folder) / name
            if not p.is_symlink():
                total += p.stat().st_size
    return total


def _commands(tmp: Path) -> list[tuple[str, list[str]]]:
    twin = [sys.executable, "-m", "twin"]
    mesh = tmp / "s_surface.stl"
    subprocess.run(twin + ["export-mesh", "scenarios/s_surface.toml", str(mesh)], cwd=ROOT, check=True,
                   capture_output=True)
    return [
        ("twin localize --scan (the S-surface scan, every orientation searched)",
         twin + ["localize", "--model", str(mesh), "--scan", str(tmp / "scan"), "--json"]),
        ("twin demo", twin + ["demo", "--out", str(tmp / "demo"), "--quiet"]),
        ("twin locate scenarios/locate_s_surface.toml",
         twin + ["locate", "scenarios/locate_s_surface.toml", "--out", str(tmp / "locate"), "--quiet"]),
    ]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results_footprint.md"))
    args = parser.parse_args(argv)
    purelib = Path(sysconfig.get_paths()["purelib"])
    env_gb = _tree_bytes(Path(sys.prefix)) / GB
    packages = sum(1 for _ in metadata.distributions())
    rows = []
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        # The scan of the localize row: the demo's scenario.
        subprocess.run([sys.executable, "-m", "twin", "scan", "scenarios/s_surface.toml", "--out", str(tmp / "scan"),
                        "--quiet"], cwd=ROOT, check=True, capture_output=True)
        for name, command in _commands(tmp):
            # Each command in its own interpreter, so that the children's peak is its alone.
            probe = [sys.executable, "-c",
                     "import resource, subprocess, sys; r = subprocess.run(sys.argv[1:]).returncode; "
                     "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, r)", *command]
            start = time.perf_counter()
            out = subprocess.run(probe, cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
            peak_kib, status = int(out[-2]), int(out[-1])
            rows.append((name, peak_kib * 1024 / GB, time.perf_counter() - start, status))
    lines = [
        "# Disk and memory",
        "",
        f"Command: `python -m benchmarks.bench_footprint`; commit {commit_stamp()}; {platform.machine()}, "
        f"{os.cpu_count()} cores, Python {platform.python_version()}.",
        "",
        "## The installation",
        "",
        "| what | size [GiB] |",
        "|---|---|",
        f"| the environment (`{Path(sys.prefix).name}`: {packages} installed distributions) | {env_gb:.2f} |",
        f"| of it, the installed packages (`{purelib.name}`) | {_tree_bytes(purelib) / GB:.2f} |",
        "",
        "## Peak memory of a command",
        "",
        "Each in a fresh process, its peak resident set size (`getrusage`, the command and its children).",
        "",
        "| command | peak memory [GiB] | wall time [s] | exit status |",
        "|---|---|---|---|",
    ]
    lines += [f"| {name} | {peak:.2f} | {wall:.0f} | {status} |" for name, peak, wall, status in rows]
    Path(args.out).write_text("\n".join(lines) + "\n", encoding="utf-8")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())

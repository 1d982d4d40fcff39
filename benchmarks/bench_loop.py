"""The loop on every laser scenario: ``twin run scenarios/NAME.toml`` one after another, each in
a fresh process, and its verdict and headline numbers from its ``report.json``.

    python -m benchmarks.bench_loop [--scenarios cube sphere] [--out benchmarks/results_loop.md]
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tests.helpers import ROOT, SCENARIOS, commit_stamp
from twin.scenario import load_scenario

PATHS = ("scan_path", "cad_path")


def laser_scenarios() -> list[str]:
    """The shipped scenarios ``twin run`` takes (a laser, no touch probe)."""
    return sorted(p.stem for p in SCENARIOS.glob("*.toml")
                  if load_scenario(p).machine == "arm" and load_scenario(p).probe is None)


def _both(report: dict, value) -> str:
    return "/".join(value(report[n]) if "verification" in report.get(n, {}) else "-" for n in PATHS)


def row(name: str, code: int, wall_s: float, r: dict) -> str:
    loc = r["localization"]
    failed = [c["name"] for c in r["checks"] if c["decides"] and not c["passed"]]
    cad = r.get("cad_path", {})
    return " | ".join([
        f"| {name}", str(code), ", ".join(failed) or "-",
        _both(r, lambda b: f"{100 * b['coverage']:.1f}"),
        _both(r, lambda b: f"{b['verification']['tip_penetration_max_mm']:.3f}"),
        _both(r, lambda b: f"{b['verification']['max_deviation_mm']:.3f}"),
        _both(r, lambda b: str(len(b["dropped"]))),
        _both(r, lambda b: f"{b['max_tool_tilt_deg']:.1f}"),
        str(r["path_verification"]["unintended_contacts"]),
        loc["status"], str(len(loc["free_directions"])), str(loc["max_error_sigmas"]),
        f"{1e3 * cad['max_surface_error_mm']:.2f} / {1e3 * cad['surface_error_bound_mm']:.2f}" if cad else "-",
        str(len(r["scan"]["passes"])), f"{wall_s:.0f} |"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", nargs="*", default=None, help="scenario names (default: every laser scenario)")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results_loop.md")
    args = ap.parse_args()
    names = args.scenarios or laser_scenarios()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            out = Path(tmp) / name
            t0 = time.perf_counter()
            code = subprocess.run([sys.executable, "-m", "twin", "run", str(SCENARIOS / f"{name}.toml"), "--out",
                                   str(out), "--quiet"], cwd=ROOT, capture_output=True, text=True).returncode
            wall = time.perf_counter() - t0
            rows.append(row(name, code, wall, json.loads((out / "report.json").read_text())))
            print(rows[-1], flush=True)
    command = "python -m benchmarks.bench_loop" + (f" --scenarios {' '.join(names)}" if args.scenarios else "")
    text = "\n".join([
        "# The loop on every scenario",
        "",
        f"Commit {commit_stamp()}, {platform.processor() or platform.machine()}, one run after another. "
        f"Command: `{command}`.",
        "",
        "Each row is `twin run scenarios/NAME.toml` with the scenario as written: its exit status (0 every "
        "deciding check passed, 3 one failed: `twin.verdicts`, the scenario's `[tolerances]`), the failed "
        "checks, then per path (scan / CAD): the share of the planned contact points kept, the deepest the "
        "replayed ball end went into the true part, the largest deviation of the replayed tool from its path, "
        "the stretches dropped, the largest tilt of the tool axis from the normal; the unintended contacts; the "
        "localization's verdict, free directions and largest error along a determined direction in reported "
        "standard deviations; the CAD path's largest surface error against its 3-sigma bound; the scan passes; "
        "the wall time of the command.",
        "",
        "| scenario | exit | failed checks | coverage % | tip penetration mm | max deviation mm | dropped | "
        "tilt deg | contacts | localization | free dirs | max err/std | CAD surf err / bound um | passes | "
        "wall s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
        *rows,
    ]) + "\n"
    args.out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()

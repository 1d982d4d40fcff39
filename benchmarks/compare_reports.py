"""Every shipped workflow's reports from one checkout, and two such trees compared field by
field, timings aside: the check that a change which must not change behaviour did not.

    python -m benchmarks.compare_reports make OUT_DIR        # run the commands below into OUT_DIR
    python -m benchmarks.compare_reports diff BASE_DIR NEW_DIR

``make`` runs, with the ``twin`` of the current environment: ``twin run`` on every
``scenarios/*.toml`` (``twin locate`` on the ``locate_*`` ones), ``twin cmm compare`` on the
three teach files, and ``twin study studies/sensor_sigma.toml --workers 1``; each command's
stdout (``--json``) and exit code are kept beside its folder. To compare two commits, run
``make`` in a checkout of each (or with ``PYTHONPATH`` pointing at it).

``diff`` compares every JSON document (reports, manifests, the commands' stdout) value by
value, CSV, DMIS, Markdown and PLY files byte by byte (Markdown tables line by line), and
Parquet tables column by column (NaN equal to NaN). Wall-clock fields are left out: keys
naming a time, wall seconds or a speed against real time (simulated times, such as a
program's ``cycle_time_s``, are compared). Paths are compared below the two roots. Exit code 0
when nothing differs, 1 otherwise, with each difference printed.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import subprocess
import sys
from pathlib import Path

import pyarrow.parquet as pq

ROOT = Path(__file__).resolve().parents[1]
CMM_CASES = (("through_hole", "through_hole"), ("inner_sphere", "inner_sphere"),
             ("inner_sphere_below_plane", "inner_sphere"))
WALL_CLOCK_WORDS = ("time_s", "wall_s", "timings", "_ms", "elapsed", "time_per", "seconds", "speed_x_realtime")
TEXT_SUFFIXES = (".csv", ".dmi", ".md", ".ply")


def is_wall_clock(key: str) -> bool:
    """Whether a report key holds a wall-clock figure (simulated times are kept)."""
    k = key.lower()
    if "speed_x_realtime" in k:
        return True
    return any(w in k for w in WALL_CLOCK_WORDS) and not k.startswith("cycle_time") and "sim" not in k


def commands(out: Path) -> list[tuple[str, list[str]]]:
    """(name, twin arguments) of every report ``make`` writes into ``out``."""
    runs = []
    for scenario in sorted((ROOT / "scenarios").glob("*.toml")):
        verb = "locate" if scenario.stem.startswith("locate_") else "run"
        runs.append((scenario.stem, [verb, str(scenario), "--out", str(out / scenario.stem)]))
    for teach, scenario in CMM_CASES:
        runs.append((f"cmm_{teach}", ["cmm", "compare", str(ROOT / "scenarios/cmm/teach" / f"{teach}.toml"),
                                      str(ROOT / "scenarios/cmm" / f"{scenario}.toml"), "--out",
                                      str(out / f"cmm_{teach}"), "--no-rrd"]))
    runs.append(("study_sensor_sigma", ["study", str(ROOT / "studies/sensor_sigma.toml"), "--out",
                                        str(out / "study_sensor_sigma"), "--workers", "1"]))
    return runs


def make(out: Path) -> int:
    out.mkdir(parents=True, exist_ok=True)
    for name, args in commands(out):
        done = subprocess.run([sys.executable, "-m", "twin.cli", *args, "--force", "--quiet", "--json"],
                              capture_output=True, text=True)
        (out / f"{name}.stdout.json").write_text(done.stdout)
        (out / f"{name}.exit").write_text(f"{done.returncode}\n")
        print(f"{name}: exit {done.returncode}", file=sys.stderr)
    return 0


def _same_number(a: object, b: object) -> bool:
    return a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b))


def _relative(text: str, roots: tuple[Path, Path]) -> str:
    """Paths below the trees' roots, and below each checkout's scenarios folder."""
    text = re.sub(r"/[^\s'\"]*?/scenarios/", "@scenarios/", text)
    for r in roots:
        text = text.replace(str(r.resolve()), "@").replace(str(r), "@")
    return text


def diff_json(a: object, b: object, where: str, roots: tuple[Path, Path]) -> list[str]:
    """The differing values of two JSON documents, wall-clock keys aside."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b)):
            if is_wall_clock(k):
                continue
            if k not in a or k not in b:
                out.append(f"{where}/{k}: only in {'new' if k in b else 'base'}")
            else:
                out += diff_json(a[k], b[k], f"{where}/{k}", roots)
        return out
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{where}: {len(a)} items != {len(b)}"]
        return [d for i, (x, y) in enumerate(zip(a, b, strict=True)) for d in diff_json(x, y, f"{where}[{i}]", roots)]
    if isinstance(a, str) and isinstance(b, str):
        return [] if _relative(a, roots) == _relative(b, roots) else [f"{where}: {a!r} != {b!r}"]
    return [] if _same_number(a, b) else [f"{where}: {a!r} != {b!r}"]


def diff_parquet(a: Path, b: Path) -> list[str]:
    ta, tb = pq.read_table(a), pq.read_table(b)
    if ta.column_names != tb.column_names or ta.num_rows != tb.num_rows:
        return [f"columns or rows differ: {ta.column_names} x {ta.num_rows} != {tb.column_names} x {tb.num_rows}"]
    return [f"column {c}" for c in ta.column_names if not is_wall_clock(c) and not all(
        _same_number(x, y) for x, y in zip(ta.column(c).to_pylist(), tb.column(c).to_pylist(), strict=True))]


def _masked_markdown(text: str) -> list[str]:
    """The lines of a Markdown report with its wall-clock figures masked: table columns whose
    header names a time in ms, and "... time N ms" in prose."""
    out, timed = [], set()
    for line in text.splitlines():
        if line.startswith("|"):
            cells = line.strip("|").split("|")
            if any("time [ms]" in c for c in cells):
                timed = {i for i, c in enumerate(cells) if "time [ms]" in c}
            elif not set(line) <= set("|-: "):
                cells = ["*" if i in timed else c for i, c in enumerate(cells)]
            line = "|" + "|".join(cells) + "|"
        else:
            timed = set()
        out.append(re.sub(r"time [0-9.]+ ms", "time * ms", line))
    return out


def diff_file(a: Path, b: Path, roots: tuple[Path, Path]) -> list[str]:
    """The differences between one file of each tree (empty when equal)."""
    if a.suffix in (".json", ".stdout"):
        return diff_json(json.loads(a.read_text() or "null"), json.loads(b.read_text() or "null"), "", roots)
    if a.suffix == ".parquet":
        return diff_parquet(a, b)
    if a.suffix == ".md":
        la, lb = _masked_markdown(a.read_text()), _masked_markdown(b.read_text())
        if len(la) != len(lb):
            return [f"{len(la)} lines != {len(lb)}"]
        return [f"line {i + 1}: {x!r} != {y!r}" for i, (x, y) in enumerate(zip(la, lb, strict=True)) if x != y]
    return [] if a.read_bytes() == b.read_bytes() else ["contents differ"]


def diff(base: Path, new: Path) -> int:
    roots = (base, new)
    compared = differing = 0
    for a in sorted(p for p in base.rglob("*") if p.is_file()):
        if a.suffix not in (".json", ".stdout", ".parquet", ".exit", *TEXT_SUFFIXES):
            continue
        b = new / a.relative_to(base)
        compared += 1
        found = ["missing in the new tree"] if not b.exists() else diff_file(a, b, roots)
        if found:
            differing += 1
            print(f"{a.relative_to(base)}: {len(found)} difference(s)")
            for line in found[:20]:
                print(f"    {line}")
    print(f"{compared} files compared, {differing} differ (wall-clock fields aside)")
    return 1 if differing else 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("make", help="run every workflow's commands into OUT").add_argument("out", type=Path)
    d = sub.add_parser("diff", help="compare two trees written by make")
    d.add_argument("base", type=Path)
    d.add_argument("new", type=Path)
    args = parser.parse_args()
    return make(args.out) if args.command == "make" else diff(args.base, args.new)


if __name__ == "__main__":
    sys.exit(main())

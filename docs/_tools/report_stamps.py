"""A committed report as a documentation page shows it: its text, the commit and date it was made
from, and whether the code it measured has changed since.

A report's commit is the one it names (benchmarks stamp theirs: a 7-40 digit hash git knows),
else the commit that last wrote the file. The code it measured is what its include marker names
(``modules=...``), plus the benchmark module and the study file its own command names. The report
is *stale* when a commit after the report's commit touched any of them.
"""

from __future__ import annotations

import re
import subprocess
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
_HASH = re.compile(r"\b[0-9a-f]{7,40}\b")
_BENCH = re.compile(r"python -m (benchmarks\.\w+)")
_STUDY = re.compile(r"(studies/\w+\.toml)")


def git(*args: str) -> str:
    """The output of a git command in the repository ('' where git or the history is missing)."""
    try:
        done = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, check=False, timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        return ""
    return done.stdout.strip() if done.returncode == 0 else ""


@dataclass(frozen=True)
class Stamp:
    """Where a report comes from and whether it is older than the code it measured."""

    commit: str  # short hash; "" when the history is not available
    date: str  # ISO date of that commit
    stamped: bool  # the report names its commit (else: the commit that last wrote the file)
    measured: tuple[str, ...]  # the files and folders it measured
    changed_since: int  # commits touching them after the report's commit
    last_change: str  # the newest of those commits, "hash date"


def _named_commit(text: str) -> str:
    """The first hash in the report that git knows as a commit."""
    for token in _HASH.findall(text[:3000]):
        if git("cat-file", "-t", token) == "commit":
            return token
    return ""


def measured_paths(text: str, modules: list[str]) -> tuple[str, ...]:
    """What a report measured: the modules its marker names, the benchmark and study it was run with."""
    found = list(modules)
    found += [m.replace(".", "/") + ".py" for m in _BENCH.findall(text)]
    found += _STUDY.findall(text)
    return tuple(p for p in dict.fromkeys(found) if (ROOT / p).exists())


def stamp(report: Path, modules: list[str]) -> Stamp:
    """The stamp of ``report`` (a path in the repository)."""
    text = report.read_text(encoding="utf-8")
    named = _named_commit(text)
    inside = report.resolve().is_relative_to(ROOT)
    commit = named or (git("log", "-1", "--format=%H", "--", str(report.resolve().relative_to(ROOT))) if inside else "")
    measured = measured_paths(text, modules)
    if not commit:
        return Stamp("", "", False, measured, 0, "")
    date = git("show", "-s", "--format=%cs", commit)
    changes = git("log", "--format=%h %cs", f"{commit}..HEAD", "--", *measured).splitlines() if measured else []
    return Stamp(commit[:7], date, bool(named), measured, len(changes), changes[0] if changes else "")


def stamp_markdown(s: Stamp, report_rel: str) -> str:
    """The line a page shows above an included report."""
    if not s.commit:
        return f'!!! note "`{report_rel}`"\n    Made at an unknown commit (no git history in this checkout).\n'
    how = "the commit it names" if s.stamped else "the commit that last wrote it"
    what = ", ".join(f"`{p}`" for p in s.measured) or "no module named"
    if s.changed_since:
        return (f'!!! warning "Older than the code it measured: `{report_rel}`"\n'
                f"    Made at commit `{s.commit}` ({s.date}, {how}); since then {s.changed_since} commit(s) "
                f"changed {what} (newest: `{s.last_change}`). Rerun its command to refresh it.\n")
    return (f'!!! info "`{report_rel}`"\n'
            f"    Made at commit `{s.commit}` ({s.date}, {how}); {what} unchanged since.\n")

"""The verdict battery (:mod:`benchmarks.verdict_battery`), large: false ``ok`` results on
adversarial trials and false alarms on sound ones, per kind and part, with the review's
outcomes (:mod:`algorithms.registration.review`) and the time per fit.

    python -m benchmarks.bench_verdicts [--per-cell 30] [--out benchmarks/results_verdicts.md]
"""

from __future__ import annotations

import argparse
import collections
import platform
import time
from pathlib import Path

import numpy as np

from benchmarks.verdict_battery import ADVERSARIAL_KINDS, ANGLE_TOL_DEG, DISTANCE_TOL_M, SOUND_KINDS, battery
from tests.helpers import ROOT, commit_stamp


def _review_kind(review: str | None) -> str:
    return "none" if review is None else review.split(":", 1)[0]


def report(out: list, seconds: float, per_cell: int) -> str:
    sound = [o for o in out if o.kind in SOUND_KINDS and not o.weak]
    lines = [
        "# Localization verdicts: the adversarial battery",
        "",
        f"Commit {commit_stamp()}, {platform.processor() or platform.machine()}, "
        f"{len(out)} trials ({per_cell} per kind and part) in {seconds:.0f} s. "
        f"Command: `python -m benchmarks.bench_verdicts --per-cell {per_cell}`.",
        "",
        f"A false `ok` is an `ok` more than {ANGLE_TOL_DEG} deg / {DISTANCE_TOL_M * 1e3} mm from the truth (or an "
        "equivalent pose of a symmetric part; for a wrong, mirrored or scaled part, an `ok` where the model at the "
        "answer does not explain the points). A false alarm is any other answer to a sound trial whose points fix "
        "every direction.",
        "",
        f"- **false ok: {sum(o.false_ok for o in out)} of {len(out)}**",
        f"- **false alarms: {sum(o.false_alarm for o in out)} of {len(sound)} sound fits "
        f"({100.0 * sum(o.false_alarm for o in out) / max(len(sound), 1):.2f} %)**",
        "",
        "| kind | trials | ok, right | ok, wrong | other verdicts | refused | reviews (outcome: count) | "
        "median time [ms] |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for kind in SOUND_KINDS + ADVERSARIAL_KINDS:
        rows = [o for o in out if o.kind == kind]
        if not rows:
            continue
        others = collections.Counter(o.status for o in rows if o.status not in ("ok", "refused"))
        reviews = collections.Counter(_review_kind(o.review) for o in rows if o.review is not None)
        lines.append(
            f"| {kind} | {len(rows)} | {sum(o.status == 'ok' and o.correct for o in rows)} | "
            f"{sum(o.false_ok for o in rows)} | {', '.join(f'{k} {v}' for k, v in sorted(others.items())) or '-'} | "
            f"{sum(o.status == 'refused' for o in rows)} | "
            f"{', '.join(f'{k} {v}' for k, v in sorted(reviews.items())) or '-'} | "
            f"{1e3 * float(np.median([o.time_s for o in rows])):.1f} |")
    bad = [o for o in out if o.false_ok or o.false_alarm]
    if bad:
        lines += ["", "Trials that went wrong (kind, part, seed, verdict, error deg / mm, review):", ""]
        lines += [f"- {o.kind} {o.part} {o.seed}: {o.status}, {o.angle_deg:.3g} deg / {o.distance_mm:.3g} mm, "
                  f"{o.review}" for o in bad]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-cell", type=int, default=30)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results_verdicts.md")
    args = ap.parse_args()
    t0 = time.perf_counter()
    out = battery(args.per_cell)
    text = report(out, time.perf_counter() - t0, args.per_cell)
    args.out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()

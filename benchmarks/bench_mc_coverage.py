"""Are a study's Monte Carlo outputs right? The same study run as many independent studies (seeds
``seed + r``), each summarized as its report does (:func:`twin.studies.jcgm101.summarize`), against
the distribution of all their trials together (the reference):

- each study's 95 % probabilistically symmetric interval's ends against the reference's 2.5 % and
  97.5 % points, in units of the study's own Monte Carlo standard error of each end;
- each study's estimate (the mean error) against zero, in units of its Monte Carlo standard error:
  with every systematic effect drawn per trial and none fixed, the error has mean zero.

If the Monte Carlo standard errors are honest, the standardized deviations ``z`` have a standard
deviation near 1 and about 95 % of them are within 2 (a batch's standard error from 10 batches
is itself uncertain: a t distribution with 9 degrees of freedom puts 92 % within 2 and 98.5 %
within 3).

    python -m benchmarks.bench_mc_coverage [--study studies/s_surface_gum.toml] [--studies 25] [--trials 200]
                                           [--workers 2] [--out benchmarks/results_mc_coverage.md] [--save T.npz]
"""

from __future__ import annotations

import argparse
import dataclasses
import platform
import time
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from tests.helpers import ROOT, commit_stamp
from twin.studies import jcgm101, load_study
from twin.studies.kinds import run_trial
from twin.studies.trials import TWIST_COLUMNS

CHUNK = 20


def _trials(task: tuple[str, int, int, int]) -> list[dict]:
    path, seed, start, count = task
    study = dataclasses.replace(load_study(path), seed=seed)
    return [run_trial(study, 0, t) for t in range(start, start + count)]


def run(path: Path, studies: int, trials: int, workers: int) -> tuple[dict[int, list[dict]], float]:
    """Every trial of ``studies`` copies of the study (cell 0, seeds ``seed + r``), by seed."""
    base = load_study(path).seed
    tasks = [(str(path), base + r, k, min(CHUNK, trials - k)) for r in range(studies) for k in range(0, trials, CHUNK)]
    t0 = time.perf_counter()
    with get_context("spawn").Pool(workers) as pool:  # spawn: a forked child of a threaded process can hang
        done = pool.map(_trials, tasks, chunksize=1)
    rows: dict[int, list[dict]] = {}
    for task, part in zip(tasks, done, strict=True):
        rows.setdefault(task[1], []).extend(part)
    return rows, time.perf_counter() - t0


def standardized(rows: dict[int, list[dict]]) -> dict:
    """Per twist component, the ``z`` of each study's interval ends (against the pooled
    reference) and of its mean (against zero); the trials not ``ok`` are counted, not used."""
    ok = {seed: [r for r in part if r["status"] == "ok"] for seed, part in rows.items()}
    out: dict = {"not_ok": sum(len(p) - len(ok[s]) for s, p in rows.items()), "components": {}}
    for c in TWIST_COLUMNS:
        pooled = np.concatenate([[r[c] for r in part] for part in ok.values()])
        ref = jcgm101.symmetric_interval(pooled)
        z_low, z_high, z_mean, z_mean_iid = [], [], [], []
        for part in ok.values():
            y = np.array([r[c] for r in part])
            o = jcgm101.summarize(y)
            z_low.append((o.values[2] - ref[0]) / o.mc_se[2])
            z_high.append((o.values[3] - ref[1]) / o.mc_se[3])
            z_mean.append(o.values[0] / o.mc_se[0])
            z_mean_iid.append(o.values[0] / (o.values[1] / np.sqrt(len(y))))
        out["components"][c] = {"reference": ref, "pooled_mean": float(np.mean(pooled)),
                                "pooled_u": float(np.std(pooled, ddof=1)), "n": len(pooled),
                                "z_ends": np.array(z_low + z_high), "z_mean": np.array(z_mean),
                                "z_mean_iid": np.array(z_mean_iid)}
    return out


def within(z: np.ndarray, k: float) -> float:
    return float(np.mean(np.abs(z) <= k))


def markdown(path: Path, result: dict, studies: int, trials: int, command: str, wall_s: float) -> str:
    lines = [
        "# Do a study's Monte Carlo standard errors hold? The same study run as independent studies",
        "",
        commit_stamp(),
        "",
        f"Command: `{command}` ({platform.machine()}, {wall_s:.0f} s wall).",
        "",
        f"`{path.relative_to(ROOT)}` run as {studies} independent studies of {trials} trials (seeds `seed + r`), each "
        "summarized as its report does (JCGM 101: the 95 % probabilistically symmetric interval, the Monte Carlo "
        "standard error of each value from 10 batches in trial order). The reference is the distribution of all "
        "the studies' trials together. `z` of an interval end: (the study's end - the reference's 2.5 % or 97.5 % "
        "point) / the study's standard error of that end; `z` of the mean: the study's mean error / its standard "
        "error (every systematic effect is drawn per trial and none fixed, so the true mean error is zero). Honest "
        "standard errors give `z` a standard deviation near 1, about 92 % within 2 and 98.5 % within 3 (a t "
        f"distribution of 9 degrees of freedom). Trials not `ok`: {result['not_ok']}. The last column divides the "
        "mean by `u / sqrt(M)` instead, the standard error of independent trials: where it is near 1 and the "
        "batches' is wider, the spread is the batch standard error's own uncertainty (10 batches), not a bias.",
        "",
        "| component | trials | reference interval | pooled mean, u | ends: sd of z | ends within 2 s.e. "
        "| ends within 3 s.e. | mean: mean and sd of z, largest abs | means within 3 s.e. "
        "| mean: sd of z by u/sqrt(M) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    all_ends, all_means = [], []
    for c, r in result["components"].items():
        places = jcgm101.decimals(r["pooled_u"])
        ze, zm = r["z_ends"], r["z_mean"]
        all_ends.append(ze)
        all_means.append(zm)
        lines.append(f"| {c} | {r['n']} | [{jcgm101.fmt(r['reference'][0], places)}, "
                     f"{jcgm101.fmt(r['reference'][1], places)}] | {jcgm101.fmt(r['pooled_mean'], places)}, "
                     f"{jcgm101.fmt(r['pooled_u'], places)} | {np.std(ze):.2f} | {100 * within(ze, 2):.0f} % | "
                     f"{100 * within(ze, 3):.0f} % | {np.mean(zm):.2f}, {np.std(zm):.2f}, {np.max(np.abs(zm)):.1f} | "
                     f"{100 * within(zm, 3):.0f} % | {np.std(r['z_mean_iid']):.2f} |")
    ze, zm = np.concatenate(all_ends), np.concatenate(all_means)
    lines += ["", f"All components: interval ends within 2 standard errors of the reference's points in "
                  f"{100 * within(ze, 2):.1f} % ({len(ze)} ends), within 3 in {100 * within(ze, 3):.1f} %; "
                  f"means within 3 standard errors of zero in {100 * within(zm, 3):.1f} % ({len(zm)} means).", ""]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--study", type=Path, default=ROOT / "studies" / "s_surface_gum.toml")
    ap.add_argument("--studies", type=int, default=25, help="independent studies (default 25)")
    ap.add_argument("--trials", type=int, default=200, help="trials per study (default 200)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results_mc_coverage.md")
    ap.add_argument("--save", type=Path, default=None, help="also write every trial's twist components (.npz)")
    args = ap.parse_args()
    path = args.study.resolve()
    rows, wall_s = run(path, args.studies, args.trials, args.workers)
    if args.save is not None:
        np.savez(args.save, **{f"{c}_seed{seed}": np.array([r[c] for r in part])
                               for seed, part in rows.items() for c in TWIST_COLUMNS})
    command = "python -m benchmarks.bench_mc_coverage" \
        + (f" --study {path.relative_to(ROOT)}" if path != ROOT / "studies" / "s_surface_gum.toml" else "") \
        + (f" --studies {args.studies}" if args.studies != 25 else "") \
        + (f" --trials {args.trials}" if args.trials != 200 else "")
    text = markdown(path, standardized(rows), args.studies, args.trials, command, wall_s)
    args.out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()

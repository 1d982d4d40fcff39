"""``twin/ActiveScan-v0`` and ``twin/ActiveProbe-v0``: the baselines compared, and the
environments' speed.

Sections:

* ``policies``: per scenario and policy (laser segments, ``--env scan``: random, raster,
  greedy information gain; probe points, ``--env probe``: random, greedy; the learned policy
  is compared in ``benchmarks/bench_env_learned.py``), ``--seeds`` x
  ``--episodes`` episodes: environment seed s resets the first of its episodes with ``s``,
  the others continue its stream. Per seed the mean over its episodes; the table gives the
  mean and standard deviation of those means over the seeds: success rate (tolerance reached
  and confirmed, no collision), steps and motion time to the tolerance (successful episodes),
  the translation and rotation error after ``K`` steps (or at the end of a shorter
  episode), the final error in the reported standard deviations, unreachable choices and
  collisions per episode.
* ``speed``: environment steps per second on one core (the process pinned to CPU 0),
  policy time excluded, for the random and the greedy policy's actions: all steps, and the
  steps that moved the arm and measured.

Run from the repository root: ``python -m benchmarks.bench_env`` (writes
``benchmarks/results_env.md``; ``--env probe`` writes ``benchmarks/results_env_probe.md``;
``--section``, ``--scenarios``, ``--policies``, ``--seeds``,
``--episodes`` and ``--workers`` narrow or spread it). Each (scenario, policy, seed) runs in a
worker process; its numbers depend only on its seed.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
#: Per environment: its id, default scenarios and policies, and the results file.
ENVS = {
    "scan": ("twin/ActiveScan-v0", ("bracket.toml", "cast_blank.toml"), ("random", "raster", "greedy"),
             ROOT / "benchmarks" / "results_env.md"),
    "probe": ("twin/ActiveProbe-v0", ("locate_hemisphere_punch.toml",), ("random", "greedy"),
              ROOT / "benchmarks" / "results_env_probe.md"),
}
K_STEPS = 5


def _make_env(env_kind: str, scenario: str, max_steps: int):
    if env_kind == "probe":
        from twin.env.active_probe import ActiveProbeEnv

        return ActiveProbeEnv(scenarios=scenario, max_steps=max_steps)
    from twin.env.active_scan import ActiveScanEnv

    return ActiveScanEnv(scenarios=scenario, max_steps=max_steps)


def _policy(env_kind: str, name: str, env, seed: int):
    from twin.env.policies import POLICIES, PROBE_POLICIES

    baselines = PROBE_POLICIES if env_kind == "probe" else POLICIES
    if name not in baselines:
        raise SystemExit(f"--policies: {name!r} is not a policy of --env {env_kind}; choose from {sorted(baselines)}")
    return baselines[name](env, seed=seed)


def run_seed(args: tuple) -> list[dict]:
    """Every episode of one (scenario, policy, seed): one dict of numbers each."""
    env_kind, scenario, policy_name, seed, episodes, max_steps = args
    env = _make_env(env_kind, scenario, max_steps)
    policy = _policy(env_kind, policy_name, env, seed)
    out = []
    for e in range(episodes):
        obs, info = env.reset(seed=seed if e == 0 else None)
        policy.reset()
        at_k = info
        done = False
        while not done:
            obs, _, term, trunc, info = env.step(policy(obs))
            done = term or trunc
            if info["steps"] <= K_STEPS:
                at_k = info
        out.append({
            "success": float(info["is_success"]),
            "steps": info["steps"], "motion_s": info["motion_time_s"],
            "trans_k_um": at_k["translation_error_m"] * 1e6, "rot_k_deg": at_k["rotation_error_deg"],
            "trans_sigmas": info["translation_error_m"] / info["std_translation_m"],
            "rot_sigmas": info["rotation_error_deg"] / info["std_rotation_deg"],
            "unreachable": info["unreachable_total"], "collisions": info["collisions_total"],
        })
    env.close()
    return out


def _mean_std(per_seed: list[float]) -> str:
    a = np.array([x for x in per_seed if np.isfinite(x)])
    if not len(a):
        return "-"
    return f"{a.mean():.3g} ± {a.std():.2g}"


def policies_section(env_kind, scenarios, policies, seeds, episodes, max_steps, workers) -> str:
    jobs = [(env_kind, sc, p, s, episodes, max_steps) for sc in scenarios for p in policies
            for s in range(seeds)]
    jobs.sort(key=lambda job: job[2] != "greedy")   # the longest first: the workers finish together
    t0 = time.perf_counter()
    with ProcessPoolExecutor(workers) as pool:
        results = list(pool.map(run_seed, jobs))
    wall = time.perf_counter() - t0
    lines = [f"## Policies ({seeds} seeds x {episodes} episodes, at most {max_steps} steps; {wall:.0f} s on "
             f"{workers} workers)", "",
             "Mean ± standard deviation over the seeds of each seed's mean over its episodes. Steps and motion "
             f"time to the tolerance: successful episodes only. Errors after {K_STEPS} steps (or at the end of a "
             "shorter episode). Final error in sigmas: the true error over the reported posterior standard "
             "deviation (worst direction), median over the episodes of a seed.", "",
             "| scenario | policy | success | steps to tol | motion to tol (s) | trans. err. after 5 (um) | "
             "rot. err. after 5 (deg) | final err. / std (trans, rot) | unreachable / ep | collisions / ep |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    by: dict = {(sc, p): [] for sc in scenarios for p in policies}   # the table's row order
    for job, res in zip(jobs, results, strict=True):
        by[job[1], job[2]].append(res)
    for (sc, p), seeds_res in by.items():
        def per_seed(key, only_success=False, runs=seeds_res):
            vals = []
            for eps in runs:
                xs = [e[key] for e in eps if (e["success"] or not only_success)]
                vals.append(float(np.mean(xs)) if xs else np.nan)
            return vals

        def per_seed_median(key, runs=seeds_res):
            return [float(np.median([e[key] for e in eps])) for eps in runs]

        lines.append(
            f"| {sc.removesuffix('.toml')} | {p} | {_mean_std(per_seed('success'))} | "
            f"{_mean_std(per_seed('steps', True))} | {_mean_std(per_seed('motion_s', True))} | "
            f"{_mean_std(per_seed('trans_k_um'))} | {_mean_std(per_seed('rot_k_deg'))} | "
            f"{_mean_std(per_seed_median('trans_sigmas'))}, {_mean_std(per_seed_median('rot_sigmas'))} | "
            f"{_mean_std(per_seed('unreachable'))} | {_mean_std(per_seed('collisions'))} |")
    return "\n".join(lines) + "\n"


def speed_section(env_kind: str, scenario: str, steps: int) -> str:
    """Steps per second on one core (this process pinned to CPU 0), policy time excluded."""
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {0})
    import importlib

    importlib.import_module("twin.env.active_probe" if env_kind == "probe" else "twin.env.active_scan")
    builds = []
    for _ in range(2):  # the first instance in the process, then another (its part already generated)
        t0 = time.perf_counter()
        env = _make_env(env_kind, scenario, 30)
        builds.append(time.perf_counter() - t0)
    resets = []
    for seed in range(5):   # the first reset in the process compiles the cell's kernels: timed apart
        t0 = time.perf_counter()
        env.reset(seed=seed)
        resets.append(time.perf_counter() - t0)
    rows = []
    for name in ("random", "greedy"):
        policy = _policy(env_kind, name, env, 0)
        obs, _ = env.reset(seed=100)
        policy.reset()
        env.step(policy(obs))  # first-call compilation out of the timing
        all_t, moving_t = [], []
        while len(all_t) < steps:
            a = policy(obs)
            t0 = time.perf_counter()
            obs, _, term, trunc, info = env.step(a)
            dt = time.perf_counter() - t0
            all_t.append(dt)
            if "duration_s" in info:
                moving_t.append(dt)
            if term or trunc:
                obs, _ = env.reset()
                policy.reset()
        rows.append(f"| {name} | {len(all_t)} | {len(all_t) / sum(all_t):.1f} | {len(moving_t)} | "
                    f"{len(moving_t) / sum(moving_t):.1f} | {1e3 * np.median(moving_t):.0f} |")
    return "\n".join([
        f"## Speed ({scenario.removesuffix('.toml')}, one core, policy time excluded)", "",
        "| actions of | steps | steps/s | steps that measured | their steps/s | median ms per measuring step |",
        "|---|---|---|---|---|---|", *rows, "",
        f"Building an instance (imports done): {builds[0]:.1f} s the first in the process, {builds[1]:.1f} s "
        f"another of the same scenario. A reset: {resets[0]:.2f} s the first, then median "
        f"{np.median(resets[1:]):.3f} s."]) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--env", choices=tuple(ENVS), default="scan")
    ap.add_argument("--section", choices=("all", "policies", "speed"), default="all")
    ap.add_argument("--scenarios", nargs="+", default=None)
    ap.add_argument("--policies", nargs="+", default=None)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--max-steps", type=int, default=30)
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--speed-steps", type=int, default=200)
    ap.add_argument("--out", default=None, help="the results file (default: per environment, see ENVS)")
    a = ap.parse_args()
    env_id, default_scenarios, default_policies, default_out = ENVS[a.env]
    scenarios = a.scenarios or list(default_scenarios)
    policies = list(a.policies or default_policies)
    parts = [f"# {env_id} baselines\n\n`python -m benchmarks.bench_env {' '.join(sys.argv[1:])}` on "
             f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, {time.strftime('%Y-%m-%d')}.\n"]
    if a.section in ("all", "policies"):
        parts.append(policies_section(a.env, scenarios, policies, a.seeds, a.episodes, a.max_steps, a.workers))
    if a.section in ("all", "speed"):
        parts.append(speed_section(a.env, scenarios[0], a.speed_steps))
    text = "\n".join(parts)
    Path(a.out or default_out).write_text(text)
    print(text)


if __name__ == "__main__":
    main()

"""The learned ``twin/ActiveScan-v0`` policy against the baselines, on held-out seeds.

``python -m benchmarks.bench_env_learned --model benchmarks/ppo_active_scan/model.zip``
(writes ``benchmarks/results_env_learned.md``): for each scenario (``--scenarios``: by default
a training part and the held-out part of ``benchmarks/train_ppo.py``) and each policy (random,
raster, greedy information gain: :mod:`twin.env.policies`, on the box actions; learned: the
model, on the views actions, reading only the observation and ``info["action_mask"]``),
``--episodes`` episodes, episode ``i`` reset with seed ``SEED_BASE + i`` (seeds no training
episode was drawn from: training streams start at seeds 0 and 1). Per policy: the mean and
standard deviation of the return, the successes (tolerance reached and confirmed), the mean
steps and motion time of all episodes, and the median final errors against the truth.
Each (scenario, policy) runs in a worker process; its numbers depend only on the seeds.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from benchmarks.train_ppo import LearnedPolicy

ROOT = Path(__file__).resolve().parent.parent
SEED_BASE = 1_000_000
POLICIES = ("random", "raster", "greedy", "learned")


class Baseline:
    """A baseline of :mod:`twin.env.policies` called as the learned policy is: (obs, info)."""

    def __init__(self, policy):
        self.policy = policy

    def reset(self) -> None:
        self.policy.reset()

    def __call__(self, observation: dict, info: dict):
        return self.policy(observation)


def run_policy(args: tuple) -> dict:
    """Every episode of one (scenario, policy): lists of numbers."""
    scenario, policy_name, episodes, model = args
    import gymnasium as gym

    import twin  # noqa: F401  (registers the environments)
    from twin.env.policies import POLICIES as BASELINES

    policy: Baseline | LearnedPolicy
    learned = policy_name == "learned"
    env = gym.make("twin/ActiveScan-v0", scenarios=scenario, actions="views" if learned else "box")
    if learned:
        policy = LearnedPolicy(model)
    else:
        policy = Baseline(BASELINES[policy_name](env, seed=0))
    rows: dict[str, list] = {k: [] for k in ("return", "success", "steps", "motion_s", "trans_um", "rot_deg",
                                             "trans_sigmas", "rot_sigmas")}
    start = time.monotonic()
    for i in range(episodes):
        obs, info = env.reset(seed=SEED_BASE + i)
        policy.reset()
        total, done = 0.0, False
        while not done:
            obs, reward, term, trunc, info = env.step(policy(obs, info))
            total += float(reward)
            done = term or trunc
        rows["return"].append(total)
        rows["success"].append(bool(info.get("is_success", False)))
        rows["steps"].append(info["steps"])
        rows["motion_s"].append(info["motion_time_s"])
        rows["trans_um"].append(info["translation_error_m"] * 1e6)
        rows["rot_deg"].append(info["rotation_error_deg"])
        rows["trans_sigmas"].append(info["translation_error_m"] / info["std_translation_m"])
        rows["rot_sigmas"].append(info["rotation_error_deg"] / info["std_rotation_deg"])
    env.close()
    return {"scenario": scenario, "policy": policy_name, "wall_s": time.monotonic() - start, **rows}


def table(results: list[dict]) -> str:
    head = ("| scenario | policy | return (mean ± sd) | successes | steps | motion time (s) | "
            "final error (um, deg), median | final error / std (trans, rot), median |")
    lines = [head, "|" + "---|" * 8]
    for r in results:
        ret = np.array(r["return"])
        lines.append(
            f"| {r['scenario'].removesuffix('.toml')} | {r['policy']} | {ret.mean():.1f} ± {ret.std():.1f} | "
            f"{sum(r['success'])}/{len(ret)} | {np.mean(r['steps']):.1f} | {np.mean(r['motion_s']):.1f} | "
            f"{np.median(r['trans_um']):.3g}, {np.median(r['rot_deg']):.2g} | "
            f"{np.median(r['trans_sigmas']):.2f}, {np.median(r['rot_sigmas']):.2f} |")
    return "\n".join(lines)


def main() -> None:
    from benchmarks.train_ppo import HELD_OUT_SCENARIO, TRAIN_SCENARIOS

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="benchmarks/ppo_active_scan/model.zip")
    ap.add_argument("--scenarios", nargs="+", default=[TRAIN_SCENARIOS[0], HELD_OUT_SCENARIO])
    ap.add_argument("--policies", nargs="+", default=list(POLICIES), choices=POLICIES)
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results_env_learned.md"))
    a = ap.parse_args()
    jobs = [(sc, p, a.episodes, a.model) for sc in a.scenarios for p in a.policies]
    jobs.sort(key=lambda job: job[1] != "greedy")   # the longest first
    start = time.monotonic()
    with ProcessPoolExecutor(a.workers) as pool:
        results = list(pool.map(run_policy, jobs))
    order = {(sc, p): k for k, (sc, p) in enumerate((sc, p) for sc in a.scenarios for p in a.policies)}
    results.sort(key=lambda r: order[(r["scenario"], r["policy"])])
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                            cwd=ROOT).stdout.strip()
    training = Path(a.model).with_name("training.json")
    trained = json.loads(training.read_text()) if training.is_file() else {}
    text = [
        "# twin/ActiveScan-v0: the learned policy against the baselines",
        "",
        f"`python -m benchmarks.bench_env_learned --model {a.model} --episodes {a.episodes}` at commit {commit} on "
        f"{platform.machine()}, {os.cpu_count()} cores, {time.monotonic() - start:.0f} s on {a.workers} workers.",
        "",
        f"The model: {trained.get('algorithm', '?')}, {trained.get('steps', '?')} environment steps in "
        f"{trained.get('wall_s', '?')} s (`{trained.get('command', '?')}`), trained on "
        f"{', '.join(trained.get('train_scenarios', []))}; held out: {trained.get('held_out_scenario', '?')}.",
        "",
        f"Episode i reset with seed {SEED_BASE} + i; at most 30 steps. Random, raster and greedy act on the box "
        "actions (greedy and raster read the CAD model and the estimate through `env.unwrapped`); the learned "
        "policy acts on the views actions and reads only the observation and `info[\"action_mask\"]`. "
        "Steps and motion time: all episodes (a failed one runs to the budget).",
        "",
        table(results),
        "",
    ]
    Path(a.out).write_text("\n".join(text))
    print("\n".join(text))


if __name__ == "__main__":
    main()

"""Train a policy for ``twin/ActiveScan-v0`` with PPO (stable-baselines3 and sb3-contrib, the
optional ``rl`` extra) and plot its learning curve.

``python -m benchmarks.train_ppo --minutes 45 --out benchmarks/ppo_active_scan`` trains on the
views action set (``actions="views"``: a ``Discrete(200)`` table of scan views) with episodes
drawn over ``TRAIN_SCENARIOS``, and writes in ``--out``: ``model.zip`` (the policy),
``training.json`` (every setting, the steps and wall time), ``monitor/*.monitor.csv`` (one row
per training episode: return, length, wall time) and ``learning_curve.png``.
``python -m benchmarks.bench_env_learned`` evaluates it against the baselines on held-out seeds.

Why PPO with action masks (sb3-contrib's ``MaskablePPO``): the views are a small discrete set,
so the policy is a categorical distribution over them and needs no exploration noise tuned to a
continuous box; the environment says which views the arm reaches (``info["action_mask"]``,
``action_masks()``), and masking them out of the distribution spends no samples on views that
can only cost. The observation is bounded in [-1, 1] by construction: no ``VecNormalize`` of
observations; rewards (tens of nats) are scaled by a running estimate of the return's spread.

Install the extra first: ``pip install -e ".[rl]"``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

#: The parts training episodes are drawn over; HELD_OUT_SCENARIO is never seen in training.
TRAIN_SCENARIOS = ("bracket.toml", "cast_blank.toml", "cube.toml")
HELD_OUT_SCENARIO = "bore_and_face.toml"
#: PPO's settings (the rest are stable-baselines3's defaults).
PPO_SETTINGS: dict[str, Any] = {"n_steps": 128, "batch_size": 64, "n_epochs": 10, "learning_rate": 3e-4, "gamma": 0.99,
                "gae_lambda": 0.95, "ent_coef": 0.01, "clip_range": 0.2,
                "policy_kwargs": {"net_arch": {"pi": [128, 128], "vf": [128, 128]}}}


def make_env(scenarios, seed: int, monitor_dir: Path | None = None, rank: int = 0):
    """A factory of one flattened views environment (for a vector environment)."""

    def thunk():
        import gymnasium as gym
        from gymnasium.wrappers import FlattenObservation
        from stable_baselines3.common.monitor import Monitor

        import twin  # noqa: F401  (registers the environments)

        env = FlattenObservation(gym.make("twin/ActiveScan-v0", scenarios=list(scenarios), actions="views"))
        if monitor_dir is not None:
            env = Monitor(env, str(monitor_dir / f"{rank}"))
        env.reset(seed=seed + rank)
        env.action_space.seed(seed + rank)
        return env

    return thunk


class LearnedPolicy:
    """A trained model as a policy: reads the observation (flattened) and what the environment
    returns in ``info``: the action mask, and whether its last view measured nothing (that view
    is then masked for the rest of the episode, as the greedy baseline passes over what
    measured nothing: a deterministic policy would otherwise choose it again). Deterministic."""

    name = "learned"

    def __init__(self, model_path: str):
        from sb3_contrib import MaskablePPO

        self.model = MaskablePPO.load(model_path, device="cpu")
        self.reset()

    def reset(self) -> None:
        self.failed: set[int] = set()
        self.last: int | None = None

    def __call__(self, observation: dict, info: dict) -> int:
        from twin.env.observation import flat

        if self.last is not None and "unreachable" in info:
            self.failed.add(self.last)
        mask = np.asarray(info["action_mask"], dtype=bool).copy()
        mask[list(self.failed)] = False
        if not mask.any():
            mask = np.asarray(info["action_mask"], dtype=bool)
        action, _ = self.model.predict(flat(observation), deterministic=True, action_masks=mask)
        self.last = int(action)
        return self.last


def learning_curve(monitor_dir: Path, png: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = []
    for f in sorted(monitor_dir.glob("*.monitor.csv")):
        r = np.genfromtxt(f, delimiter=",", skip_header=2, ndmin=2)   # columns r, l, t
        rows.append(r[:, :3])
    data = np.vstack(rows)
    data = data[np.argsort(data[:, 2])]   # by wall time, across the workers
    steps = np.cumsum(data[:, 1])
    ret = data[:, 0]
    window = max(1, len(ret) // 25)
    mean = np.convolve(ret, np.ones(window) / window, mode="valid")
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot(steps, ret, ".", alpha=0.25, label="episode return")
    ax.plot(steps[window - 1:], mean, "-", label=f"moving mean ({window} episodes)")
    ax.set(xlabel="environment steps", ylabel="return (nats less motion cost)", title=title)
    ax.legend()
    fig.tight_layout()
    fig.savefig(png, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=45.0, help="wall-clock training budget")
    ap.add_argument("--max-steps", type=int, default=200_000, help="environment steps at most")
    ap.add_argument("--envs", type=int, default=2, help="environments in parallel processes")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="benchmarks/ppo_active_scan")
    a = ap.parse_args()
    import torch
    from sb3_contrib import MaskablePPO
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import SubprocVecEnv, VecNormalize

    torch.set_num_threads(1)   # a small network: threads only contend with the simulation
    out = Path(a.out)
    monitor_dir = out / "monitor"
    monitor_dir.mkdir(parents=True, exist_ok=True)
    for old in monitor_dir.glob("*.monitor.csv"):
        old.unlink()
    venv = SubprocVecEnv([make_env(TRAIN_SCENARIOS, a.seed, monitor_dir, k) for k in range(a.envs)],
                         start_method="forkserver")
    scaled = VecNormalize(venv, norm_obs=False, norm_reward=True, gamma=PPO_SETTINGS["gamma"])
    model = MaskablePPO("MlpPolicy", scaled, seed=a.seed, device="cpu", verbose=0, **PPO_SETTINGS)
    deadline = time.monotonic() + 60.0 * a.minutes

    class Budget(BaseCallback):
        def _on_step(self) -> bool:
            return time.monotonic() < deadline

    start = time.monotonic()
    model.learn(total_timesteps=a.max_steps, callback=Budget())
    wall_s = time.monotonic() - start
    scaled.close()
    model.save(out / "model.zip")
    record = {"algorithm": "MaskablePPO (sb3-contrib)", "environment": "twin/ActiveScan-v0, actions='views'",
              "train_scenarios": list(TRAIN_SCENARIOS), "held_out_scenario": HELD_OUT_SCENARIO,
              "settings": PPO_SETTINGS, "envs": a.envs, "seed": a.seed, "steps": int(model.num_timesteps),
              "wall_s": round(wall_s, 1), "budget_minutes": a.minutes,
              "command": f"python -m benchmarks.train_ppo --minutes {a.minutes:g} --envs {a.envs} --seed {a.seed} "
                         f"--out {a.out}"}
    (out / "training.json").write_text(json.dumps(record, indent=2) + "\n")
    learning_curve(monitor_dir, out / "learning_curve.png",
                   f"MaskablePPO on twin/ActiveScan-v0 (views): {', '.join(s[:-5] for s in TRAIN_SCENARIOS)}")
    print(f"{model.num_timesteps} steps in {wall_s:.0f} s; wrote {out}/model.zip, training.json, learning_curve.png")


if __name__ == "__main__":
    main()

"""Train PPO (stable-baselines3, the optional ``rl`` extra) on ``twin/ActiveScan-v0`` and plot
its learning curve.

``python -m benchmarks.train_ppo --steps 20000 --out benchmarks/ppo_active_scan`` writes, in
``--out``: ``model.zip`` (the policy), ``vecnormalize.pkl`` (the observation scaling it was
trained with), ``monitor.monitor.csv`` (one row per training episode: reward, length, wall time) and
``learning_curve.png`` (episode return against environment steps, with a moving mean).
``python -m benchmarks.bench_env --ppo benchmarks/ppo_active_scan/model.zip`` adds the trained
policy to the baseline table. Install the extra first: ``pip install -e ".[rl]"``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


class PPOPolicy:
    """A trained PPO model as a baseline policy (deterministic actions)."""

    name = "ppo"

    def __init__(self, model_path: str):
        from stable_baselines3 import PPO

        self.model = PPO.load(model_path, device="cpu")
        stats = Path(model_path).with_name("vecnormalize.pkl")
        self.obs_rms = None
        if stats.is_file():
            import pickle

            with stats.open("rb") as f:
                vn = pickle.load(f)
            self.obs_rms, self.clip, self.eps = vn.obs_rms, vn.clip_obs, vn.epsilon

    def reset(self) -> None:
        pass

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        obs = np.asarray(observation, dtype=np.float64)
        if self.obs_rms is not None:
            obs = np.clip((obs - self.obs_rms.mean) / np.sqrt(self.obs_rms.var + self.eps), -self.clip, self.clip)
        action, _ = self.model.predict(obs.astype(np.float32), deterministic=True)
        return np.asarray(action, dtype=np.float64)


def learning_curve(monitor_csv: Path, png: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = np.genfromtxt(monitor_csv, delimiter=",", skip_header=2, ndmin=2)   # columns r, l, t
    steps = np.cumsum(rows[:, 1])
    ret = rows[:, 0]
    window = max(1, len(ret) // 20)
    mean = np.convolve(ret, np.ones(window) / window, mode="valid")
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot(steps, ret, ".", alpha=0.3, label="episode return")
    ax.plot(steps[window - 1:], mean, "-", label=f"moving mean ({window} episodes)")
    ax.set(xlabel="environment steps", ylabel="return (nats less motion cost)",
           title="PPO on twin/ActiveScan-v0 (bracket)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(png, dpi=120)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=20000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="benchmarks/ppo_active_scan")
    a = ap.parse_args()
    import gymnasium as gym
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.monitor import Monitor
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    import twin.env  # noqa: F401  (registers the environments)

    torch.set_num_threads(1)   # a small network: threads only contend with the simulation
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    venv = DummyVecEnv([lambda: Monitor(gym.make("twin/ActiveScan-v0", max_steps=20), str(out / "monitor"))])
    venv.seed(a.seed)
    venv = VecNormalize(venv, norm_obs=True, norm_reward=True)
    model = PPO("MlpPolicy", venv, n_steps=256, batch_size=64, learning_rate=3e-4, seed=a.seed, device="cpu",
                verbose=1)
    model.learn(total_timesteps=a.steps)
    model.save(out / "model.zip")
    venv.save(str(out / "vecnormalize.pkl"))
    learning_curve(out / "monitor.monitor.csv", out / "learning_curve.png")
    print(f"wrote {out}/model.zip, vecnormalize.pkl, monitor.monitor.csv, learning_curve.png")


if __name__ == "__main__":
    main()

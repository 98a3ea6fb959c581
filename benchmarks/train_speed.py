"""
Training speed of the manager against the flat baseline: environment steps per second of SB3 DDPG learning
on ``WorkerSelectionWrapper`` over two default-size workers, and on plain ``hddpg/SnakeReach-v0`` (what
``train-manager`` and ``train-flat`` train), with the same DDPG hyperparameters (the bundled config's flat
block), one torch thread, measured side by side in one process (interleaved rounds, medians).

Target (issue: speed): the manager reaches at least 0.9x the flat agent's steps per second. The manager's
action has 2 dimensions instead of 6, so its networks are a little smaller; everything else is the same.

    python benchmarks/train_speed.py [--steps 2000] [--rounds 3]
"""

from __future__ import annotations

import argparse
import statistics
import time

import gymnasium as gym
import torch
from stable_baselines3 import DDPG

import sb3_hddpg  # noqa: F401
from sb3_hddpg.hierarchy import WorkerSelectionWrapper
from sb3_hddpg.training.config import Hyperparams, load_hyperparams


def make_model(env: gym.Env, hyperparams: Hyperparams) -> DDPG:
    noise = hyperparams.action_noise(env.action_space.shape[0])
    model = DDPG(hyperparams.policy, env, seed=0, device="cpu", action_noise=noise, **hyperparams.algo_kwargs)
    model.learn(hyperparams.algo_kwargs.get("learning_starts", 100) + 200)  # warm-up: past learning_starts
    return model


def steps_per_second(model: DDPG, steps: int) -> float:
    start = time.perf_counter()
    model.learn(steps, reset_num_timesteps=False)
    return steps / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--steps", type=int, default=2000, help="learning steps per measurement")
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds (medians are reported)")
    args = parser.parse_args()
    torch.set_num_threads(1)

    flat_params = load_hyperparams("hddpg/SnakeReach-v0", DDPG)
    worker_params = load_hyperparams("hddpg/SnakeGoal-v0", DDPG)
    base = gym.make("hddpg/SnakeReach-v0")
    workers = {
        name: DDPG("MlpPolicy", base, policy_kwargs=worker_params.algo_kwargs["policy_kwargs"], seed=i)
        for i, name in enumerate(("goal", "avoid"))
    }
    models = {
        "train-flat (SnakeReach)": make_model(gym.make("hddpg/SnakeReach-v0"), flat_params),
        "train-manager (wrapper, sample)": make_model(
            WorkerSelectionWrapper(gym.make("hddpg/SnakeReach-v0"), workers), flat_params
        ),
    }
    rates: dict[str, list[float]] = {name: [] for name in models}
    for _ in range(args.rounds):
        for name, model in models.items():
            rates[name].append(steps_per_second(model, args.steps))
    medians = {name: statistics.median(values) for name, values in rates.items()}
    for name, value in medians.items():
        print(f"{name:34s} {value:7.1f} steps/s (median of {args.rounds})")
    flat, manager = medians.values()
    print(f"ratio manager / flat training steps per second: {manager / flat:.2f}x (target >= 0.9x)")


if __name__ == "__main__":
    main()

"""
Cost of a manager env step: ``WorkerSelectionWrapper`` over two DDPG workers of the default size, against a
plain ``hddpg/SnakeReach-v0`` step, measured side by side in one process (interleaved rounds, medians).

Target (issue: the manager): a manager step in sample or argmax mode costs at most 2x a plain env step.
Only the chosen worker runs in those modes, through its actor network under ``torch.no_grad()``.

    python benchmarks/manager_env_speed.py [--steps 4000] [--rounds 5]
"""

from __future__ import annotations

import argparse
import statistics
import time

import gymnasium as gym
import numpy as np
import torch
from rich.console import Console
from rich.table import Table
from stable_baselines3 import DDPG

import sb3_hddpg  # noqa: F401
from sb3_hddpg.hierarchy import WorkerSelectionWrapper
from sb3_hddpg.training.config import load_hyperparams


def seconds_per_step(env: gym.Env, actions: np.ndarray) -> float:
    env.reset(seed=0)
    start = time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    return (time.perf_counter() - start) / len(actions)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--steps", type=int, default=4000, help="steps per measurement")
    parser.add_argument("--rounds", type=int, default=5, help="interleaved rounds (medians are reported)")
    args = parser.parse_args()
    torch.set_num_threads(1)

    policy_kwargs = load_hyperparams("hddpg/SnakeGoal-v0", DDPG).algo_kwargs["policy_kwargs"]
    base = gym.make("hddpg/SnakeReach-v0")
    workers = {
        name: DDPG("MlpPolicy", base, policy_kwargs=policy_kwargs, seed=i)
        for i, name in enumerate(("goal", "avoid"))
    }
    rng = np.random.default_rng(0)
    envs = {
        "plain SnakeReach": (
            gym.make("hddpg/SnakeReach-v0"),
            rng.uniform(-1, 1, (args.steps, 6)).astype(np.float32),
        )
    }
    for mode in ("sample", "argmax", "mix"):
        env = WorkerSelectionWrapper(gym.make("hddpg/SnakeReach-v0"), workers, selection=mode)
        envs[f"manager ({mode})"] = (env, rng.uniform(-1, 1, (args.steps, 2)).astype(np.float32))

    times: dict[str, list[float]] = {name: [] for name in envs}
    for _ in range(args.rounds):
        for name, (env, actions) in envs.items():
            times[name].append(seconds_per_step(env, actions))
    medians = {name: statistics.median(values) for name, values in times.items()}
    plain = medians["plain SnakeReach"]
    table = Table(
        title=f"{args.steps} steps x {args.rounds} rounds, 1 torch thread, workers {policy_kwargs['net_arch']}"
    )
    table.add_column("env")
    table.add_column("µs/step (median)", justify="right")
    table.add_column("x plain step", justify="right")
    for name, value in medians.items():
        table.add_row(name, f"{value * 1e6:.1f}", f"{value / plain:.2f}")
    Console().print(table)
    worst = max(medians["manager (sample)"], medians["manager (argmax)"]) / plain
    print(f"ratio manager step (sample/argmax, worst) / plain step: {worst:.2f}x (target <= 2x)")


if __name__ == "__main__":
    main()

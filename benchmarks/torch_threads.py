"""
SB3 DDPG training speed on this machine with 1 vs 2 torch threads, measured side by side in one run.

Small MLPs spend more time in thread synchronisation than in arithmetic, so one thread is expected to win;
this script measures it rather than assuming (interleaved rounds, medians).

    python benchmarks/torch_threads.py [--steps 3000] [--rounds 3] [--net 64,64]
"""

from __future__ import annotations

import argparse
import statistics
import time

import gymnasium as gym
import torch
from stable_baselines3 import DDPG

import sb3_hddpg  # noqa: F401


def steps_per_second(threads: int, steps: int, net: list[int]) -> float:
    torch.set_num_threads(threads)
    model = DDPG(
        "MlpPolicy",
        gym.make("hddpg/SnakeGoal-v0"),
        learning_starts=200,
        batch_size=128,
        policy_kwargs={"net_arch": net},
        seed=0,
    )
    model.learn(300)  # warm-up: buffers, first optimiser steps
    start = time.perf_counter()
    model.learn(steps, reset_num_timesteps=False)
    return steps / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--net", default="64,64", help="hidden layer sizes")
    args = parser.parse_args()
    net = [int(x) for x in args.net.split(",")]
    results: dict[int, list[float]] = {1: [], 2: []}
    for _ in range(args.rounds):
        for threads in (1, 2):
            results[threads].append(steps_per_second(threads, args.steps, net))
    one, two = statistics.median(results[1]), statistics.median(results[2])
    print(f"net {net}: 1 thread {one:.0f} steps/s, 2 threads {two:.0f} steps/s (medians of {args.rounds})")
    print(f"ratio 1-thread / 2-thread training speed: {one / two:.2f}x")


if __name__ == "__main__":
    main()

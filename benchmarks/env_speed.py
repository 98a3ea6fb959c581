"""
Environment step speed: ``hddpg/SnakeReach-v0`` against gymnasium's ``Pendulum-v1``, in one process.

Both environments are built with ``gym.make`` (so both carry the same wrappers: the passive env checker,
order enforcing and the time limit) and stepped with random actions sampled before timing. Only
``env.step`` calls are timed: every episode's ``reset`` happens outside the clock.

The machine may be noisy, so the two environments are timed interleaved, episode by episode (a Pendulum
episode, a Snake episode, a Pendulum episode, ...), which exposes both to the same background load, in
several rounds after one untimed warm-up round. The table reports each environment's median and fastest
round; the last line is the ratio of the median step times (the target of the speed issue is at most
1.5x).

Usage::

    python benchmarks/env_speed.py                 # 5 rounds of 20 000 steps per environment
    python benchmarks/env_speed.py --steps 5000 --rounds 9
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time

import gymnasium as gym
import numpy as np
from rich.console import Console
from rich.table import Table

import sb3_hddpg  # noqa: F401  (registers the hddpg/ ids)

SNAKE_ID = "hddpg/SnakeReach-v0"
PENDULUM_ID = "Pendulum-v1"
TARGET_RATIO = 1.5


def episodes(env: gym.Env, actions: np.ndarray) -> list[np.ndarray]:
    """``actions`` cut into episodes of the env's time limit."""
    limit = env.spec.max_episode_steps if env.spec and env.spec.max_episode_steps else len(actions)
    return [actions[i : i + limit] for i in range(0, len(actions), limit)]


def time_episode(env: gym.Env, actions: np.ndarray, seed: int) -> float:
    """Reset (untimed), then the seconds spent stepping through ``actions``."""
    env.reset(seed=seed)
    step = env.step
    start = time.perf_counter()
    for action in actions:
        step(action)
    return time.perf_counter() - start


def time_round(envs: dict[str, gym.Env], actions: dict[str, np.ndarray], seed: int) -> dict[str, float]:
    """Seconds per step of each env over all its actions, the envs' episodes interleaved."""
    chunks = {env_id: episodes(env, actions[env_id]) for env_id, env in envs.items()}
    elapsed = dict.fromkeys(envs, 0.0)
    for k in range(max(len(c) for c in chunks.values())):
        for env_id, env in envs.items():
            if k < len(chunks[env_id]):
                elapsed[env_id] += time_episode(env, chunks[env_id][k], seed + k)
    return {env_id: elapsed[env_id] / len(actions[env_id]) for env_id in envs}


def main(argv: list[str] | None = None) -> float:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter, prog="env_speed.py"
    )
    parser.add_argument("--steps", type=int, default=20_000, help="steps per round and env (20000)")
    parser.add_argument("--rounds", type=int, default=5, help="timed rounds (5)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the actions and the resets (0)")
    args = parser.parse_args(argv)
    if args.steps < 1 or args.rounds < 1:
        parser.error("--steps and --rounds must be at least 1")

    envs = {PENDULUM_ID: gym.make(PENDULUM_ID), SNAKE_ID: gym.make(SNAKE_ID)}
    actions = {}
    for env_id, env in envs.items():
        env.action_space.seed(args.seed)
        actions[env_id] = np.array([env.action_space.sample() for _ in range(args.steps)])

    # One untimed warm-up round (first-step env checks, caches, lazy imports), then the timed rounds.
    time_round(envs, {env_id: a[:2000] for env_id, a in actions.items()}, args.seed)
    per_step: dict[str, list[float]] = {env_id: [] for env_id in envs}
    for _ in range(args.rounds):
        for env_id, seconds in time_round(envs, actions, args.seed).items():
            per_step[env_id].append(seconds)

    table = Table(
        title=f"env step time: {args.rounds} rounds x {args.steps} random-action steps per env, "
        f"Python {platform.python_version()}"
    )
    table.add_column("env")
    table.add_column("median us/step", justify="right")
    table.add_column("min us/step", justify="right")
    table.add_column("median steps/s", justify="right")
    table.add_column("us/step per round", justify="left")
    medians = {}
    for env_id, times in per_step.items():
        medians[env_id] = statistics.median(times)
        table.add_row(
            env_id,
            f"{medians[env_id] * 1e6:.1f}",
            f"{min(times) * 1e6:.1f}",
            f"{1.0 / medians[env_id]:,.0f}",
            " ".join(f"{t * 1e6:.1f}" for t in times),
        )
    Console(width=120).print(table)
    rounds = [s / p for s, p in zip(per_step[SNAKE_ID], per_step[PENDULUM_ID])]
    print("ratio per round: " + " ".join(f"{r:.2f}" for r in rounds))
    print(f"ratio of the fastest rounds: {min(per_step[SNAKE_ID]) / min(per_step[PENDULUM_ID]):.2f}x")
    ratio = medians[SNAKE_ID] / medians[PENDULUM_ID]
    print(f"ratio SnakeReach/Pendulum step time: {ratio:.2f}x (target <= {TARGET_RATIO}x)")
    return ratio


if __name__ == "__main__":
    main()

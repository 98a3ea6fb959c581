"""
Environment step speed: ``hddpg/SnakeReach-v0`` against gymnasium's ``Pendulum-v1``, in one process.

Both environments are built with ``gym.make`` (so both carry the same wrappers: the passive env checker,
order enforcing and the time limit) and stepped with random actions sampled before timing. Only
``env.step`` calls are timed: each episode's ``reset`` happens outside the clock, the loop steps up to the
time limit, then resets. The machine may be noisy, so the two environments are timed in alternating
rounds (Pendulum, Snake, Pendulum, Snake, ...) after one untimed warm-up round, and the table reports
the median and the fastest round of each. The last line is the ratio of the median step times; the
target of the speed issue is at most 1.5x.

Usage::

    python benchmarks/env_speed.py                 # 5 rounds of 20 000 steps each
    python benchmarks/env_speed.py --steps 5000 --rounds 3
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


def time_steps(env: gym.Env, actions: np.ndarray, seed: int) -> float:
    """Seconds spent in ``env.step`` over all ``actions``, resetting (untimed) at every episode's end."""
    limit = env.spec.max_episode_steps if env.spec and env.spec.max_episode_steps else len(actions)
    step = env.step
    perf_counter = time.perf_counter
    elapsed = 0.0
    done = 0
    episode = 0
    while done < len(actions):
        env.reset(seed=seed + episode)
        episode += 1
        chunk = actions[done : done + limit]
        start = perf_counter()
        for action in chunk:
            step(action)
        elapsed += perf_counter() - start
        done += len(chunk)
    return elapsed


def main(argv: list[str] | None = None) -> float:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter, prog="env_speed.py"
    )
    parser.add_argument("--steps", type=int, default=20_000, help="env steps per round and env (20000)")
    parser.add_argument("--rounds", type=int, default=5, help="timed rounds per env, alternating (5)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the actions and the resets (0)")
    args = parser.parse_args(argv)
    if args.steps < 1 or args.rounds < 1:
        parser.error("--steps and --rounds must be at least 1")

    envs = {PENDULUM_ID: gym.make(PENDULUM_ID), SNAKE_ID: gym.make(SNAKE_ID)}
    actions = {}
    for env_id, env in envs.items():
        env.action_space.seed(args.seed)
        actions[env_id] = np.array([env.action_space.sample() for _ in range(args.steps)])

    # One untimed warm-up round (first-step env checks, caches, lazy imports), then alternating rounds.
    for env_id, env in envs.items():
        time_steps(env, actions[env_id][: min(args.steps, 2000)], args.seed)
    per_step: dict[str, list[float]] = {env_id: [] for env_id in envs}
    for _ in range(args.rounds):
        for env_id, env in envs.items():
            per_step[env_id].append(time_steps(env, actions[env_id], args.seed) / args.steps)

    console = Console(width=120)
    table = Table(
        title=f"env step speed: {args.rounds} rounds x {args.steps} random-action steps, "
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
    console.print(table)
    paired = [s / p for s, p in zip(per_step[SNAKE_ID], per_step[PENDULUM_ID])]
    print(
        "per-round ratios (Snake round / the Pendulum round just before it): "
        + " ".join(f"{r:.2f}" for r in paired)
    )
    ratio = medians[SNAKE_ID] / medians[PENDULUM_ID]
    print(f"ratio SnakeReach/Pendulum step time: {ratio:.2f}x (target <= {TARGET_RATIO}x)")
    return ratio


if __name__ == "__main__":
    main()

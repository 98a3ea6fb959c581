"""
What can a preference factor change? Before training biased managers (paper Section 3.4), look at the
objective they will maximise: evaluate fixed selection policies over the same two trained workers and score
each under the goal- and the avoid-preferred manager reward.

Two families of selection policies are swept: constant mixtures (the goal worker acts with probability p,
whatever the state) and HAM switches (the avoid worker acts when the summed joint-obstacle distances fall
under a threshold; a state-dependent policy of the kind a manager can learn). For each preference the best
policy of the sweep is marked. If both preferences pick the same policy, a manager trained with that bias
has nothing to gain from behaving differently, and biased training cannot separate the managers; the
smallest bias at which the best policies part shows how strong a preference this env needs.

    python studies/preference_landscape.py --workers runs/workers [--episodes 20] [--bias 0.15 1 3]
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from rich.console import Console
from rich.table import Table

import sb3_hddpg  # noqa: F401  (registers the env ids)
from sb3_hddpg import WorkerSelectionWrapper, evaluate
from sb3_hddpg.artifacts.manifests import load_workers
from sb3_hddpg.baselines.ham import HAMSwitch


def normalised_returns(summary: dict[str, Any], bounds: dict[str, tuple[float, float]]) -> dict[str, float]:
    """Per-episode sums of each normalised term, from the mean raw sums (normalisation is affine per step)."""
    length = summary["mean_length"]
    out = {}
    for term in ("goal", "avoid"):
        low, high = bounds[term]
        out[term] = (summary[f"mean_{term}_reward"] - low * length) / (high - low)
    return out


def evaluate_mixture(workers: dict[str, Any], p_goal: float, episodes: int) -> dict[str, Any]:
    # A manager action whose simplex map gives exactly (p, 1 - p): floor 0, temperature 1, a = logit/2 each.
    env = WorkerSelectionWrapper(
        gym.make("hddpg/SnakeReach-v0"),
        {"goal": workers["goal"], "avoid": workers["avoid"]},
        temperature=1.0,
        floor=0.0,
    )
    p = min(max(p_goal, 1e-6), 1 - 1e-6)
    half_logit = float(np.clip(np.log(p / (1 - p)) / 2, -1.0, 1.0))
    action = np.array([half_logit, -half_logit], dtype=np.float32)
    result = evaluate(_FixedAction(action), env, n_episodes=episodes, deterministic=False).summary()
    env.close()
    return result


class _FixedAction:
    """A manager that always outputs the same action (sampling then draws the worker)."""

    def __init__(self, action: np.ndarray) -> None:
        self.action = action

    def predict(self, obs: np.ndarray, deterministic: bool = True) -> tuple[np.ndarray, None]:
        return self.action, None


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--workers", type=Path, default=Path("runs/workers"), help="a train-workers run folder"
    )
    parser.add_argument(
        "--episodes", type=int, default=20, help="evaluation episodes per policy (fixed seeds)"
    )
    parser.add_argument(
        "--bias",
        type=float,
        nargs="+",
        default=[0.15, 1.0, 3.0],
        help="preference biases to score (0.15: paper)",
    )
    args = parser.parse_args()

    workers = load_workers(args.workers)
    env = gym.make("hddpg/SnakeReach-v0")
    bounds = env.unwrapped.reward_bounds
    layout = env.unwrapped.state_layout
    policies: list[tuple[str, Callable[[], dict[str, Any]]]] = []
    for p in (1.0, 0.75, 0.5, 0.25, 0.0):
        policies.append((f"mixture p(goal)={p:.2f}", lambda p=p: evaluate_mixture(workers, p, args.episodes)))
    for threshold in (3.0, 4.0, 5.0, 5.25, 5.5, 5.75, 6.0):
        switch = HAMSwitch(workers["goal"], workers["avoid"], layout, threshold=threshold)
        policies.append(
            (
                f"HAM threshold {threshold:.2f}",
                lambda s=switch: evaluate(s, env, n_episodes=args.episodes).summary(),
            )
        )

    rows = []
    for name, run in policies:
        summary = run()
        rows.append((name, summary, normalised_returns(summary, bounds)))

    table = Table(title=f"Selection policies over {args.workers}, {args.episodes} episodes each")
    for column in ("policy", "goal (norm.)", "avoid (norm.)", "touch %", "collisions/ep"):
        table.add_column(
            column, justify="left" if column == "policy" else "right", no_wrap=column == "policy"
        )
    for bias in args.bias:
        table.add_column(f"R goal-pref {bias:g}", justify="right")
        table.add_column(f"R avoid-pref {bias:g}", justify="right")
    best = {}
    for bias in args.bias:
        for prefer in ("goal", "avoid"):
            scores = [
                (1 + bias if prefer == "goal" else 1) * n["goal"]
                + (1 + bias if prefer == "avoid" else 1) * n["avoid"]
                for _, _, n in rows
            ]
            best[(bias, prefer)] = (int(np.argmax(scores)), scores)
    for index, (name, summary, n) in enumerate(rows):
        cells = [
            name,
            f"{n['goal']:.1f}",
            f"{n['avoid']:.1f}",
            f"{100 * summary['goal_touch_rate']:.1f}",
            f"{summary['collisions_per_episode']:.2f}",
        ]
        for bias in args.bias:
            for prefer in ("goal", "avoid"):
                top, scores = best[(bias, prefer)]
                cells.append(
                    f"[bold green]{scores[index]:.1f}*[/]" if index == top else f"{scores[index]:.1f}"
                )
        table.add_row(*cells)
    console = Console(width=max(Console().width, 150))  # the table is wide: do not fold it
    console.print(table)
    for bias in args.bias:
        goal_best, avoid_best = rows[best[(bias, "goal")][0]][0], rows[best[(bias, "avoid")][0]][0]
        verdict = "the same policy" if goal_best == avoid_best else "different policies"
        console.print(
            f"bias {bias:g}: goal-preferred best = {goal_best}; avoid-preferred best = {avoid_best} ({verdict})"
        )


if __name__ == "__main__":
    main()

"""
Where a goal-reaching policy loses its touches (docs/WORKERS.md, "Reaching is not the problem, holding is"):
per policy, on the benchmark's held-out test episodes of the goal task, how soon it first touches the goal,
how close it stays afterwards (the share of steps with the tip within 1, 1.5, 2 and 3 touch radii, and the
median distance), how large its joint commands are, and how they compare with the IK reacher's command for
the same observation (the median cosine between the two, and the median projection of the policy's command
onto the reacher's: 1 is the reacher's size, 0.5 half of it).

    python studies/goal_holding.py docs/results/models/seed-0/workers/goal.zip ik

Each argument is what ``hddpg-cli evaluate`` takes: a worker or flat zip with its manifest (loaded
weights-only, on the env and state view it was trained with), or ``ik`` / ``scripted`` / ``random``.
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import numpy as np
import torch
from rich.console import Console
from rich.table import Table

import sb3_hddpg  # noqa: F401  (registers the env ids)
from sb3_hddpg.baselines import IKReacher
from sb3_hddpg.hierarchy.loading import load_policy

GOAL_ENV_ID = "hddpg/SnakeGoal-v0"
#: The benchmark's held-out test episodes.
TEST_SEED = 15000
#: Distances reported, in touch radii.
RADII = (1.0, 1.5, 2.0, 3.0)


def holding(policy: object, env: gym.Env, episodes: int, seed: int) -> dict[str, float]:
    """
    Run ``policy`` deterministically on ``episodes`` episodes from ``seed`` on and measure how it holds the goal.

    :return: ``within_<k>`` (share of steps with the tip within k touch radii), ``median_distance``,
        ``first_touch`` (median step of the first touch; the episode length where it never touches),
        ``mean_command`` (mean absolute joint command), ``ik_cosine`` and ``ik_projection`` (medians over the
        steps where the reacher commands anything).
    """
    snake = env.unwrapped
    radius = float(snake.touch_radius)  # type: ignore[attr-defined]
    observed = getattr(snake, "observed_components", None)
    layout = snake.state_layout.view(observed) if observed else snake.state_layout  # type: ignore[attr-defined]
    reacher = IKReacher(layout, max_joint_speed=snake.max_joint_speed)  # type: ignore[attr-defined]
    distances, first_touches, commands, cosines, projections = [], [], [], [], []
    for episode in range(episodes):
        obs, _ = env.reset(seed=seed + episode)
        episode_distances = []
        done = False
        while not done:
            action, _ = policy.predict(obs, deterministic=True)  # type: ignore[attr-defined]
            commands.append(float(np.abs(action).mean()))
            teacher = reacher.predict(obs)[0]
            size = float(np.dot(teacher, teacher))
            if size > 1e-12:
                cosines.append(
                    float(np.dot(action, teacher)) / np.sqrt(size * float(np.dot(action, action)) + 1e-12)
                )
                projections.append(float(np.dot(action, teacher)) / size)
            obs, _, terminated, truncated, info = env.step(action)
            episode_distances.append(float(info["distance_to_goal"]))
            done = terminated or truncated
        touched = np.flatnonzero(np.asarray(episode_distances) <= radius)
        first_touches.append(int(touched[0]) + 1 if touched.size else len(episode_distances))
        distances.extend(episode_distances)
    d = np.asarray(distances)
    return {
        **{f"within_{k:g}": float(np.mean(d <= k * radius)) for k in RADII},
        "median_distance": float(np.median(d)),
        "first_touch": float(np.median(first_touches)),
        "mean_command": float(np.mean(commands)),
        "ik_cosine": float(np.median(cosines)) if cosines else float("nan"),
        "ik_projection": float(np.median(projections)) if projections else float("nan"),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("policies", nargs="+", help="worker/flat zips, or ik, scripted, random")
    p.add_argument("--episodes", type=int, default=20, help="test episodes per policy")
    p.add_argument("--seed", type=int, default=TEST_SEED, help="seed of the first test episode")
    args = p.parse_args()
    torch.set_num_threads(1)

    table = Table(title=f"Holding the goal: {args.episodes} episodes of {GOAL_ENV_ID} from seed {args.seed}")
    table.add_column("policy", overflow="fold")
    for k in RADII:
        table.add_column(f"within {k:g} r", justify="right")
    for name in ("median distance", "first touch (step)", "mean |command|", "cos to IK", "size vs IK"):
        table.add_column(name, justify="right")
    for path in args.policies:
        loaded = load_policy(path, env_id=GOAL_ENV_ID)
        # A worker acts on the env (and state view) it was trained with; a reference policy on the goal task.
        env = loaded.make_env(GOAL_ENV_ID)
        result = holding(loaded.policy, env, args.episodes, args.seed)
        env.close()
        table.add_row(
            path,
            *(f"{100 * result[f'within_{k:g}']:.1f} %" for k in RADII),
            f"{result['median_distance']:.3f}",
            f"{result['first_touch']:.0f}",
            f"{result['mean_command']:.2f}",
            f"{result['ik_cosine']:.2f}",
            f"{result['ik_projection']:.2f}",
        )
    Console(width=160).print(table)


if __name__ == "__main__":
    main()

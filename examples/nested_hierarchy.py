"""
A two-level HDDPG (paper design specification 3: "each DDPG or DDPG group can become a sub layer of
another DDPG"): a trained hierarchy (manager over goal and avoid workers) becomes one worker of a higher
manager, beside the plain avoid worker, and the whole tree saves and loads as one bundle.

    python examples/nested_hierarchy.py --hierarchy runs/manager/hierarchy.zip --workers runs/workers \
        --timesteps 5000 --out runs/nested.zip

Without ``--hierarchy`` it first trains tiny workers and a tiny manager, so it runs anywhere in a minute.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import gymnasium as gym
import torch
from stable_baselines3 import DDPG

import sb3_hddpg  # noqa: F401  (registers the env ids)
from sb3_hddpg import Hierarchy, SelectionConfig, WorkerSelectionWrapper, evaluate
from sb3_hddpg.artifacts.manifests import load_workers
from sb3_hddpg.training.manager import train_manager
from sb3_hddpg.training.workers import train_workers


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--hierarchy", type=Path, help="a trained hierarchy.zip (default: train a tiny one)")
    parser.add_argument("--workers", type=Path, help="the train-workers run folder it was trained on")
    parser.add_argument("--timesteps", type=int, default=2000, help="steps for the top manager")
    parser.add_argument(
        "--out", type=Path, default=Path("runs/nested.zip"), help="where to save the two-level bundle"
    )
    args = parser.parse_args()
    torch.set_num_threads(1)

    if args.hierarchy is None:
        scratch = Path(tempfile.mkdtemp(prefix="nested-"))
        train_workers(scratch / "w", timesteps=1000, eval_freq=0, eval_episodes=1)
        train_manager(scratch / "w", scratch / "m", timesteps=1000, eval_freq=0, eval_episodes=1)
        args.hierarchy, args.workers = scratch / "m" / "hierarchy.zip", scratch / "w"

    lower = Hierarchy.load(args.hierarchy)
    avoid = load_workers(args.workers, ["avoid"])["avoid"]
    workers = {"reach": lower, "avoid": avoid}
    config = SelectionConfig(preferences={"reach": 1.0, "avoid": 1.0}, selection="sample")
    env = WorkerSelectionWrapper(gym.make("hddpg/SnakeReach-v0"), workers, **config.wrapper_kwargs())
    print("the lower hierarchy's reward as a worker:", env.reward_specs["reach"])
    top = DDPG("MlpPolicy", env, policy_kwargs={"net_arch": [64, 64]}, learning_starts=500, seed=0)
    top.learn(args.timesteps)

    nested = Hierarchy(top, workers, config)
    nested.save(args.out)
    reloaded = Hierarchy.load(args.out)
    summary = evaluate(reloaded, gym.make("hddpg/SnakeReach-v0"), n_episodes=5).summary()
    print(
        f"saved {args.out}; top-level choices: {summary.get('selection_rate')}; mean reach reward {summary['mean_reach_reward']:.1f}"
    )


if __name__ == "__main__":
    main()

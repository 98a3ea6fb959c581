"""
The manager study of docs/MANAGER.md: a DDPG manager over two saved workers, with or without the actor's
action penalty, scored on the held-out test episodes (seeds 15000-15019) with the state-dependence figure.

    python studies/manager_study.py --workers runs/w --action-l2 0.5 --steps 20000

``--workers`` is a ``train-workers`` run folder; each worker sees the state components it was trained on (its
manifest's ``observe``). Prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
import time

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import DDPG
from stable_baselines3.common.noise import NormalActionNoise

import sb3_hddpg  # noqa: F401  (registers the env ids)
from sb3_hddpg.artifacts.manifests import load_workers
from sb3_hddpg.callbacks import apply_action_l2
from sb3_hddpg.evaluation import evaluate, state_dependence
from sb3_hddpg.hierarchy import WorkerSelectionWrapper
from sb3_hddpg.hierarchy.hierarchy import Hierarchy, SelectionConfig


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--workers", required=True, help="a train-workers run folder (goal and avoid workers)")
    p.add_argument("--steps", type=int, default=20_000, help="manager training steps")
    p.add_argument("--action-l2", type=float, default=0.0, help="the manager actor's action penalty")
    p.add_argument("--temperature", type=float, default=0.5, help="the simplex map's temperature")
    p.add_argument(
        "--selection", default="sample", choices=["sample", "argmax", "mix"], help="selection mode"
    )
    p.add_argument("--gamma", type=float, default=0.9, help="the manager's discount")
    p.add_argument("--noise", type=float, default=0.3, help="std of the manager's Gaussian action noise")
    p.add_argument("--seed", type=int, default=0, help="training seed")
    p.add_argument("--test-episodes", type=int, default=20, help="held-out test episodes")
    args = p.parse_args()
    torch.set_num_threads(1)

    workers = load_workers(args.workers, ["goal", "avoid"])
    config = SelectionConfig(
        preferences={"goal": 1.0, "avoid": 1.0},
        selection=args.selection,
        temperature=args.temperature,
        worker_states=workers.states,
    )
    env = WorkerSelectionWrapper(gym.make("hddpg/SnakeReach-v0"), workers, **config.wrapper_kwargs())
    model = DDPG(
        "MlpPolicy",
        env,
        learning_rate=1e-3,
        buffer_size=200_000,
        learning_starts=1000,
        batch_size=128,
        tau=0.005,
        gamma=args.gamma,
        action_noise=NormalActionNoise(np.zeros(2), args.noise * np.ones(2)),
        policy_kwargs={"net_arch": [64, 64]},
        seed=args.seed,
        device="cpu",
    )
    if args.action_l2 > 0:
        apply_action_l2(model, args.action_l2)
    start = time.time()
    model.learn(args.steps)
    hierarchy = Hierarchy(model, workers, config, env_id="hddpg/SnakeReach-v0")
    summary = evaluate(
        hierarchy, gym.make("hddpg/SnakeReach-v0"), n_episodes=args.test_episodes, seed=15000
    ).summary()
    keys = (
        "mean_reach_reward",
        "goal_touch_rate",
        "collisions_per_episode",
        "action_saturation",
        "selection_rate",
    )
    print(
        json.dumps(
            {
                "args": vars(args),
                "seconds": round(time.time() - start),
                **{k: summary[k] for k in keys if k in summary},
                "state_dependence": state_dependence(summary, "avoid"),
            }
        ),
        flush=True,
    )


if __name__ == "__main__":
    main()

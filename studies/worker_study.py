"""
The goal-worker study of docs/WORKERS.md: one worker, one set of learning settings, its evaluation curve and
its score on the held-out test episodes (seeds 15000-15019), printed as JSON lines.

    python studies/worker_study.py --observe goal --noise 0.1 --gamma 0.7 --relabel 0.8 --action-l2 0.5

Each flag maps to what the library offers: ``--observe goal`` is the env kwarg ``observe`` (the goal worker's
15 values), ``--relabel`` the :class:`~sb3_hddpg.goal_relabeling.GoalRelabelingReplayBuffer`, ``--action-l2``
the :class:`~sb3_hddpg.callbacks.ActionL2Penalty`. ``--backend sbx`` trains with SBX (JAX) where installed.
"""

from __future__ import annotations

import argparse
import json
import time

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.noise import NormalActionNoise

import sb3_hddpg  # noqa: F401  (registers the env ids)
from sb3_hddpg.callbacks import apply_action_l2
from sb3_hddpg.evaluation import evaluate
from sb3_hddpg.goal_relabeling import GoalRelabelingReplayBuffer
from sb3_hddpg.training.backends import sbx_class
from sb3_hddpg.training.config import parse_schedule
from sb3_hddpg.training.sbx_models import sbx_kwargs

ENV_IDS = {"goal": "hddpg/SnakeGoal-v0", "avoid": "hddpg/SnakeAvoid-v0", "reach": "hddpg/SnakeReach-v0"}
VIEWS = {"all": None, "goal": ["joint_positions", "ee_to_goal", "goal_touched"]}
#: The held-out test episodes of the benchmark, and the episodes of the curve.
TEST_SEED, CURVE_SEED = 15000, 14000


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", default="goal", choices=sorted(ENV_IDS), help="which reward the worker learns")
    p.add_argument(
        "--algo",
        default="ddpg",
        choices=["ddpg", "td3", "sac"],
        help="the worker's algorithm (sac: no action noise or penalty; its entropy term explores)",
    )
    p.add_argument("--backend", default="sb3", choices=["sb3", "sbx"], help="torch (sb3) or JAX (sbx)")
    p.add_argument("--steps", type=int, default=40_000, help="training env steps")
    p.add_argument("--gamma", type=float, default=0.9, help="discount")
    p.add_argument("--noise", type=float, default=0.3, help="std of the Gaussian action noise")
    p.add_argument("--observe", default="all", choices=sorted(VIEWS), help="state components the worker sees")
    p.add_argument(
        "--relabel", type=float, default=0.0, help="share of replayed samples with a hindsight goal"
    )
    p.add_argument("--action-l2", type=float, default=0.0, help="actor action penalty (0: none)")
    p.add_argument("--net", default="64,64", help="hidden layer sizes of actor and critic, comma-separated")
    p.add_argument("--lr", type=float, default=1e-3, help="learning rate of actor and critic")
    p.add_argument(
        "--lr-schedule",
        default="constant",
        choices=["constant", "linear"],
        help="constant, or linear: from --lr at the start to 0 at the end of the run (RL Zoo's lin_)",
    )
    p.add_argument(
        "--train-freq",
        type=int,
        default=1,
        help="env steps between updates, with as many gradient steps times --updates-per-step",
    )
    p.add_argument(
        "--updates-per-step", type=int, default=1, help="gradient steps per env step (the replay ratio)"
    )
    p.add_argument("--batch-size", type=int, default=128, help="transitions per gradient step")
    p.add_argument("--seed", type=int, default=0, help="training seed")
    p.add_argument("--eval-every", type=int, default=10_000, help="steps between curve points (5 episodes)")
    p.add_argument("--curve-episodes", type=int, default=5, help="episodes per curve point")
    p.add_argument("--test-episodes", type=int, default=20, help="held-out test episodes at the end")
    p.add_argument(
        "--test-each-point",
        action="store_true",
        help="also score every curve point on the held-out test episodes (how well a curve point picks a model)",
    )
    p.add_argument("--save", default="", help="save the final model here (an SB3 zip for --backend sb3)")
    args = p.parse_args()
    torch.set_num_threads(1)

    def make() -> gym.Env:
        view = VIEWS[args.observe]
        return gym.make(ENV_IDS[args.task], **({"observe": view} if view else {}))

    env, eval_env = make(), make()
    kwargs = dict(
        learning_rate=args.lr if args.lr_schedule == "constant" else parse_schedule(f"lin_{args.lr}", "--lr"),
        buffer_size=200_000,
        learning_starts=1000,
        batch_size=args.batch_size,
        tau=0.005,
        train_freq=args.train_freq,
        gradient_steps=args.train_freq * args.updates_per_step,
        gamma=args.gamma,
        seed=args.seed,
        policy_kwargs={"net_arch": [int(size) for size in args.net.split(",")]},
    )
    if args.algo == "sac":
        if args.action_l2 > 0:
            p.error("--action-l2 applies to DDPG and TD3 actors, not SAC")
    else:
        kwargs["action_noise"] = NormalActionNoise(np.zeros(6), args.noise * np.ones(6))
    if args.relabel > 0:
        kwargs["replay_buffer_class"] = GoalRelabelingReplayBuffer
        kwargs["replay_buffer_kwargs"] = {
            **GoalRelabelingReplayBuffer.env_kwargs(env),
            "relabel_fraction": args.relabel,
        }
    if args.backend == "sbx":
        # sbx_kwargs: the critic learns at --lr too (SBX's DDPG would keep it at 1e-3), and a schedule
        # reaches the optimisers.
        model = sbx_class(args.algo)("MlpPolicy", env, **sbx_kwargs(args.algo, kwargs))
    else:
        import stable_baselines3

        model = getattr(stable_baselines3, args.algo.upper())("MlpPolicy", env, device="cpu", **kwargs)
    if args.action_l2 > 0:
        apply_action_l2(model, args.action_l2)

    def score(episodes: int, seed: int) -> dict[str, float]:
        summary = evaluate(model, eval_env, n_episodes=episodes, seed=seed).summary()
        keys = ("mean_reward", "goal_touch_rate", "collisions_per_episode", "action_saturation")
        return {k: round(summary[k], 4) for k in keys}

    start = time.time()

    def curve_point(locals_: dict, globals_: dict) -> bool:
        # One learn call for the whole run, so that a schedule's progress spans it; a point every
        # --eval-every steps.
        if model.num_timesteps % args.eval_every == 0 or model.num_timesteps == args.steps:
            point = {
                "steps": model.num_timesteps,
                "seconds": round(time.time() - start),
                **score(args.curve_episodes, CURVE_SEED),
                **({"test": score(args.test_episodes, TEST_SEED)} if args.test_each_point else {}),
            }
            print(json.dumps(point), flush=True)
        return True

    model.learn(args.steps, callback=curve_point)
    print(json.dumps({"test": vars(args), **score(args.test_episodes, TEST_SEED)}), flush=True)
    if args.save:
        model.save(args.save)


if __name__ == "__main__":
    main()

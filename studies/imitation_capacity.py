"""Can a worker-sized actor represent a good reacher? Behaviour cloning of the IK reacher from the goal view.

    python studies/imitation_capacity.py [--net 64,64] [--episodes 200] [--epochs 30] [--scale ee_to_goal=30]

Collects the :class:`~sb3_hddpg.baselines.IKReacher`'s commands along its own (noise-perturbed) trajectories,
fits an actor of DDPG's shape (ReLU hidden layers, ``tanh`` output) on the goal worker's 15 observed values
by mean squared error, and scores it on the 20 development episodes. If the clone touches the goal about as
often as the IK reacher, the network and the goal view are not what limits the goal worker: its
reinforcement learning is. ``--scale NAME=FACTOR`` multiplies a component of the view before the network
(in fitting and acting alike): whether the inputs' scale, not the network's size, is what the clone misses.
Writes the figures as JSON to ``--out``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

import sb3_hddpg  # noqa: F401  (registers the env ids)
from sb3_hddpg.baselines import IKReacher
from sb3_hddpg.envs.contract import state_layout_of
from sb3_hddpg.episode_sets import DEVELOPMENT
from sb3_hddpg.evaluation import evaluate

GOAL_VIEW = ["joint_positions", "ee_to_goal", "goal_touched"]
#: Demonstration episodes use their own seeds, far from every named episode set's.
DEMO_SEED = 100_000


def collect(episodes: int, noise: float, rng: np.random.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """The IK reacher's commands on the states it visits when its actions are perturbed by ``noise``."""
    env = gym.make("hddpg/SnakeGoal-v0")
    layout = state_layout_of(env)
    view = np.concatenate([np.arange(layout[name].start, layout[name].stop) for name in GOAL_VIEW])
    teacher = IKReacher(layout)
    inputs, targets = [], []
    for episode in range(episodes):
        obs, _ = env.reset(seed=DEMO_SEED + episode)
        done = False
        while not done:
            action, _ = teacher.predict(obs)
            inputs.append(obs[view])
            targets.append(action)
            # Acting with noise covers states next to the teacher's path, where the clone will drift.
            noisy = np.clip(action + rng.normal(0.0, noise, action.shape), -1.0, 1.0).astype(np.float32)
            obs, _, terminated, truncated, _ = env.step(noisy)
            done = terminated or truncated
    return torch.tensor(np.array(inputs)), torch.tensor(np.array(targets))


class ClonedActor:
    """An MLP actor of DDPG's shape, fitted to demonstrations; acts through SB3's ``predict`` signature."""

    def __init__(
        self, n_inputs: int, n_actions: int, net: list[int], input_scale: torch.Tensor | None = None
    ) -> None:
        layers: list[torch.nn.Module] = []
        width = n_inputs
        for size in net:
            layers += [torch.nn.Linear(width, size), torch.nn.ReLU()]
            width = size
        self.net = torch.nn.Sequential(*layers, torch.nn.Linear(width, n_actions), torch.nn.Tanh())
        self.input_scale = torch.ones(n_inputs) if input_scale is None else input_scale

    def fit(self, inputs: torch.Tensor, targets: torch.Tensor, epochs: int, batch: int = 256) -> float:
        optimiser = torch.optim.Adam(self.net.parameters(), lr=1e-3)
        loss = torch.zeros(())
        for _ in range(epochs):
            order = torch.randperm(len(inputs))
            for start in range(0, len(inputs), batch):
                rows = order[start : start + batch]
                loss = ((self.net(inputs[rows] * self.input_scale) - targets[rows]) ** 2).mean()
                optimiser.zero_grad()
                loss.backward()
                optimiser.step()
        return float(loss.detach())

    def predict(
        self,
        observation: np.ndarray,
        state: object = None,
        episode_start: object = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, None]:
        with torch.no_grad():
            inputs = torch.as_tensor(observation, dtype=torch.float32) * self.input_scale
            return self.net(inputs).numpy(), None


def input_scale(text: str) -> torch.Tensor:
    """``"ee_to_goal=30"`` -> the goal view's per-input factors (1 where no component is named)."""
    env = gym.make("hddpg/SnakeGoal-v0")
    view = state_layout_of(env).view(GOAL_VIEW)
    env.close()
    factors = torch.ones(view.size)
    for part in filter(None, (piece.strip() for piece in text.split(","))):
        name, _, value = part.partition("=")
        if name not in GOAL_VIEW:
            raise ValueError(f"--scale: expected a component of {GOAL_VIEW}, got {name!r:.100}")
        factor = float(value)
        if not 0.0 < factor < 1e6:
            raise ValueError(f"--scale: expected a factor in (0, 1e6) for {name}, got {value!r:.100}")
        factors[view[name]] = factor
    return factors


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--net", default="64,64", help="hidden layer sizes of the cloned actor")
    parser.add_argument("--episodes", type=int, default=200, help="demonstration episodes (200 steps each)")
    parser.add_argument("--noise", type=float, default=0.2, help="std of the noise on the teacher's actions")
    parser.add_argument("--epochs", type=int, default=30, help="passes over the demonstrations")
    parser.add_argument(
        "--scale",
        default="",
        help="NAME=FACTOR[,NAME=FACTOR]: multiply components of the goal view by FACTOR before the network",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the demonstrations' noise and the fit")
    parser.add_argument("--out", default="runs/imitation_capacity.json", help="where the figures go")
    args = parser.parse_args()
    for name in ("episodes", "epochs"):
        if not 1 <= getattr(args, name) <= 100_000:
            parser.error(f"--{name} must be in [1, 100000], got {getattr(args, name)}")
    try:
        net = [int(size) for size in args.net.split(",")]
        scale = input_scale(args.scale)
    except ValueError as error:
        parser.error(str(error))
    torch.set_num_threads(1)
    torch.manual_seed(args.seed)
    inputs, targets = collect(args.episodes, args.noise, np.random.default_rng(args.seed))
    actor = ClonedActor(inputs.shape[1], targets.shape[1], net, scale)
    final_loss = actor.fit(inputs, targets, args.epochs)
    test_env = gym.make("hddpg/SnakeGoal-v0", observe=GOAL_VIEW)
    clone = evaluate(actor, test_env, n_episodes=20, seed=DEVELOPMENT.first_seed).summary()
    teacher_env = gym.make("hddpg/SnakeGoal-v0")
    teacher = evaluate(
        IKReacher(state_layout_of(teacher_env)), teacher_env, n_episodes=20, seed=DEVELOPMENT.first_seed
    )
    keys = ("mean_reward", "goal_touch_rate", "action_saturation")
    result = {
        "args": vars(args),
        "samples": len(inputs),
        "final_loss": round(final_loss, 5),
        "clone": {key: round(clone[key], 4) for key in keys},
        "ik_reacher": {key: round(teacher.summary()[key], 4) for key in keys},
    }
    print(json.dumps(result))
    Path(args.out).write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()

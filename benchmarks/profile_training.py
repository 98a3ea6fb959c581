"""
Where does a manager's training step go? Profile SB3 DDPG learning on ``WorkerSelectionWrapper`` (two
default-size workers, the bundled config's hyperparameters, one torch thread) end to end with pyinstrument
(a sampling profiler: it does not inflate the many small calls the way cProfile does), and report the share
of the wall time spent in this package's code, split into the env's physics and the manager's selection.

    pip install -e .[profile]   # pyinstrument
    python benchmarks/profile_training.py [--steps 3000] [--html profile.html]
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import torch
from pyinstrument import Profiler
from stable_baselines3 import DDPG

import sb3_hddpg  # noqa: F401
from sb3_hddpg.training.config import load_hyperparams
from sb3_hddpg.wrappers import WorkerSelectionWrapper


def own_time(frame, path_part: str) -> float:
    """Seconds spent in frames whose file path contains ``path_part`` (their own time, not their callees')."""
    total = frame.total_self_time if path_part in (frame.file_path or "") else 0.0
    return total + sum(own_time(child, path_part) for child in frame.children)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--steps", type=int, default=3000, help="learning steps profiled (after a warm-up)")
    parser.add_argument("--html", help="also write the interactive profile here")
    args = parser.parse_args()
    torch.set_num_threads(1)

    params = load_hyperparams("hddpg/SnakeReach-v0", DDPG)
    workers = {
        name: DDPG(
            "MlpPolicy", gym.make("hddpg/SnakeReach-v0"), policy_kwargs=params.algo_kwargs["policy_kwargs"]
        )
        for name in ("goal", "avoid")
    }
    env = WorkerSelectionWrapper(gym.make("hddpg/SnakeReach-v0"), workers)
    model = DDPG(
        params.policy, env, seed=0, device="cpu", action_noise=params.action_noise(2), **params.algo_kwargs
    )
    model.learn(params.algo_kwargs.get("learning_starts", 100) + 200)  # past the warm-up: every step trains

    profiler = Profiler(interval=0.0005)
    profiler.start()
    model.learn(args.steps, reset_num_timesteps=False)
    session = profiler.stop()
    root = session.root_frame()
    print(profiler.output_text(unicode=True, color=False, show_all=False)[:6000])
    if args.html:
        with open(args.html, "w") as handle:
            handle.write(profiler.output_html())

    total = session.duration
    env_share = own_time(root, "sb3_hddpg/envs") / total
    selection_share = (own_time(root, "sb3_hddpg/wrappers") + own_time(root, "sb3_hddpg/selection")) / total
    print(f"{args.steps / total:.0f} steps/s while profiled")
    print(f"share of wall time in sb3_hddpg/envs (physics, observation, reward): {env_share:.1%}")
    print(
        f"share of wall time in the manager's selection (wrapper, simplex, frozen workers): {selection_share:.1%}"
    )
    print(f"ratio of time outside this package (SB3 + torch + pymunk): {1 - env_share - selection_share:.2f}")


if __name__ == "__main__":
    main()

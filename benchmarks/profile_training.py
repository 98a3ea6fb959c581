"""
Where does a training step go? Profile learning end to end with pyinstrument (a sampling profiler: it does
not inflate the many small calls the way cProfile does) and split the wall time by who spends it.

Cases (the bundled configs' networks, update schedule and replay buffer, one thread):

- ``manager``: DDPG on ``WorkerSelectionWrapper`` over two workers of the goal block's size;
- ``worker``: the goal worker (``hddpg/SnakeGoal-v0`` with the block's goal view, its hindsight-relabelling
  replay buffer and its ``train_freq``/``gradient_steps``).

Backends: ``sb3`` (PyTorch) or ``sbx`` (JAX). The split, by the file of each frame's own time:

- the update: torch (``sb3``) or jax/XLA, flax, optax and SBX's jitted train step (``sbx``), including the
  host-to-device copies of the batch (on the CPU, a ``device_put`` of numpy arrays);
- replay sampling: SB3's buffers and our goal relabelling;
- acting: the policy's forward pass for the next action (SB3 ``predict``; on SBX a jitted call);
- the env: ``sb3_hddpg/envs`` and pymunk (physics, observation, reward);
- the manager's selection: ``sb3_hddpg/hierarchy`` (simplex map, frozen workers);
- the rest: SB3's collection loop, gymnasium's wrappers, numpy glue.

    pip install -e .[profile,fast]   # pyinstrument, sbx
    python benchmarks/profile_training.py [--case manager|worker] [--backend sb3|sbx] [--steps 3000] [--html F]
"""

from __future__ import annotations

import argparse
import os
from typing import Any

from sb3_hddpg.training.backends import configure_jax_threads

configure_jax_threads(1)  # before jax's first import, as train_agent does

import gymnasium as gym  # noqa: E402
import torch  # noqa: E402
from pyinstrument import Profiler  # noqa: E402
from stable_baselines3 import DDPG  # noqa: E402
from stable_baselines3.common.env_util import make_vec_env  # noqa: E402

import sb3_hddpg  # noqa: E402, F401
from sb3_hddpg.hierarchy import WorkerSelectionWrapper  # noqa: E402
from sb3_hddpg.training.config import MANAGER_KEY, load_hyperparams  # noqa: E402
from sb3_hddpg.training.models import make_model  # noqa: E402

#: (label, substrings of a frame's file path or function name), first match wins; order matters: SB3's
#: ``predict``/``_sample_action`` are acting even though they live in SB3's files.
CATEGORIES: tuple[tuple[str, tuple[str, ...]], ...] = (
    (
        "the manager's selection (wrapper, simplex map, frozen workers)",
        ("sb3_hddpg/hierarchy",),
    ),
    ("the env (physics, observation, reward)", ("sb3_hddpg/envs", "pymunk")),
    ("replay sampling (SB3 buffers, goal relabelling)", ("common/buffers.py", "goal_relabeling.py")),
    (
        "the update (torch / jax, XLA, flax, optax, SBX train step)",
        ("torch/", "/jax/", "jaxlib", "flax/", "optax/", "/sbx/"),
    ),
)
REST = "the rest (SB3's collection loop, gymnasium wrappers, numpy glue)"
ACTING = "acting (the policy's forward pass for the next action)"
ACTING_FUNCTIONS = ("predict", "_sample_action")


def _manager_env(goal_net: list[int]) -> gym.Env:
    base = gym.make("hddpg/SnakeReach-v0")
    workers = {
        name: DDPG("MlpPolicy", base, policy_kwargs={"net_arch": goal_net}, seed=i)
        for i, name in enumerate(("goal", "avoid"))
    }
    return WorkerSelectionWrapper(gym.make("hddpg/SnakeReach-v0"), workers)


def build(case: str, backend: str) -> Any:
    """The case's model on ``backend``, past ``learning_starts`` (so every profiled step trains)."""
    worker_params = load_hyperparams("hddpg/SnakeGoal-v0", DDPG)
    if case == "manager":
        params = load_hyperparams(MANAGER_KEY, DDPG, manager=True)
        net = list(worker_params.algo_kwargs.get("policy_kwargs", {}).get("net_arch", [64, 64]))
        factory = lambda: _manager_env(net)  # noqa: E731
    else:
        params = worker_params
        factory = lambda: gym.make("hddpg/SnakeGoal-v0", **params.env_kwargs)  # noqa: E731
    env = make_vec_env(factory, n_envs=1, seed=0)
    model = make_model("ddpg", backend, env, params.model_kwargs(factory()), seed=0)
    model.learn(int(params.algo_kwargs.get("learning_starts", 100)) + 400)  # SBX compiles here
    return model


def split(frame: Any, shares: dict[str, float], acting: bool = False, parent: str = REST) -> None:
    """
    Add each frame's own time to its category in ``shares``.

    Children inherit ``acting``; a built-in function (no file) takes its caller's category: jax dispatches
    a jitted call asynchronously, so the XLA computation's time shows up in the ``asarray`` that reads its
    result, inside the SBX function that called it.
    """
    acting = acting or frame.function in ACTING_FUNCTIONS
    path = frame.file_path or ""
    label = parent if path.startswith("<") else REST
    for name, parts in CATEGORIES:
        if any(part in path for part in parts):
            label = name
            break
    if acting and label in (REST, CATEGORIES[-1][0]):
        label = ACTING
    shares[label] = shares.get(label, 0.0) + frame.total_self_time
    for child in frame.children:
        if not child.is_synthetic:  # synthetic children's time is already in total_self_time
            split(child, shares, acting, label)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--case", choices=("manager", "worker"), default="manager", help="what is trained")
    parser.add_argument("--backend", choices=("sb3", "sbx"), default="sb3", help="training backend")
    parser.add_argument("--steps", type=int, default=3000, help="learning steps profiled (after a warm-up)")
    parser.add_argument("--html", help="also write the interactive profile here")
    args = parser.parse_args()
    torch.set_num_threads(1)
    model = build(args.case, args.backend)

    load_before = os.getloadavg()[0]
    profiler = Profiler(interval=0.0005)
    profiler.start()
    model.learn(args.steps, reset_num_timesteps=False)
    session = profiler.stop()
    print(profiler.output_text(unicode=True, color=False, show_all=False)[:6000])
    if args.html:
        with open(args.html, "w") as handle:
            handle.write(profiler.output_html())

    shares: dict[str, float] = {}
    split(session.root_frame(), shares)
    total = session.duration
    print(f"{args.case} on {args.backend}: {args.steps / total:.0f} steps/s while profiled")
    print(f"load average before {load_before:.2f}, after {os.getloadavg()[0]:.2f} (1 min)")
    for label, seconds in sorted(shares.items(), key=lambda item: -item[1]):
        print(f"{seconds / total:6.1%}  {label}")
    own = sum(shares.get(name, 0.0) for name, _ in CATEGORIES[:2])
    print(f"share of wall time in this package's env and selection code: {own / total:.1%}")


if __name__ == "__main__":
    main()

"""
Training speed of the two backends, side by side in one process: SBX (JAX) against SB3 (PyTorch).

For each case, the same env, hyperparameters (the bundled configs' networks and update schedule) and
seed on both backends; after a warm-up past ``learning_starts`` (which also compiles SBX's update), rounds
of ``learn(--steps)`` alternate between cases and backends, and each measurement records environment steps
per second of wall time and per second of this process's CPU time (``time.process_time``). The machine
may be shared: wall time then depends on the load, CPU time much less, so both ratios are printed with
the load average before and after. Medians over the rounds.

Cases:

- ``worker``: the goal worker's DDPG on ``hddpg/SnakeGoal-v0`` (``zoo_configs/ddpg.yml``);
- ``manager``: the manager's DDPG on ``WorkerSelectionWrapper`` over two default-size workers (the
  ``manager`` block), which includes the workers' torch forward passes on every env step;
- ``flat-ddpg``, ``flat-td3``, ``flat-sac``: the flat baselines on ``hddpg/SnakeReach-v0``;
- amortised settings of the worker: ``worker-k8`` (``train_freq = gradient_steps = 8``: the same number
  of updates per env step, 8 per call, which SBX runs in one jitted loop) and ``worker-4envs``
  (4 envs in a ``DummyVecEnv``, ``gradient_steps = 4``: 4 env steps and 4 updates per call). These change
  the order of collection and updates, so they may learn differently: measure learning before using them.

    python benchmarks/backend_speed.py [--steps 1000] [--rounds 3] [--cases worker,manager,...]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Callable
from typing import Any

from sb3_hddpg.training.backends import configure_jax_threads

configure_jax_threads(1)  # before jax's first import, as train_agent does

import gymnasium as gym  # noqa: E402
import torch  # noqa: E402
from stable_baselines3 import DDPG  # noqa: E402
from stable_baselines3.common.env_util import make_vec_env  # noqa: E402

import sb3_hddpg  # noqa: E402, F401
from sb3_hddpg.hierarchy import WorkerSelectionWrapper  # noqa: E402
from sb3_hddpg.training.backends import algo_class  # noqa: E402
from sb3_hddpg.training.config import MANAGER_KEY, default_config, load_hyperparams  # noqa: E402
from sb3_hddpg.training.models import make_model  # noqa: E402

CASES = ("worker", "manager", "flat-ddpg", "flat-td3", "flat-sac", "worker-k8", "worker-4envs")


def _manager_env() -> gym.Env:
    workers_params = load_hyperparams("hddpg/SnakeGoal-v0", DDPG)
    base = gym.make("hddpg/SnakeReach-v0")
    workers = {
        name: DDPG("MlpPolicy", base, policy_kwargs=workers_params.algo_kwargs["policy_kwargs"], seed=i)
        for i, name in enumerate(("goal", "avoid"))
    }
    return WorkerSelectionWrapper(gym.make("hddpg/SnakeReach-v0"), workers)


def case_setup(case: str) -> tuple[str, Callable[[], gym.Env], Any, int, dict[str, Any]]:
    """(algo, env factory, hyperparameters, n_envs, overrides of the block) of a case."""
    if case == "manager":
        return "ddpg", _manager_env, load_hyperparams(MANAGER_KEY, DDPG, manager=True), 1, {}
    if case.startswith("flat-"):
        algo = case.split("-", 1)[1]
        params = load_hyperparams("hddpg/SnakeReach-v0", algo_class(algo), default_config(algo))
        return algo, lambda: gym.make("hddpg/SnakeReach-v0"), params, 1, {}
    params = load_hyperparams("hddpg/SnakeGoal-v0", DDPG)
    factory = lambda: gym.make("hddpg/SnakeGoal-v0", **params.env_kwargs)  # noqa: E731
    if case == "worker-k8":
        return "ddpg", factory, params, 1, {"train_freq": 8, "gradient_steps": 8}
    if case == "worker-4envs":
        return "ddpg", factory, params, 4, {"train_freq": 1, "gradient_steps": 4}
    return "ddpg", factory, params, 1, {}


def build(case: str, backend: str) -> Any:
    """The case's model on ``backend``, warmed up past ``learning_starts`` (SBX compiles its update here)."""
    algo, factory, params, n_envs, overrides = case_setup(case)
    env = make_vec_env(factory, n_envs=n_envs, seed=0)
    # The block's arguments as training builds them (action noise, a named replay buffer resolved).
    kwargs = {**params.model_kwargs(factory()), **overrides}
    model = make_model(algo, backend, env, kwargs, seed=0)
    model.learn(int(kwargs.get("learning_starts", 100)) + 200 * n_envs)
    return model


def measure(model: Any, steps: int) -> tuple[float, float]:
    """(steps per wall second, steps per CPU second of this process) over ``learn(steps)``."""
    wall, cpu = time.perf_counter(), time.process_time()
    model.learn(steps, reset_num_timesteps=False)
    return steps / (time.perf_counter() - wall), steps / (time.process_time() - cpu)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--steps", type=int, default=1000, help="env steps per measurement")
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds (medians are reported)")
    parser.add_argument("--cases", default=",".join(CASES), help=f"comma-separated, among {list(CASES)}")
    args = parser.parse_args()
    cases = [c.strip() for c in args.cases.split(",") if c.strip()]
    unknown = [c for c in cases if c not in CASES]
    if unknown:
        parser.error(f"unknown cases {unknown}; choose from {list(CASES)}")
    torch.set_num_threads(1)
    load_before = os.getloadavg()
    models = {(case, backend): build(case, backend) for case in cases for backend in ("sb3", "sbx")}
    rates: dict[tuple[str, str], list[tuple[float, float]]] = {key: [] for key in models}
    for _ in range(args.rounds):
        for key, model in models.items():
            rates[key].append(measure(model, args.steps))
    load_after = os.getloadavg()

    def median(key: tuple[str, str], index: int) -> float:
        return statistics.median(r[index] for r in rates[key])

    print(
        f"load average before {load_before[0]:.2f} after {load_after[0]:.2f} (1 min); {os.cpu_count()} CPUs"
    )
    print(f"{'case':14s} {'SB3 steps/s':>18s} {'SBX steps/s':>18s} {'ratio':>14s}")
    print(f"{'':14s} {'wall':>8s} {'CPU':>9s} {'wall':>8s} {'CPU':>9s} {'wall':>6s} {'CPU':>7s}")
    for case in cases:
        sb3_wall, sb3_cpu = median((case, "sb3"), 0), median((case, "sb3"), 1)
        sbx_wall, sbx_cpu = median((case, "sbx"), 0), median((case, "sbx"), 1)
        print(
            f"{case:14s} {sb3_wall:8.1f} {sb3_cpu:9.1f} {sbx_wall:8.1f} {sbx_cpu:9.1f} "
            f"{sbx_wall / sb3_wall:5.2f}x {sbx_cpu / sb3_cpu:6.2f}x"
        )
    print(f"(medians of {args.rounds} rounds of {args.steps} steps; CPU = steps per second of process time)")


if __name__ == "__main__":
    main()

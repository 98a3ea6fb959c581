"""
What the harness's runs of several agents (benchmark, quickstart, tuning) derive for each agent from the
library's config blocks: the backend that trains it, a manager's env steps per decision and the discount that
keeps its horizon over options of another length, and an evaluation history counted in env steps.
"""

from __future__ import annotations

import inspect
from pathlib import Path
from typing import Any

from sb3_hddpg.artifacts.limits import read_json_file
from sb3_hddpg.training.backends import SBX_ALGOS, algo_class
from sb3_hddpg.training.config import manager_hyperparams, wrapper_kwargs


def backend_for(algo: str, backend: str) -> str:
    """
    The backend that trains ``algo`` when ``backend`` is asked for every agent of a run: ``backend`` if it
    trains the algorithm, else SB3, which trains every one (e.g. a DQN manager in an SBX benchmark).
    """
    return backend if backend != "sbx" or algo.lower() in SBX_ALGOS else "sb3"


def manager_option_steps(config: str | Path | None = None, algo: str = "ddpg") -> int:
    """
    Env steps per manager decision: the manager block's ``option_steps`` (1 when it sets none), by which a
    manager's timesteps (decisions) multiply into env steps.

    :param config: a ``zoo_configs``-format file (default: the bundled config of ``algo``).
    :param algo: the manager's algorithm.
    """
    return int(wrapper_kwargs(config, algo).get("option_steps", 1))


def horizon_gamma(option_steps: int, algo: str = "ddpg", config: str | Path | None = None) -> float:
    """
    The discount per decision that keeps a manager block's horizon in env steps over options of another
    length: the block's ``gamma ** (option_steps / block option_steps)`` (DQN's 0.9 over 4-step options
    becomes ``0.9 ** 0.25`` over 1-step ones).

    :param option_steps: env steps per decision of the manager to be trained.
    :param algo: the manager's algorithm.
    :param config: a ``zoo_configs``-format file (default: ``algo``'s bundled one).
    """
    hyperparams = manager_hyperparams(algo, config)
    block_steps = int(hyperparams.wrapper_kwargs.get("option_steps", 1))
    default = inspect.signature(algo_class(algo).__init__).parameters["gamma"].default
    return float(hyperparams.algo_kwargs.get("gamma", default)) ** (option_steps / block_steps)


def read_history(path: Path, steps_per_timestep: int = 1, offset: int = 0) -> list[dict[str, Any]]:
    """
    A history written by :class:`~sb3_hddpg.callbacks.evaluation.MetricsEvalCallback`, over env steps:
    ``timesteps`` times ``steps_per_timestep`` (a manager's decisions times its ``option_steps``; the
    decisions are kept as ``decisions``), and ``total_timesteps`` = that + ``offset`` (e.g. the workers' steps
    before a manager's).

    :param path: the run's own ``evaluations/<name>.json``.
    :param steps_per_timestep: env steps per step the model counts.
    :param offset: env steps spent before this model's first step.
    """
    out = []
    points = read_json_file(path)
    if not isinstance(points, list) or not all(isinstance(p, dict) for p in points):
        raise ValueError(f"{path}: expected a list of evaluation points")
    for point in points:
        steps = int(point["timesteps"]) * steps_per_timestep
        extra = {"decisions": int(point["timesteps"])} if steps_per_timestep != 1 else {}
        out.append({**point, **extra, "timesteps": steps, "total_timesteps": steps + offset})
    return out

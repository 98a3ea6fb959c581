"""
Training a flat baseline: one SB3 model on the combined reward (the paper's "single DDPG"), and its
manifest.
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
from stable_baselines3.common.type_aliases import MaybeCallback

from sb3_hddpg.artifacts.manifests import check_resumed_env, model_entry, save_manifest
from sb3_hddpg.artifacts.records import models_manifest, read_models_manifest
from sb3_hddpg.artifacts.run_folder import holds_run_folder
from sb3_hddpg.artifacts.values import check_make_kwargs
from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID
from sb3_hddpg.envs.terms_env import config_key
from sb3_hddpg.hierarchy.preference import make_preference_env
from sb3_hddpg.training.agent import (
    AgentPaths,
    TrainingOutcome,
    agent_run,
    check_takes,
    finished_with_budget,
    make_snake_env,
    train_agent,
)
from sb3_hddpg.training.backends import algo_class
from sb3_hddpg.training.config import Hyperparams, config_source, default_config, load_hyperparams
from sb3_hddpg.training.run_options import RunOptions, run_options

#: The config block of a flat agent given the goal worker's tricks (hindsight relabelling of the goal, the
#: action penalty where the algorithm takes it) on the full observation and the reach reward.
FLAT_HER_KEY = "flat-her"


def check_flat_env(algo: str, env_id: str | None = None, env_kwargs: Mapping[str, Any] | None = None) -> None:
    """
    :func:`check_takes` for a flat agent of ``algo`` on ``gym.make(env_id, **env_kwargs)`` (default: the
    combined task, :data:`~sb3_hddpg.envs.ids.SNAKE_REACH_ENV_ID`).
    """
    with contextlib.closing(make_snake_env(env_id or SNAKE_REACH_ENV_ID, dict(env_kwargs or {}))) as probe:
        check_takes(algo, probe.action_space)


def flat_hyperparams(
    algo: str,
    env_id: str,
    env_kwargs: Mapping[str, Any] | None = None,
    config: str | Path | None = None,
    block: str | None = None,
) -> Hyperparams:
    """
    The block a flat agent of ``algo`` on ``gym.make(env_id, **env_kwargs)`` trains from: an adapter's is
    keyed by the env it adapts, as the workers' are.

    :param config: a ``zoo_configs``-format file (default: ``algo``'s bundled one).
    :param block: another block of the file to read instead (e.g. :data:`FLAT_HER_KEY`).
    """
    path = Path(config) if config is not None else default_config(algo)
    return load_hyperparams(block or config_key(env_id, env_kwargs), algo_class(algo), path)


@holds_run_folder(lambda call: call.arguments["out_dir"], "train_flat")
def train_flat(
    out_dir: str | Path,
    algo: str = "ddpg",
    config: str | Path | None = None,
    *,
    run: RunOptions | None = None,
    env_id: str = SNAKE_REACH_ENV_ID,
    preferences: dict[str, float] | None = None,
    env_kwargs: dict[str, Any] | None = None,
    name: str | None = None,
    callback: MaybeCallback = None,
    block: str | None = None,
    **run_changes: object,
) -> FlatResult:
    """
    Train a flat baseline: one SB3 model on the combined reward of ``hddpg/SnakeReach-v0`` (the paper's
    "single DDPG", Section 3.3), and write ``out_dir/flat/<name>.zip`` and ``out_dir/flat/manifest.json``
    (in the workers manifest's format, so that the zip opens without unpickling anything).

    :param out_dir: the run folder.
    :param algo: the algorithm.
    :param config: a ``zoo_configs``-format file (default: the bundled ``zoo_configs/<algo>.yml``).
    :param run: the run-control settings (:class:`~sb3_hddpg.training.run_options.RunOptions`); with
        ``resume`` a model already finished with this budget is kept.
    :param env_id: the env to learn (the combined reward by default).
    :param preferences: reward term -> factor: learn ``sum_t factor_t * normalised(term_t)`` instead of the
        env's reward (the reward of a manager with the same factors); ``None``: the env's own reward.
    :param env_kwargs: its keyword arguments, over the config block's.
    :param name: the model's name in the manifest and its file name (default: ``algo``).
    :param callback: more SB3 callbacks, as SB3's ``learn`` takes them.
    :param block: the config block to train from instead of the env's (e.g. :data:`FLAT_HER_KEY`).
    :param run_changes: ``RunOptions`` fields as keywords, over ``run``'s.
    :return: the manifest written, the model's file and the training outcome.
    """
    run = run_options(run, run_changes, "train_flat")
    algo = algo.lower()
    algo_class(algo)  # an unknown algorithm named as such, before its config file is looked for
    config_path = Path(config) if config is not None else default_config(algo)
    hyperparams = flat_hyperparams(algo, env_id, env_kwargs, config_path, block)
    make_kwargs = check_make_kwargs(env_id, {**hyperparams.env_kwargs, **(env_kwargs or {})}, "env_kwargs")
    budget = int(run.timesteps if run.timesteps is not None else hyperparams.n_timesteps)
    out_dir = Path(out_dir)
    manifest_path = out_dir / "flat" / "manifest.json"
    name = name or algo
    exists = manifest_path.exists()
    manifest = read_models_manifest(manifest_path, "models") if exists else models_manifest("models")
    if run.resume:  # an earlier model of this name trained on another env is refused
        check_resumed_env(manifest.entries.get(name), env_id, make_kwargs)
    paths = AgentPaths(out_dir, f"flat-{algo}", out_dir / "flat" / f"{name}.zip")
    if run.resume and finished_with_budget(manifest.entries.get(name), budget):
        return FlatResult(manifest.to_json(), paths.model_path, None)  # finished in an earlier run
    factory = _flat_env_factory(env_id, make_kwargs, preferences)
    outcome = train_agent(
        factory, hyperparams, paths, algo=algo, run=agent_run(run, paths, budget), callback=callback
    )
    entry = model_entry(
        name,
        outcome,
        algo,
        env_id,
        make_kwargs,
        {"file": config_source(config_path, out_dir), "block": hyperparams.raw},
        run.seed,
        budget,
        stopped_early=outcome.stopped_early,
        preferences=dict(preferences) if preferences is not None else None,
        threads=run.threads,
    )
    manifest = manifest.with_entry(name, entry)
    save_manifest(manifest_path, manifest)
    return FlatResult(manifest.to_json(), paths.model_path, outcome)


@dataclass(frozen=True)
class FlatResult:
    """
    What :func:`train_flat` made.

    :param manifest: the flat models' manifest written (its JSON).
    :param model_path: the model's zip (``out_dir/flat/<name>.zip``).
    :param outcome: the training outcome; ``None`` when ``resume`` kept a finished model.
    """

    manifest: dict[str, Any]
    model_path: Path
    outcome: TrainingOutcome | None


def _flat_env_factory(
    env_id: str, make_kwargs: dict[str, Any], preferences: Mapping[str, float] | None
) -> Callable[[], gym.Env]:
    """
    A picklable factory of the flat agent's env: the env itself, or with ``preferences`` the env whose reward
    is the weighted sum of its normalised terms (the factors checked here, once, rather than in subprocesses).
    """
    if preferences is None:
        return functools.partial(make_snake_env, env_id, make_kwargs)
    factory = functools.partial(make_preference_env, env_id, make_kwargs, dict(preferences))
    factory().close()
    return factory

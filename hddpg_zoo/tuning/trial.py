"""One trial: train (or, for HAM, evaluate) a sampled configuration and return the objective value."""

from __future__ import annotations

import math
import re
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import optuna

from hddpg_zoo.tuning.pruning import TrialPruningCallback
from hddpg_zoo.tuning.target import (
    TuningTarget,
    ham_env,
    make_ham,
    merge_block,
    trial_env_factory,
)
from sb3_hddpg.artifacts.manifests import load_workers
from sb3_hddpg.episode_sets import episode_set
from sb3_hddpg.evaluation import evaluate
from sb3_hddpg.training.agent import AgentPaths, TrainingInterrupted, train_agent
from sb3_hddpg.training.config import Hyperparams, parse_block
from sb3_hddpg.training.run_options import RunOptions

_NAN_MESSAGE = re.compile(r"\bnan\b|non-finite|not finite|\binf\b|infinit", re.IGNORECASE)


def objective(trial: optuna.Trial, target: TuningTarget, out_dir: str | Path, threads: int = 1) -> float:
    """
    Train (or, for HAM, evaluate) one sampled configuration and return its last mean evaluation reward (the
    mean over the trial's ``n_seeds`` runs).

    :param trial: the Optuna trial.
    :param target: what is tuned.
    :param out_dir: the run folder; trials train in temporary folders under ``OUT/trials``.
    :param threads: torch threads.
    :return: the objective value; raises ``optuna.TrialPruned`` when pruned or diverged.
    """
    changes = target.sampler(trial)
    if target.level == "ham":
        threshold = changes["threshold"]
        if not isinstance(threshold, (int, float)):
            raise TypeError(f"HAM's sampler gave a threshold of {threshold!r}")
        return _evaluate_ham(trial, target, float(threshold))
    block = merge_block(target.base_block(), changes)
    trial.set_user_attr("config_block", block)
    timesteps = target.budget()
    hyperparams = parse_block(
        dict(block, n_timesteps=timesteps, n_envs=1),
        target.algo_class,
        source=f"trial {trial.number}",
        manager=target.level == "manager",
    )
    if target.level == "manager":
        # Every level's trial gets the same env steps: a manager decides once per option_steps env steps.
        timesteps = max(1, timesteps // int(hyperparams.wrapper_kwargs.get("option_steps", 1)))
        trial.set_user_attr("decisions", timesteps)
    trials_dir = Path(out_dir) / "trials"
    trials_dir.mkdir(parents=True, exist_ok=True)
    histories = []
    for index in range(target.n_seeds):
        # Run k's evaluations are reported as steps k * (n_evaluations + 1) + 1...: every trial trains the
        # same seeds in the same order, so the pruner compares like with like (seed k, evaluation i). The
        # + 1 is room for the final evaluation: with train_freq > 1 SB3 overshoots the budget by up to
        # train_freq - 1 steps, and a run then ends with n_evaluations + 1 of them.
        pruning = TrialPruningCallback(trial, step_offset=index * (target.n_evaluations + 1))
        history = _train_trial_run(
            trial, target, hyperparams, timesteps, target.seed + index, pruning, threads, trials_dir
        )
        histories.append(history)
        if target.n_seeds > 1:  # every run so far, each entry with its seed (kept if a later run is pruned)
            history = [dict(entry, seed=target.seed + i) for i, run in enumerate(histories) for entry in run]
        trial.set_user_attr("history", history)
        if pruning.diverged is not None:
            trial.set_user_attr("diverged", pruning.diverged)
            raise optuna.TrialPruned(f"diverged: {pruning.diverged}")
        if pruning.is_pruned:
            raise optuna.TrialPruned(
                f"pruned after evaluation {pruning.eval_idx} of seed {target.seed + index}"
            )
    # Each run's best evaluation, for the `peak` ranking (the mean of these, not the best of all runs).
    trial.set_user_attr("seed_peaks", [max(float(e["mean_reward"]) for e in run) for run in histories])
    return float(np.mean([float(run[-1]["mean_reward"]) for run in histories]))


def _train_trial_run(
    trial: optuna.Trial,
    target: TuningTarget,
    hyperparams: Hyperparams,
    timesteps: int,
    seed: int,
    pruning: TrialPruningCallback,
    threads: int,
    trials_dir: Path,
) -> list[dict[str, Any]]:
    """One training run of a trial with one seed (in a temporary folder under ``trials_dir``); its history."""
    # The trial's models, checkpoint and logs are not needed once its value is known: a temporary folder.
    with tempfile.TemporaryDirectory(prefix=f"trial-{trial.number}-seed-{seed}-", dir=trials_dir) as folder:
        paths = AgentPaths(Path(folder), target.name, Path(folder) / "model.zip")
        try:
            outcome = train_agent(
                trial_env_factory(target, hyperparams),
                hyperparams,
                paths,
                algo=target.algo,
                run=RunOptions(
                    timesteps=timesteps,
                    seed=seed,
                    n_envs=1,
                    eval_freq=math.ceil(timesteps / target.n_evaluations),
                    eval_episodes=target.eval_episodes,
                    eval_seed=episode_set(target.episode_set).first_seed,
                    checkpoint_freq=0,
                    keep_best=False,
                    threads=threads,
                    backend=target.backend,
                ),
                after_eval=pruning,
            )
        except (KeyboardInterrupt, TrainingInterrupted):
            # Interrupted by the user, not a bad configuration: queue the same parameters again so that a
            # re-run tries them (the interrupted trial itself ends FAIL).
            trial.study.enqueue_trial(trial.params, user_attrs={"retry_of": trial.number})
            raise
        except Exception as error:
            reason = pruning.check_divergence()
            if reason is None and _NAN_MESSAGE.search(str(error)):
                reason = f"{type(error).__name__}: {error}"
            if reason is None:
                raise
            trial.set_user_attr("diverged", reason)
            raise optuna.TrialPruned(f"diverged: {reason}") from error
    return [_jsonable(entry) for entry in outcome.history]


def _evaluate_ham(trial: optuna.Trial, target: TuningTarget, threshold: float) -> float:
    """HAM's trial: no training, one evaluation on the combined reward."""

    workers = load_workers(str(target.workers_dir))
    manifest = workers.manifest
    env = ham_env(target, manifest)
    try:
        policy = make_ham(workers, env, threshold, manifest)
        first = episode_set(target.episode_set).first_seed
        summary = evaluate(policy, env, n_episodes=target.eval_episodes, seed=first).summary()
    finally:
        env.close()
    trial.set_user_attr("history", [_jsonable({"timesteps": 0, **summary})])
    value = float(summary["mean_reward"])
    if not math.isfinite(value):
        raise optuna.TrialPruned(f"diverged: mean evaluation reward is {value}")
    trial.report(value, 1)
    return value


def _jsonable(entry: Mapping[str, object]) -> dict[str, object]:
    """An evaluation summary with only JSON-safe finite numbers (NaN becomes ``None``)."""
    out: dict[str, object] = {}
    for key, value in entry.items():
        if isinstance(value, float):
            out[key] = value if math.isfinite(value) else None
        elif isinstance(value, (int, str, bool)) or value is None:
            out[key] = value
        elif isinstance(value, dict):
            out[key] = _jsonable(value)
    return out

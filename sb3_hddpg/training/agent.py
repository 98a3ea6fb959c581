"""
Training one agent of the hierarchy (a worker, the manager, or a flat baseline) as a plain SB3 model, with
periodic evaluation, the best model kept, checkpoints that Ctrl-C, SIGTERM or SIGKILL lose little of, and
resume: what every ``hddpg-cli train-*`` command builds on.
"""

from __future__ import annotations

import contextlib
import json
import signal
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import (
    BaseCallback,
    CallbackList,
    ConvertCallback,
    StopTrainingOnNoModelImprovement,
)
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.type_aliases import MaybeCallback
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv

from sb3_hddpg.algorithms import ALGORITHMS, REGISTRY, algorithm
from sb3_hddpg.artifacts.io import atomic_write, holds_folder_lock, note_stop_signal, remove_stale_temporaries
from sb3_hddpg.callbacks.checkpoint import ResumableCheckpointCallback, read_checkpoint_state
from sb3_hddpg.callbacks.evaluation import MetricsEvalCallback, best_entry
from sb3_hddpg.extras import configure
from sb3_hddpg.training.backends import algo_class, check_algo, configure_jax_threads, resolve_backend
from sb3_hddpg.training.config import Hyperparams
from sb3_hddpg.training.models import load_native, make_model, to_sb3
from sb3_hddpg.training.run_options import RunOptions, run_options

#: Algorithm names accepted by ``--algo`` (the registry's, in its order).
ALGO_NAMES = tuple(ALGORITHMS)


class TrainingInterrupted(RuntimeError):
    """Training stopped by Ctrl-C or SIGTERM after saving a resumable checkpoint."""


def make_snake_env(env_id: str, env_kwargs: dict[str, Any] | None = None) -> gym.Env:
    """
    Build a registered env by id; a module-level function so that SubprocVecEnv can pickle it.

    :param env_id: e.g. ``"hddpg/SnakeGoal-v0"``.
    :param env_kwargs: keyword arguments for ``gym.make``.
    """
    torch.set_num_threads(1)
    return gym.make(env_id, **(env_kwargs or {}))


@dataclass
class AgentPaths:
    """
    Where one agent's files go inside a run folder.

    :param root: the run folder.
    :param name: the agent's name (``goal``, ``avoid``, ``manager``, ``flat-ddpg``...).
    :param model_path: the final model zip.
    """

    root: Path
    name: str
    model_path: Path

    @property
    def checkpoint_dir(self) -> Path:
        return self.root / "checkpoints" / self.name

    @property
    def best_dir(self) -> Path:
        return self.root / "best" / self.name

    @property
    def history_path(self) -> Path:
        return self.root / "evaluations" / f"{self.name}.json"


@dataclass
class TrainingOutcome:
    """
    What :func:`train_agent` produced.

    :param model: the trained model (the best one by evaluation when ``keep_best``).
    :param model_path: where it was saved.
    :param num_timesteps: environment steps trained.
    :param history: the evaluation history (one dict of metrics per evaluation).
    :param metrics: the final evaluation's summary of the saved model.
    :param stopped_early: whether the plateau rule stopped training.
    :param backend: the backend that trained it (``sb3`` or ``sbx``; the saved model is SB3 either way).
    """

    model: BaseAlgorithm
    model_path: Path
    num_timesteps: int
    history: list[dict[str, Any]] = field(default_factory=list)
    metrics: dict[str, Any] = field(default_factory=dict)
    stopped_early: bool = False
    backend: str = "sb3"


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """Turn SIGTERM into KeyboardInterrupt for the duration, so both take the same save-and-exit path."""

    def handler(signum: int, frame: object) -> None:
        note_stop_signal(signum)  # the command exits 143, not Ctrl-C's 130
        raise KeyboardInterrupt

    try:
        previous = signal.signal(signal.SIGTERM, handler)
    except ValueError:  # not the main thread: leave signals alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


@holds_folder_lock(lambda call: call.arguments["paths"].root)
def train_agent(
    env_factory: Callable[[], gym.Env],
    hyperparams: Hyperparams,
    paths: AgentPaths,
    algo: str = "ddpg",
    *,
    run: RunOptions | None = None,
    callback: MaybeCallback = None,
    after_eval: BaseCallback | None = None,
    prepare_model: Callable[[BaseAlgorithm], None] | None = None,
    **run_changes: object,
) -> TrainingOutcome:
    """
    Train one SB3 agent with evaluation, best-model keeping, checkpoints and resume. With ``backend="sbx"``
    the checkpoints stay in SBX's format, and the model saved and returned is exported to SB3.

    :param env_factory: builds one (unwrapped by Monitor) training env; picklable when ``n_envs > 1``.
    :param hyperparams: the config block.
    :param paths: where the agent's files go.
    :param algo: the algorithm.
    :param run: the run-control settings (:class:`~sb3_hddpg.training.run_options.RunOptions`); ``resume``
        continues from the last checkpoint in ``paths.checkpoint_dir``.
    :param callback: more SB3 callbacks, as SB3's ``learn`` takes them, run after the package's own.
    :param after_eval: a callback run after every evaluation, with the evaluator as its ``parent`` (e.g. the
        Optuna pruning callback); returning ``False`` stops training.
    :param prepare_model: called with a freshly built model before it learns (not on resume).
    :param run_changes: ``RunOptions`` fields as keywords, over ``run``'s.
    :return: the outcome; raises :class:`TrainingInterrupted` after saving on Ctrl-C or SIGTERM.
    """
    run = run_options(run, run_changes, "train_agent")
    total, n_envs, backend = _check_agent(hyperparams, paths, algo, run)
    vec_cls = SubprocVecEnv if n_envs > 1 else DummyVecEnv
    vec_env = make_vec_env(env_factory, n_envs=n_envs, seed=run.seed, vec_env_cls=vec_cls)
    eval_env = env_factory()
    # After the env factories: make_snake_env sets one thread for subprocess envs, which must not
    # override this process's choice.
    torch.set_num_threads(run.threads)
    try:
        check_takes(algo, eval_env.action_space)
        model, state = _start_model(hyperparams, paths, algo, backend, run, vec_env, eval_env)
        if prepare_model is not None and state is None:
            prepare_model(model)
        evaluator = _make_evaluator(eval_env, paths, state, n_envs, run, after_eval)
        checkpointer = _make_checkpointer(paths, run, (total, algo, hyperparams), backend, evaluator, state)
        callbacks = CallbackList(
            [*hyperparams.callbacks(), evaluator, checkpointer, *callback_list(callback)]
        )
        _learn(
            model, total, callbacks, checkpointer, paths, fresh=state is None, progress_bar=run.progress_bar
        )
        stopped_early = model.num_timesteps < total
        # Always end with an evaluation of the final policy, so that a best model and metrics exist.
        if not evaluator.history or evaluator.history[-1]["timesteps"] != model.num_timesteps:
            evaluator.init_callback(model)
            evaluator.run_evaluation()
        checkpointer.init_callback(model)
        checkpointer.save(replay_buffer=run.keep_checkpoints)
        return _save_outcome(model, evaluator, paths, algo, backend, run.keep_best, stopped_early)
    finally:
        with contextlib.suppress(Exception):  # subprocesses may already be gone after Ctrl-C
            vec_env.close()
        eval_env.close()


def _check_agent(
    hyperparams: Hyperparams, paths: AgentPaths, algo: str, run: RunOptions
) -> tuple[int, int, str]:
    """
    Check one agent's settings before any env starts, and clear its stale temporaries.

    :return: the total budget, the number of training envs and the backend.
    """
    total = int(run.timesteps if run.timesteps is not None else hyperparams.n_timesteps)
    if total < 1:  # a config block's n_timesteps (the options' own budget is checked when they are built)
        raise ValueError(f"Expected timesteps >= 1, actually: {total}")
    n_envs = int(run.n_envs or hyperparams.n_envs)
    backend = resolve_backend(run.backend, hyperparams.backend)
    check_algo(algo, backend)
    if backend == "sbx":
        configure_jax_threads(run.threads)  # before jax's first import in this process, or it cannot apply
    # A run killed mid-write leaves hidden temporaries that hold nothing we read: clear this agent's.
    for folder in (paths.checkpoint_dir, paths.best_dir):
        remove_stale_temporaries(folder)
    for path in (paths.model_path, paths.history_path):
        remove_stale_temporaries(path.parent, target=path.name)
    algo_class(algo)  # a clear error for an unknown name before any env starts
    asked = [type(callback).__name__ for callback in hyperparams.callbacks()]
    if asked and not algorithm(algo).action_penalty:
        penalised = [name for name, record in REGISTRY.items() if record.action_penalty]
        raise ValueError(
            f"The {' and '.join(asked)} callback applies to {penalised}, not {algo!r}: remove it from the config block"
        )
    return total, n_envs, backend


def _start_model(
    hyperparams: Hyperparams,
    paths: AgentPaths,
    algo: str,
    backend: str,
    run: RunOptions,
    vec_env: VecEnv,
    eval_env: gym.Env,
) -> tuple[BaseAlgorithm, dict[str, Any] | None]:
    """The model to learn, logging to TensorBoard: the last checkpoint's on resume (with its state), else a new one."""
    if run.resume:
        model, state = _resume_model(algo, backend, paths, vec_env)
    else:
        kwargs = hyperparams.model_kwargs(eval_env)
        model = make_model(algo, backend, vec_env, kwargs, seed=run.seed, policy=hyperparams.policy)
        state = None
    model.set_logger(configure(str(paths.root / "tensorboard" / paths.name), ["tensorboard"]))
    return model, state


def _make_checkpointer(
    paths: AgentPaths,
    run: RunOptions,
    planned: tuple[int, str, Hyperparams],
    backend: str,
    evaluator: MetricsEvalCallback,
    state: dict[str, Any] | None,
) -> ResumableCheckpointCallback:
    """
    The resumable checkpoints, each with what a resumed run needs (budget, seed, backend, history) and what
    it was trained with (algorithm, config block), to compare with when an agent killed before its manifest
    entry is resumed.

    :param planned: the total budget, the algorithm and the config block.
    """
    total, algo, hyperparams = planned
    block = json.loads(json.dumps(dict(hyperparams.raw), default=str))
    return ResumableCheckpointCallback(
        paths.checkpoint_dir,
        save_freq=run.checkpoint_freq,
        extra_state=lambda: {
            "total_timesteps": total,
            "algo": algo,
            "config": {"block": block},
            "seed": run.seed,
            "backend": backend,
            "history": evaluator.history,
            "best_mean_reward": evaluator.best_mean_reward
            if np.isfinite(evaluator.best_mean_reward)
            else None,
        },
        min_timesteps=state["num_timesteps"] if state is not None else 0,
    )


def check_takes(algo: str, action_space: gym.spaces.Space) -> None:
    """Refuse, in one line naming both, an algorithm for an env whose ``action_space`` it does not take."""
    record = algorithm(algo)
    if not record.takes(action_space):
        raise ValueError(
            f"Expected an env whose actions {record.name} takes ({sorted(record.action_spaces)}), actually "
            f"{action_space}"
        )


def _resume_model(
    algo: str, backend: str, paths: AgentPaths, vec_env: VecEnv
) -> tuple[BaseAlgorithm, dict[str, Any]]:
    """The model of the last checkpoint in ``paths.checkpoint_dir``, with its replay buffer, and its state."""
    state = read_checkpoint_state(paths.checkpoint_dir)
    if state is None:
        raise FileNotFoundError(f"Nothing to resume: no checkpoint in {str(paths.checkpoint_dir)!r}")
    saved_backend = state.get("backend", "sb3")
    if saved_backend != backend:
        raise ValueError(
            f"The checkpoint in {str(paths.checkpoint_dir)!r} was trained with backend "
            f"{saved_backend!r}; resume it with --backend {saved_backend}"
        )
    # Our own checkpoint, written by this library: the full (SB3 or SBX) load is appropriate here.
    model = load_native(algo, backend, state["model_path"], env=vec_env)
    if not isinstance(model, OffPolicyAlgorithm):
        return model, state  # an on-policy model collects a fresh rollout: nothing to restore
    if state["replay_buffer_path"] is not None:
        model.load_replay_buffer(state["replay_buffer_path"])
    elif model.replay_buffer is not None:
        # A finished run's checkpoint without its buffer: collect learning_starts fresh transitions
        # before the first update, as at the start, rather than train on a handful of them.
        model.learning_starts = int(model.num_timesteps + model.learning_starts)
    return model, state


def _make_evaluator(
    eval_env: gym.Env,
    paths: AgentPaths,
    state: dict[str, Any] | None,
    n_envs: int,
    run: RunOptions,
    after_eval: BaseCallback | None,
) -> MetricsEvalCallback:
    """The periodic evaluator, continuing a resumed run's, with the plateau rule and ``after_eval``."""
    plateau = (
        StopTrainingOnNoModelImprovement(max_no_improvement_evals=run.plateau_patience, min_evals=1)
        if run.stop_on_plateau
        else None
    )
    after_eval_callbacks = [c for c in (plateau, after_eval) if c is not None]
    best = state.get("best_mean_reward") if state is not None else None
    evaluator = MetricsEvalCallback(
        eval_env,
        n_eval_episodes=run.eval_episodes,
        eval_freq=max(run.eval_freq // n_envs, 1) if run.eval_freq > 0 else 0,
        eval_seed=run.eval_seed,
        best_model_save_path=paths.best_dir if run.keep_best else None,
        history_path=paths.history_path,
        callback_after_eval=CallbackList(after_eval_callbacks) if after_eval_callbacks else None,
        history=state.get("history", []) if state is not None else [],
        best_mean_reward=best if best is not None else -np.inf,
    )
    # The plateau rule and the pruner read the evaluator's results through ``parent``, also in a list.
    for callback in after_eval_callbacks:
        callback.parent = evaluator
    return evaluator


def _learn(
    model: BaseAlgorithm,
    total: int,
    callbacks: BaseCallback,
    checkpointer: ResumableCheckpointCallback,
    paths: AgentPaths,
    fresh: bool,
    progress_bar: bool,
) -> None:
    """Learn up to ``total`` steps; on Ctrl-C or SIGTERM save a checkpoint and raise TrainingInterrupted."""
    remaining = total - model.num_timesteps
    if remaining <= 0:
        return
    try:
        with sigterm_as_interrupt():
            model.learn(
                remaining,
                callback=callbacks,
                reset_num_timesteps=fresh,
                tb_log_name=paths.name,
                progress_bar=progress_bar,
            )
    except KeyboardInterrupt:
        checkpointer.save()
        raise TrainingInterrupted(
            f"{paths.name}: interrupted at {model.num_timesteps} of {total} steps; checkpoint saved in "
            f"{paths.checkpoint_dir}. Run the same command with --resume to continue."
        ) from None


def _save_outcome(
    model: BaseAlgorithm,
    evaluator: MetricsEvalCallback,
    paths: AgentPaths,
    algo: str,
    backend: str,
    keep_best: bool,
    stopped_early: bool,
) -> TrainingOutcome:
    """Save the chosen model (the best evaluated one when ``keep_best``, else the final one) as plain SB3."""
    chosen = model
    from_best = keep_best and evaluator.best_model_path is not None and evaluator.best_model_path.exists()
    if from_best:
        chosen = load_native(algo, backend, evaluator.best_model_path)
    # What a user shares is plain SB3, whichever backend trained it.
    chosen = to_sb3(chosen)
    atomic_write(paths.model_path, lambda tmp: chosen.save(tmp))
    kept = best_entry(evaluator.history) if from_best else evaluator.history[-1]
    metrics = {k: v for k, v in kept.items() if k not in ("timesteps", "updates")}
    metrics["selected_at_timesteps"] = kept["timesteps"]
    return TrainingOutcome(
        model=chosen,
        model_path=paths.model_path,
        num_timesteps=int(model.num_timesteps),
        history=list(evaluator.history),
        metrics=metrics,
        stopped_early=stopped_early,
        backend=backend,
    )


def agent_run(run: RunOptions, paths: AgentPaths, budget: int | None) -> RunOptions:
    """
    One agent's options within a command's ``run``: its own budget, and resume only when asked to and a
    checkpoint exists (killed before its first checkpoint, a run has nothing to resume and starts afresh).
    """
    resume = run.resume and read_checkpoint_state(paths.checkpoint_dir) is not None
    return run.replace(timesteps=budget, resume=resume)


def finished_with_budget(entry: object, budget: int) -> bool:
    """Whether a manifest entry is a model that an earlier run finished with this budget."""
    return isinstance(entry, dict) and entry.get("timesteps_requested") == budget


def callback_list(callback: MaybeCallback) -> list[BaseCallback]:
    """``callback`` as SB3's ``learn`` takes it (a callback, a list, a function or ``None``), as a list."""
    if callback is None:
        return []
    if isinstance(callback, list):
        return [item for entry in callback for item in callback_list(entry)]
    if isinstance(callback, BaseCallback):
        return [callback]
    if callable(callback):
        return [ConvertCallback(callback)]
    raise TypeError(
        f"Expected `callback` to be an SB3 callback, a list of them or a function, actually: {callback!r}"
    )

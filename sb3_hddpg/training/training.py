"""
Training any agent of the hierarchy: a worker, the manager, or a flat baseline, as a plain SB3 model.

One function, :func:`train_agent`, does what every ``hddpg-cli train-*`` command needs: build the
vectorised env and the model from a config block, evaluate periodically with the env's metrics and keep
the best model, checkpoint so that Ctrl-C, SIGTERM or even SIGKILL lose little, resume to the requested
total, optionally stop on a plateau, and log to TensorBoard. :func:`train_workers` builds on it.
"""

from __future__ import annotations

import contextlib
import functools
import inspect
import signal
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, CallbackList, StopTrainingOnNoModelImprovement
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.logger import configure
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

from sb3_hddpg.algorithms import ALGORITHMS, REGISTRY, algorithm, algorithms_for
from sb3_hddpg.artifacts.io import (
    atomic_write,
    atomic_write_json,
    holds_folder_lock,
    remove_stale_temporaries,
)
from sb3_hddpg.artifacts.limits import brief, read_json_file
from sb3_hddpg.artifacts.manifests import check_resumed_env, load_workers, model_entry, save_manifest
from sb3_hddpg.artifacts.records import ModelsManifest, models_manifest, read_models_manifest
from sb3_hddpg.artifacts.values import check_make_kwargs
from sb3_hddpg.artifacts.workers import Workers, shared_env_of
from sb3_hddpg.callbacks.checkpoint import ResumableCheckpointCallback, read_checkpoint_state
from sb3_hddpg.callbacks.evaluation import MetricsEvalCallback, best_entry
from sb3_hddpg.callbacks.selection_stats import SelectionStatsCallback
from sb3_hddpg.envs import REWARD_TERMS
from sb3_hddpg.envs.contract import env_contract
from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID, WORKER_ENV_IDS
from sb3_hddpg.envs.terms_env import TermsEnv, config_key, make_term_view
from sb3_hddpg.hierarchy.conditioning import PreferenceSpace
from sb3_hddpg.hierarchy.hierarchy import Hierarchy
from sb3_hddpg.hierarchy.preference import make_preference_env
from sb3_hddpg.hierarchy.relabeling import PreferenceRelabelingReplayBuffer
from sb3_hddpg.hierarchy.selection import OptionEnd, SelectionConfig, check_preferences, preferences_from_bias
from sb3_hddpg.hierarchy.wrapper import WorkerSelectionWrapper
from sb3_hddpg.training.backends import (
    algo_class,
    check_algo,
    configure_jax_threads,
    load_native,
    make_model,
    resolve_backend,
    to_sb3,
)
from sb3_hddpg.training.config import MANAGER_KEY, Hyperparams, default_config, load_hyperparams
from sb3_hddpg.training.ham_start import HAM_START_ALGOS, HamStart, ham_start_hook
from sb3_hddpg.training.run_options import RunOptions, run_options

#: Algorithm names accepted by ``--algo`` (the registry's, in its order).
ALGO_NAMES = tuple(ALGORITHMS)

#: The algorithms a manager can be: DDPG (the paper's), or another whose record takes the manager role, each with
#: a ``manager`` block in its bundled config (``zoo_configs/<algo>.yml``); one acting in Discrete spaces (DQN)
#: selects with the ``discrete`` mode, its action the worker's index.
MANAGER_ALGOS = algorithms_for("manager")
#: The algorithm of a worker no ``algos`` entry names: the paper's.
DEFAULT_WORKER_ALGO = "ddpg"


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
    def tensorboard_dir(self) -> Path:
        return self.root / "tensorboard"

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

    def handler(signum: int, frame: Any) -> None:
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
    extra_callbacks: Sequence[BaseCallback] = (),
    after_eval: BaseCallback | None = None,
    prepare_model: Callable[[BaseAlgorithm], None] | None = None,
    **run_changes: Any,
) -> TrainingOutcome:
    """
    Train one SB3 agent with evaluation, best-model keeping, checkpoints and resume.

    With ``backend="sbx"`` the agent trains on JAX (:mod:`sb3_hddpg.training.backends`); its checkpoints and best
    model stay in SBX's format inside the run folder, and the model saved to ``paths.model_path`` and
    returned is exported to the same SB3 algorithm.

    :param env_factory: builds one (unwrapped by Monitor) training env; picklable when ``n_envs > 1``.
    :param hyperparams: the config block (see :mod:`sb3_hddpg.training.config`).
    :param paths: where the agent's files go.
    :param algo: ``ddpg``, ``td3``, ``sac`` or ``tqc``.
    :param run: the run-control settings (:class:`~sb3_hddpg.training.run_options.RunOptions`: budget, seed,
        envs, resume, plateau rule, evaluation, checkpoints, threads, backend); ``resume`` continues from the
        last checkpoint in ``paths.checkpoint_dir``.
    :param extra_callbacks: more SB3 callbacks (e.g. selection statistics).
    :param after_eval: a callback run after every evaluation, with the evaluator as its ``parent`` (e.g. the
        Optuna pruning callback); returning ``False`` stops training.
    :param prepare_model: called with a freshly built model before it learns (not on resume), e.g. the
        manager's start from HAM (:mod:`sb3_hddpg.training.ham_start`).
    :param run_changes: :class:`~sb3_hddpg.training.run_options.RunOptions` fields as keywords (e.g.
        ``seed=3``), over ``run``'s.
    :return: the outcome; raises :class:`TrainingInterrupted` after saving on Ctrl-C or SIGTERM.
    """
    run = run_options(run, run_changes, "train_agent")
    total = int(run.timesteps if run.timesteps is not None else hyperparams.n_timesteps)
    if total < 1:  # a config block's n_timesteps (the options' own budget is checked when they are built)
        raise ValueError(f"Expected timesteps >= 1, actually: {total}")
    n_envs = int(run.n_envs or hyperparams.n_envs)
    backend = resolve_backend(run.backend, hyperparams.backend)
    check_algo(algo, backend)
    if backend == "sbx":
        configure_jax_threads(run.threads)  # before jax's first import in this process, or it cannot apply
    _remove_stale_temporaries(paths)
    algo_class(algo)  # a clear error for an unknown name before any env starts
    if hyperparams.action_l2 > 0 and not algorithm(algo).action_penalty:
        penalised = [name for name, record in REGISTRY.items() if record.action_penalty]
        raise ValueError(
            f"The ActionL2Penalty callback applies to {penalised}, not {algo!r}: remove it from the config block"
        )

    vec_cls = SubprocVecEnv if n_envs > 1 else DummyVecEnv
    vec_env = make_vec_env(env_factory, n_envs=n_envs, seed=run.seed, vec_env_cls=vec_cls)
    eval_env = env_factory()
    # After the env factories: make_snake_env sets one thread for subprocess envs, which must not
    # override this process's choice.
    torch.set_num_threads(run.threads)
    try:
        check_takes(algo, eval_env.action_space)
        if run.resume:
            model, state = _resume_model(algo, backend, paths, vec_env)
        else:
            kwargs = hyperparams.model_kwargs(eval_env)
            model, state = (
                make_model(algo, backend, vec_env, kwargs, seed=run.seed, policy=hyperparams.policy),
                None,
            )
        model.set_logger(_tensorboard_logger(paths))
        if prepare_model is not None and state is None:
            prepare_model(model)
        evaluator = _make_evaluator(eval_env, paths, state, n_envs, run, after_eval)
        checkpointer = ResumableCheckpointCallback(
            paths.checkpoint_dir,
            save_freq=run.checkpoint_freq,
            extra_state=lambda: {
                "total_timesteps": total,
                "seed": run.seed,
                "backend": backend,
                "history": evaluator.history,
                "best_mean_reward": evaluator.best_mean_reward
                if np.isfinite(evaluator.best_mean_reward)
                else None,
            },
            min_timesteps=state["num_timesteps"] if state is not None else 0,
        )
        callbacks = CallbackList([*hyperparams.callbacks(), evaluator, checkpointer, *extra_callbacks])
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


def check_takes(algo: str, action_space: gym.spaces.Space) -> None:
    """
    Refuse an algorithm for an env whose action space it does not take (DQN on continuous actions), in one
    line naming both, before anything trains.

    :param algo: the algorithm.
    :param action_space: the env's action space.
    """
    record = algorithm(algo)
    if not record.takes(action_space):
        raise ValueError(
            f"Expected an env whose actions {record.name} takes ({sorted(record.action_spaces)}), actually "
            f"{action_space}"
        )


def check_flat_env(algo: str, env_id: str | None = None, env_kwargs: Mapping[str, Any] | None = None) -> None:
    """
    :func:`check_takes` for a flat agent of ``algo`` on ``gym.make(env_id, **env_kwargs)`` (default: the
    combined task, :data:`FLAT_ENV_ID`).
    """
    probe = make_snake_env(env_id or FLAT_ENV_ID, dict(env_kwargs or {}))
    try:
        check_takes(algo, probe.action_space)
    finally:
        probe.close()


def _remove_stale_temporaries(paths: AgentPaths) -> None:
    """
    A run killed mid-write (SIGKILL, power cut) leaves hidden temporaries; they never hold anything we
    read, so clear this agent's before they pile up (a replay buffer's can be large).
    """
    remove_stale_temporaries(paths.checkpoint_dir)
    remove_stale_temporaries(paths.best_dir)
    remove_stale_temporaries(paths.model_path.parent, target=paths.model_path.name)
    remove_stale_temporaries(paths.history_path.parent, target=paths.history_path.name)


def _resume_model(
    algo: str, backend: str, paths: AgentPaths, vec_env: Any
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
    """
    The periodic evaluator, continuing a resumed run's history and best reward, with the plateau rule
    (when ``run.stop_on_plateau``) and ``after_eval`` run after each evaluation.
    """
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
        callback_after_eval=_combine_callbacks(after_eval_callbacks),
        history=state.get("history", []) if state is not None else [],
        best_mean_reward=best if best is not None else -np.inf,
    )
    # SB3 makes only the direct after-eval callback a child of the evaluator; the plateau rule and the
    # pruner both read the evaluator's results through ``parent``, also when combined in a list.
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
    """
    Learn up to ``total`` steps in all; on Ctrl-C or SIGTERM save a checkpoint and raise
    :class:`TrainingInterrupted`.
    """
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


def _combine_callbacks(callbacks: Sequence[BaseCallback]) -> BaseCallback | None:
    """One callback for a slot that takes one: ``None``, the callback itself, or a ``CallbackList``."""
    if not callbacks:
        return None
    return callbacks[0] if len(callbacks) == 1 else CallbackList(list(callbacks))


def _tensorboard_logger(paths: AgentPaths) -> Any:
    folder = paths.tensorboard_dir / paths.name
    return configure(str(folder), ["tensorboard"])


def _agent_run(run: RunOptions, paths: AgentPaths, budget: int | None) -> RunOptions:
    """
    One agent's options within a command's ``run``: its own budget, and resume only when asked to and a
    checkpoint exists (killed before its first checkpoint, a run has nothing to resume and starts afresh).
    """
    resume = run.resume and read_checkpoint_state(paths.checkpoint_dir) is not None
    return run.replace(timesteps=budget, resume=resume)


def _finished(entry: Any, budget: int) -> bool:
    """Whether a manifest entry is a model that an earlier run finished with this budget."""
    return isinstance(entry, dict) and entry.get("timesteps_requested") == budget


def worker_env_factory(name: str, env_kwargs: dict[str, Any] | None = None) -> Callable[[], gym.Env]:
    """A picklable factory of the registered env whose reward is worker ``name``'s."""
    if name not in WORKER_ENV_IDS:
        raise ValueError(f"Unknown worker {name!r}; choose from {sorted(WORKER_ENV_IDS)}")
    return functools.partial(make_snake_env, WORKER_ENV_IDS[name], dict(env_kwargs or {}))


def worker_hyperparams(
    workers: Sequence[str],
    config: str | Path | None = None,
    env: TermsEnv | None = None,
    algos: Mapping[str, str] | None = None,
) -> dict[str, Hyperparams]:
    """
    Check worker names and read each worker's config block, before anything is trained: a bad block for
    the second worker should not surface after the first one has trained for an hour.

    :param workers: worker names among :data:`WORKER_ENV_IDS` (or ``env``'s terms), each at most once.
    :param config: a ``zoo_configs``-format file (default: each worker's algorithm's bundled one).
    :param algos: worker name -> its algorithm (:func:`worker_algorithms`; default: DDPG for each).
    :param env: another env with several objectives (default: the snake arm); its blocks are keyed by the
        adapted env's id, else ``default``.
    :return: name -> its parsed block; raises ``ValueError`` (``ConfigError`` for the file) naming the problem.
    """
    known = list(env.terms) if env is not None else sorted(WORKER_ENV_IDS)
    if isinstance(workers, str):
        raise ValueError(f"Expected a sequence of worker names, actually the string {workers!r}")
    if not workers:
        raise ValueError(f"Expected at least one worker; choose from {known}")
    unknown = [w for w in workers if w not in known]
    if unknown:
        raise ValueError(f"Unknown worker names {unknown}; choose from {known}")
    duplicates = sorted({w for w in workers if list(workers).count(w) > 1})
    if duplicates:
        raise ValueError(f"Duplicate worker names {duplicates} in {list(workers)}: name each worker once")
    chosen = worker_algorithms(workers, algos)
    blocks = {
        name: load_hyperparams(
            env.config_key if env is not None else WORKER_ENV_IDS[name],
            algorithm(chosen[name]).cls,
            config if config is not None else default_config(chosen[name]),
        )
        for name in workers
    }
    for name, block in blocks.items():
        env_id, view_kwargs = env.term_view(name) if env is not None else (WORKER_ENV_IDS[name], {})
        check_make_kwargs(env_id, {**view_kwargs, **block.env_kwargs}, f"worker {name!r}: env_kwargs")
    return blocks


def parse_worker_algorithms(text: str, workers: Sequence[str]) -> dict[str, str]:
    """
    Parse ``--algo``'s text: ``goal=crossq,avoid=sac`` (a worker not named keeps DDPG), or one algorithm
    name for every worker (``crossq``).

    :param text: the option's value.
    :param workers: the workers being trained.
    :return: worker name -> algorithm, checked by :func:`worker_algorithms`.
    """
    parts = [part.strip() for part in text.split(",") if part.strip()]
    if len(parts) == 1 and "=" not in parts[0]:
        return worker_algorithms(workers, dict.fromkeys(workers, parts[0]))
    algos: dict[str, str] = {}
    for part in parts:
        name, sep, algo = (piece.strip() for piece in part.partition("="))
        if not sep or not name or not algo:
            raise ValueError(
                f"Expected WORKER=ALGORITHM pairs separated by commas, actually {part!r} in {text!r}"
            )
        if name in algos:
            raise ValueError(f"Expected each worker once, actually {name!r} twice in {text!r}")
        algos[name] = algo
    return worker_algorithms(workers, algos)


def worker_algorithms(workers: Sequence[str], algos: Mapping[str, str] | None = None) -> dict[str, str]:
    """
    Each worker's algorithm: the one ``algos`` names, else DDPG (the paper's); checked against the
    algorithm records (a worker role).

    :param workers: the worker names.
    :param algos: worker name -> algorithm name (any case); a name not among ``workers`` is refused.
    :return: worker name -> registry name.
    """
    algos = dict(algos or {})
    unknown = sorted(set(algos) - set(workers))
    if unknown:
        raise ValueError(f"Expected algorithms for the workers {list(workers)}, actually also for {unknown}")
    chosen = {name: algorithm(algos.get(name, DEFAULT_WORKER_ALGO)).name for name in workers}
    for name, algo in chosen.items():
        if "worker" not in REGISTRY[algo].roles:
            raise ValueError(
                f"Expected a worker algorithm for {name!r}, actually {algo!r}, which cannot be one"
            )
    return chosen


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


def manager_hyperparams(algo: str = "ddpg", config: str | Path | None = None) -> Hyperparams:
    """
    The ``manager`` block a manager of ``algo`` trains from.

    :param config: a ``zoo_configs``-format file (default: ``algo``'s bundled one).
    """
    return load_hyperparams(MANAGER_KEY, algo_class(algo), config or default_config(algo), manager=True)


@holds_folder_lock(lambda call: call.arguments["out_dir"])
def train_workers(
    out_dir: str | Path,
    workers: Sequence[str] | None = None,
    config: str | Path | None = None,
    *,
    run: RunOptions | None = None,
    on_worker_done: Callable[[str, TrainingOutcome], None] | None = None,
    extra_callbacks: Sequence[BaseCallback] = (),
    env: TermsEnv | None = None,
    algos: Mapping[str, str] | None = None,
    **run_changes: Any,
) -> dict[str, Any]:
    """
    Train each named worker as a plain SB3 model (DDPG, the paper's, unless ``algos`` names another) on its
    own registered env id (paper Algorithm 1, first half) and write ``out_dir/workers/<name>.zip`` and
    ``out_dir/workers/manifest.json``.

    :param out_dir: the run folder.
    :param workers: worker names among :data:`WORKER_ENV_IDS`, or ``env``'s terms (``None``: all of them).
    :param config: a ``zoo_configs``-format file (default: each worker's algorithm's bundled one).
    :param algos: worker name -> its algorithm (e.g. ``{"goal": "crossq"}``; default: DDPG for each).
    :param run: the run-control settings (:class:`~sb3_hddpg.training.run_options.RunOptions`): the same for every worker; ``timesteps`` is per worker, and ``resume`` keeps finished workers and continues interrupted ones.
    :param run_changes: :class:`~sb3_hddpg.training.run_options.RunOptions` fields as keywords (e.g.
        ``seed=3``), over ``run``'s.
    :param on_worker_done: called after each worker with its outcome.
    :param extra_callbacks: more SB3 callbacks for every worker (e.g. progress reporting).
    :param env: another env with several objectives (:func:`~sb3_hddpg.envs.terms_env.terms_env`; default:
        the snake arm): one worker per named term, each on that term's view; the manifest records the
        shared env (``shared_env``) so that ``train_manager`` acts in it.
    :return: the manifest written.
    """
    run = run_options(run, run_changes, "train_workers")
    shared = env if env is not None else TermsEnv(SNAKE_REACH_ENV_ID, {}, REWARD_TERMS)
    if workers is None:
        workers = list(shared.terms)
    chosen = worker_algorithms(workers, algos)
    blocks = worker_hyperparams(workers, config, env, chosen)
    out_dir = Path(out_dir)
    manifest_path = out_dir / "workers" / "manifest.json"
    manifest = models_manifest("workers")
    if run.resume and manifest_path.exists():
        manifest = read_models_manifest(manifest_path, "workers")
        if env is not None or manifest.shared_env is not None:
            check_resumed_env(
                manifest.shared_env or {"env_id": SNAKE_REACH_ENV_ID}, shared.env_id, shared.env_kwargs
            )
        for name in workers:
            env_id, view_kwargs = shared.term_view(name)
            check_resumed_env(manifest.entries.get(name), env_id, {**view_kwargs, **blocks[name].env_kwargs})
    if env is not None:
        manifest = manifest.with_shared_env(env.env_id, env.env_kwargs)
    for name in workers:
        hyperparams = blocks[name]
        env_id, view_kwargs = shared.term_view(name)
        env_kwargs = {**view_kwargs, **hyperparams.env_kwargs}
        budget = int(run.timesteps if run.timesteps is not None else hyperparams.n_timesteps)
        if run.resume and _finished(manifest.entries.get(name), budget):
            continue  # finished in an earlier run
        paths = AgentPaths(out_dir, name, out_dir / "workers" / f"{name}.zip")
        outcome = train_agent(
            functools.partial(make_term_view, env_id, env_kwargs, name),
            hyperparams,
            paths,
            algo=chosen[name],
            run=_agent_run(run, paths, budget),
            extra_callbacks=extra_callbacks,
        )
        probe = make_term_view(env_id, env_kwargs, name)
        bounds = env_contract(probe).reward_bounds[name]
        probe.close()
        entry = model_entry(
            name,
            outcome,
            chosen[name],
            env_id,
            env_kwargs,
            {
                "file": str(config) if config else f"sb3_hddpg/zoo_configs/{chosen[name]}.yml",
                "block": hyperparams.raw,
            },
            run.seed,
            budget,
            reward_term=name,
            reward_bounds=list(bounds),
            stopped_early=outcome.stopped_early,
            threads=run.threads,
        )
        manifest = manifest.with_entry(name, entry)
        save_manifest(manifest_path, manifest)
        if on_worker_done is not None:
            on_worker_done(name, outcome)
    return manifest.to_json()


#: The env a flat baseline learns: both objectives in one reward (the normalised sum of the terms).
FLAT_ENV_ID = SNAKE_REACH_ENV_ID
#: The config block of a flat agent given the goal worker's tricks (hindsight relabelling of the goal, the
#: action penalty where the algorithm takes it) on the full observation and the reach reward.
FLAT_HER_KEY = "flat-her"


@holds_folder_lock(lambda call: call.arguments["out_dir"])
def train_flat(
    out_dir: str | Path,
    algo: str = "ddpg",
    config: str | Path | None = None,
    *,
    run: RunOptions | None = None,
    env_id: str = FLAT_ENV_ID,
    preferences: dict[str, float] | None = None,
    env_kwargs: dict[str, Any] | None = None,
    name: str | None = None,
    extra_callbacks: Sequence[BaseCallback] = (),
    block: str | None = None,
    **run_changes: Any,
) -> tuple[dict[str, Any], TrainingOutcome | None]:
    """
    Train a flat baseline: one SB3 model on the combined reward of ``hddpg/SnakeReach-v0`` (the paper's
    "single DDPG", Section 3.3), and write ``out_dir/flat/<name>.zip`` and ``out_dir/flat/manifest.json``.

    The manifest's ``models`` mapping has one entry per model name (by default the algorithm), in the workers manifest's format
    (file, sha256, algo, env id and kwargs, rebuild spec, metrics, config, seed, versions), so that
    :func:`sb3_hddpg.hierarchy.loading.load_policy` opens the zip without unpickling anything.

    :param out_dir: the run folder.
    :param algo: ``ddpg``, ``td3``, ``sac`` or ``tqc``.
    :param config: a ``zoo_configs``-format file (default: the bundled ``zoo_configs/<algo>.yml``).
    :param run: the run-control settings (:class:`~sb3_hddpg.training.run_options.RunOptions`); with ``resume`` a model already finished with this budget is kept.
    :param run_changes: :class:`~sb3_hddpg.training.run_options.RunOptions` fields as keywords (e.g.
        ``seed=3``), over ``run``'s.
    :param env_id: the env to learn (the combined reward by default).
    :param env_kwargs: its keyword arguments, over the config block's; the block read is the adapted env's
        for an adapter (:func:`~sb3_hddpg.envs.terms_env.config_key`), as the workers' is.
    :param preferences: reward term -> factor: learn ``sum_t factor_t * normalised(term_t)`` instead of the
        env's reward (:class:`~sb3_hddpg.hierarchy.preference.PreferenceReward`, the reward of a manager with the same
        factors); ``None``: the env's own reward.
    :param name: the model's name in the manifest and its file name (default: ``algo``).
    :param extra_callbacks: more SB3 callbacks (e.g. progress reporting).
    :param block: the config block to train from instead of the env's (e.g. :data:`FLAT_HER_KEY`: the goal
        worker's hindsight relabelling and action penalty on the full observation and the env's reward).
    :return: the manifest written, and the training outcome (``None`` when a finished model was kept).
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
    manifest = (
        read_models_manifest(manifest_path, "models") if manifest_path.exists() else models_manifest("models")
    )
    name = name or algo
    if run.resume:
        check_resumed_env(manifest.entries.get(name), env_id, make_kwargs)
    if run.resume and _finished(manifest.entries.get(name), budget):
        return manifest.to_json(), None  # finished in an earlier run
    paths = AgentPaths(out_dir, f"flat-{algo}", out_dir / "flat" / f"{name}.zip")
    factory: Callable[[], gym.Env] = functools.partial(make_snake_env, env_id, make_kwargs)
    if preferences is not None:
        factory = functools.partial(make_preference_env, env_id, make_kwargs, dict(preferences))
        factory().close()  # checks the factors here, once, rather than inside env subprocesses
    outcome = train_agent(
        factory,
        hyperparams,
        paths,
        algo=algo,
        run=_agent_run(run, paths, budget),
        extra_callbacks=extra_callbacks,
    )
    entry = model_entry(
        name,
        outcome,
        algo,
        env_id,
        make_kwargs,
        {"file": str(config_path), "block": hyperparams.raw},
        run.seed,
        budget,
        stopped_early=outcome.stopped_early,
        preferences=dict(preferences) if preferences is not None else None,
        threads=run.threads,
    )
    manifest = manifest.with_entry(name, entry)
    save_manifest(manifest_path, manifest)
    return manifest.to_json(), outcome


@dataclass
class ManagerEnvFactory:
    """
    Builds the manager's env: the shared env wrapped in ``WorkerSelectionWrapper`` over the workers.

    The workers are the ones already loaded (``workers``), so a run loads and verifies them once; pickled
    into a ``SubprocVecEnv`` process the factory drops them and that process loads them from
    ``workers_dir`` once (hashes verified), for all the envs it builds.

    :param env_id: the shared env.
    :param env_kwargs: its keyword arguments.
    :param workers_dir: the workers' folder (for processes that must load them themselves).
    :param worker_names: the workers, in the manager's action order.
    :param wrapper_kwargs: the selection settings (``SelectionConfig.wrapper_kwargs()``).
    :param trusted: load the workers with SB3's full loader.
    :param workers: name -> worker already loaded in this process (``None``: load on first use).
    """

    env_id: str
    env_kwargs: dict[str, Any]
    workers_dir: str
    worker_names: Sequence[str]
    wrapper_kwargs: dict[str, Any]
    trusted: bool = False
    workers: Mapping[str, Any] | None = None

    def __call__(self) -> gym.Env:
        if self.workers is None:
            self.workers = load_workers(self.workers_dir, self.worker_names, trusted=self.trusted)
        env = make_snake_env(self.env_id, self.env_kwargs)
        return WorkerSelectionWrapper(env, self.workers, **self.wrapper_kwargs)

    def __getstate__(self) -> dict[str, Any]:
        # Models do not cross process boundaries: the receiving process loads them from the files.
        return {**self.__dict__, "workers": None}


@dataclass
class ManagerSetup:
    """
    Everything :func:`train_manager` needs before training starts, checked: see :func:`prepare_manager`.

    :param workers: the loaded workers, in the manager's action order.
    :param manifest: the workers' manifest.
    :param hyperparams: the manager's config block.
    :param selection: the selection settings, preferences included.
    :param env_id: the shared env the manager acts in.
    :param env_kwargs: its keyword arguments (from the manager's config block).
    :param algo: the manager's algorithm, one of :data:`MANAGER_ALGOS`.
    :param ham_start: imitate HAM before RL (``None``: start from the random initialisation).
    """

    workers: Workers
    manifest: ModelsManifest
    hyperparams: Hyperparams
    selection: SelectionConfig
    env_id: str
    env_kwargs: dict[str, Any]
    workers_dir: str = ""
    trusted: bool = False
    algo: str = "ddpg"
    ham_start: HamStart | None = None

    @property
    def names(self) -> list[str]:
        return list(self.workers)

    def env_factory(self) -> ManagerEnvFactory:
        """The manager's env factory over these (already loaded) workers."""
        return ManagerEnvFactory(
            self.env_id,
            self.env_kwargs,
            self.workers_dir,
            self.names,
            self.selection.wrapper_kwargs(),
            self.trusted,
            self.workers,
        )


def prepare_manager(
    workers_dir: str | Path,
    worker_names: Sequence[str] | None = None,
    prefer: str | None = None,
    bias: float = 0.15,
    preferences: dict[str, float] | None = None,
    selection: str | None = None,
    option_steps: int | None = None,
    temperature: float | None = None,
    floor: float | None = None,
    config: str | Path | None = None,
    trusted: bool = False,
    env_id: str | None = None,
    env_kwargs: dict[str, Any] | None = None,
    algo: str = "ddpg",
    manager_preferences: str | PreferenceSpace | None = None,
    relabel_fraction: float = 0.5,
    init_from_ham: float | HamStart | None = None,
    option_end: str | OptionEnd | None = None,
) -> ManagerSetup:
    """
    Load and check everything the manager is trained from, without training: the workers (hashes
    verified), the config block, the preferences and selection settings, and that every worker fits the
    manager's env. :func:`train_manager` calls it first; call it yourself to validate arguments early (the
    CLI does, to report bad input before creating the output folder). Arguments as in :func:`train_manager`,
    and ``env_id`` / ``env_kwargs``: the shared env (default: the workers manifest's ``shared_env``, else
    ``hddpg/SnakeReach-v0``; ``env_kwargs`` go under the config block's), and ``algo``: the manager's
    algorithm, one of :data:`MANAGER_ALGOS`, whose bundled config (``zoo_configs/<algo>.yml``) is the default.

    :return: the checked set-up; raises ``ValueError`` (or ``FileNotFoundError``) naming the problem.
    """
    if worker_names is not None and isinstance(worker_names, str):
        raise ValueError(f"Expected a sequence of worker names, actually the string {worker_names!r}")
    if algo not in MANAGER_ALGOS:
        raise ValueError(f"Unknown manager algorithm {algo!r}; choose from {list(MANAGER_ALGOS)}")
    config = config if config is not None else default_config(algo)
    hyperparams = manager_hyperparams(algo, config)
    workers = load_workers(workers_dir, worker_names, trusted=trusted)
    manifest = workers.manifest
    env_id, given_kwargs = shared_env_of(manifest, env_id, env_kwargs, trusted)
    names = list(workers)
    wrapper_kwargs = dict(hyperparams.wrapper_kwargs)
    factors = preferences_from_bias(names, prefer, bias)
    if preferences:
        factors = check_preferences(preferences, names)
    if manager_preferences is not None:
        factors, hyperparams = _conditioned(
            wrapper_kwargs, hyperparams, algo, names, manager_preferences, preferences, relabel_fraction
        )
    for key, value in (
        ("selection", selection),
        ("option_steps", option_steps),
        ("temperature", temperature),
        ("floor", floor),
    ):
        if value is not None:
            wrapper_kwargs[key] = value
    wrapper_kwargs["preferences"] = factors
    wrapper_kwargs["option_end"] = _option_end_json(option_end, wrapper_kwargs.get("option_end"))
    # A worker trained on part of the state (env_kwargs `observe`) is fed the same components of the
    # manager's full state; a worker_states entry in the config block wins.
    configured = wrapper_kwargs.get("worker_states") or {}
    if not isinstance(configured, dict):
        raise ValueError(
            f"Expected wrapper_kwargs.worker_states to map worker names to component lists, actually: {configured!r:.200}"
        )
    wrapper_kwargs["worker_states"] = {**workers.states, **configured}
    try:
        selection_config = SelectionConfig(**wrapper_kwargs)
    except TypeError as error:  # an unknown key in the config's wrapper_kwargs
        raise ValueError(f"Invalid wrapper_kwargs in the manager's config block: {error}") from None
    env_kwargs = check_make_kwargs(env_id, {**given_kwargs, **hyperparams.env_kwargs}, "manager env_kwargs")
    if "observe" in env_kwargs:
        raise ValueError(
            "The manager's env must give the full state (its workers slice it): remove `observe` from the "
            "manager block's env_kwargs; to feed the manager part of the state, set wrapper_kwargs.manager_state"
        )
    probe = make_snake_env(env_id, env_kwargs)
    try:
        expected = probe.observation_space.shape
        for name, worker in workers.items():
            space = getattr(worker, "observation_space", None)
            sliced = name in selection_config.worker_states  # the wrapper checks the sliced shape itself
            if space is not None and not sliced and space.shape != expected:
                trained_on = brief(manifest.entries[name].get("env_kwargs", {}))
                raise ValueError(
                    f"Worker {name!r} was trained on observations of shape {space.shape} (env_kwargs "
                    f"{trained_on}), but the manager's env {env_id} with env_kwargs {env_kwargs} gives "
                    f"{expected}: give the manager's config block the workers' env_kwargs"
                )
        # The wrapper's own checks (spaces, reward terms, state names, temperature, floor), run once here
        # in this process, so that they fail with one clear error rather than inside env subprocesses.
        WorkerSelectionWrapper(probe, workers, **selection_config.wrapper_kwargs())
    finally:
        probe.close()
    return ManagerSetup(
        workers,
        manifest,
        hyperparams,
        selection_config,
        env_id,
        env_kwargs,
        str(Path(workers_dir)),
        trusted,
        algo,
        _ham_start(init_from_ham, names, algo),
    )


def _option_end_json(given: str | OptionEnd | None, configured: Any) -> dict[str, Any] | None:
    """The option end as a bundle records it: the one given, else the config block's (``None``: none)."""
    if given is None:
        return configured
    return (OptionEnd.parse(given) if isinstance(given, str) else given).to_json()


def _conditioned(
    wrapper_kwargs: dict[str, Any],
    hyperparams: Hyperparams,
    algo: str,
    names: list[str],
    given: str | PreferenceSpace,
    preferences: dict[str, float] | None,
    relabel_fraction: float,
) -> tuple[dict[str, float], Hyperparams]:
    """
    A conditioned manager's settings: its space in ``wrapper_kwargs``, the preference it acts at first (the
    unweighted one unless given, within the space) and its config block with the relabelling buffer.
    """
    conditioning = _preference_space(given, names)
    wrapper_kwargs["manager_preferences"] = conditioning.to_json()
    factors = conditioning.check(preferences or conditioning.default)
    return factors, _with_preference_relabeling(hyperparams, algo, names, conditioning, relabel_fraction)


def _ham_start(given: float | HamStart | None, names: list[str], algo: str) -> HamStart | None:
    """The start from HAM, checked: HAM switches between workers named ``goal`` and ``avoid``."""
    if given is None:
        return None
    if algo not in HAM_START_ALGOS:
        raise ValueError(f"The start from HAM fits managers of {list(HAM_START_ALGOS)}, not {algo!r}")
    if not {"goal", "avoid"} <= set(names):
        raise ValueError(
            f"The start from HAM needs workers named 'goal' and 'avoid' (HAM's two), actually: {names}"
        )
    return given if isinstance(given, HamStart) else HamStart(float(given))


def _preference_space(given: str | PreferenceSpace, names: list[str]) -> PreferenceSpace:
    """A conditioned manager's preference space, from its command-line form or as given, for ``names``."""
    space = PreferenceSpace.parse(given, names) if isinstance(given, str) else given
    if list(space.names) != names:
        raise ValueError(f"The preference space names workers {list(space.names)}, the manager {names}")
    return space


def _with_preference_relabeling(
    hyperparams: Hyperparams, algo: str, names: list[str], space: PreferenceSpace, relabel_fraction: float
) -> Hyperparams:
    """
    The manager's config block with the preference-relabelling replay buffer, for an algorithm with a replay
    buffer (an on-policy one, PPO, learns from the preference drawn each episode only).
    """
    if "replay_buffer_class" not in inspect.signature(algo_class(algo).__init__).parameters:
        return hyperparams
    if hyperparams.algo_kwargs.get("replay_buffer_class") is not None:
        raise ValueError(
            "A conditioned manager replays its steps with PreferenceRelabelingReplayBuffer: remove "
            "replay_buffer_class from the manager's config block"
        )
    if not 0.0 <= relabel_fraction <= 1.0:
        raise ValueError(f"Expected the relabel fraction in [0, 1], actually: {relabel_fraction}")
    kwargs = {
        **hyperparams.algo_kwargs,
        "replay_buffer_class": PreferenceRelabelingReplayBuffer,
        "replay_buffer_kwargs": {
            "names": names,
            "space": space.to_json(),
            "relabel_fraction": relabel_fraction,
        },
    }
    return replace(hyperparams, algo_kwargs=kwargs)


#: The manager's env and selection settings, kept beside its model so that a resumed run continues on the
#: same MDP.
MANAGER_SETTINGS_FILE = "manager_settings.json"


def _check_manager_resume(
    paths: AgentPaths, resume: bool, setup: ManagerSetup, selection: dict[str, Any]
) -> None:
    """
    Keep the manager's MDP (env, workers, algorithm, selection settings) beside its model; a resumed
    run whose MDP differs is refused in one line naming the difference
    (:func:`~sb3_hddpg.artifacts.manifests.check_resumed_env`), since its replay buffer and network were
    made on the recorded one.
    """
    mdp: dict[str, Any] = {
        **setup.env_kwargs,
        "workers": list(setup.workers),
        "algo": setup.algo,
        "selection": selection,
    }
    path = paths.model_path.parent / MANAGER_SETTINGS_FILE
    if resume and read_checkpoint_state(paths.checkpoint_dir) is not None and path.is_file():
        check_resumed_env(read_json_file(path), setup.env_id, mdp)
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(path, {"env_id": setup.env_id, "env_kwargs": mdp})


@holds_folder_lock(lambda call: call.arguments["out_dir"])
def train_manager(
    workers_dir: str | Path | ManagerSetup,
    out_dir: str | Path,
    worker_names: Sequence[str] | None = None,
    prefer: str | None = None,
    bias: float | None = None,
    preferences: dict[str, float] | None = None,
    selection: str | None = None,
    option_steps: int | None = None,
    temperature: float | None = None,
    floor: float | None = None,
    config: str | Path | None = None,
    trusted: bool | None = None,
    env_id: str | None = None,
    env_kwargs: dict[str, Any] | None = None,
    algo: str | None = None,
    manager_preferences: str | PreferenceSpace | None = None,
    relabel_fraction: float | None = None,
    init_from_ham: float | HamStart | None = None,
    option_end: str | OptionEnd | None = None,
    *,
    run: RunOptions | None = None,
    extra_callbacks: Sequence[BaseCallback] = (),
    **run_changes: Any,
) -> tuple[Any, TrainingOutcome]:
    """
    Train the manager: a plain SB3 DDPG (or TD3 or SAC, ``algo``) on ``WorkerSelectionWrapper`` over
    pre-trained workers (paper Algorithm 1, second half), and write ``out_dir/hierarchy.zip``.

    Preference factors (paper Section 3.4): by default every worker's factor is 1; ``prefer=NAME`` makes
    that worker's ``1 + bias`` (the paper's 15 % by default); ``preferences`` sets every factor explicitly
    and wins over ``prefer``. A factor multiplies the worker's normalised reward term in the manager's
    reward, so the manager is paid more for the preferred worker's objective.

    :param workers_dir: the run folder of ``train-workers`` (or its ``workers`` folder), or the set-up
        :func:`prepare_manager` returned: then the workers it loaded are used as they are (nothing is loaded
        or checked twice) and the arguments of :func:`prepare_manager` below must be left out.
    :param out_dir: the run folder for the manager.
    :param worker_names: which workers, in the manager's action order (default: all in the manifest).
    :param prefer: a worker to prefer.
    :param bias: the preferred worker's extra factor, > 0 (default 0.15).
    :param preferences: explicit factors, name -> value.
    :param selection: a registered selection mode (default: the config's ``wrapper_kwargs``).
    :param option_steps: env steps per manager decision (default: the config's).
    :param temperature: the simplex map's temperature (default: the config's).
    :param floor: the probability floor (default: the config's).
    :param config: a ``zoo_configs`` file; its ``manager`` block is used.
    :param trusted: load the workers with SB3's full loader (default ``False``).
    :param env_id: the shared env the manager acts in (default: the workers manifest's ``shared_env``,
        else ``hddpg/SnakeReach-v0``).
    :param env_kwargs: its keyword arguments (default: the manifest's, with the config block's on top).
    :param algo: the manager's algorithm, one of :data:`MANAGER_ALGOS` (default ``ddpg``, the paper's);
        its bundled config ``zoo_configs/<algo>.yml`` is the default ``config``.
    :param manager_preferences: train one manager for every preference (see
        :class:`~sb3_hddpg.hierarchy.conditioning.PreferenceSpace`): ``"ratio-sweep"``,
        ``"dirichlet[:ALPHA]"``, ``"goal=1.6,avoid=0.4;goal=0.4,avoid=1.6"`` or a space. The manager observes
        the normalised preference weights, a preference is drawn every episode, and an off-policy manager
        replays stored steps at other preferences (``PreferenceRelabelingReplayBuffer``). The bundle records
        the space (``selection.manager_preferences``); ``Hierarchy.set_preference`` picks one at run time.
        ``preferences`` is then the one the bundle acts at first (default: the unweighted one).
    :param relabel_fraction: a conditioned off-policy manager's share of replayed steps given another
        preference (default 0.5).
    :param init_from_ham: start from the hand-written rule: HAM's threshold (or a
        :class:`~sb3_hddpg.training.ham_start.HamStart`); the manager imitates HAM's choices and its replay
        buffer is filled with them before RL (:mod:`sb3_hddpg.training.ham_start`). The bundle's metadata
        keeps the settings and how often the fitted manager agrees with HAM.
    :param option_end: options that also end by state: ``"distance=0.5"`` (an obstacle comes within half
        the sensor range or leaves it), ``"touch"`` (the goal is touched or lost), both (``"distance=0.5,touch"``)
        or an :class:`~sb3_hddpg.hierarchy.selection.OptionEnd`; ``option_steps`` stays the longest option.
    :param run: the run-control settings (:class:`~sb3_hddpg.training.run_options.RunOptions`) for the manager's DDPG; the bundle holds an SB3 manager whichever ``backend`` trains it.
    :param run_changes: :class:`~sb3_hddpg.training.run_options.RunOptions` fields as keywords (e.g.
        ``seed=3``), over ``run``'s.
    :param extra_callbacks: more SB3 callbacks (e.g. progress reporting).
    :return: the saved :class:`~sb3_hddpg.hierarchy.hierarchy.Hierarchy` and the training outcome.
    """
    run = run_options(run, run_changes, "train_manager")
    preparation: dict[str, Any] = {
        key: value
        for key, value in (
            ("worker_names", worker_names),
            ("prefer", prefer),
            ("bias", bias),
            ("preferences", preferences),
            ("selection", selection),
            ("option_steps", option_steps),
            ("temperature", temperature),
            ("floor", floor),
            ("config", config),
            ("trusted", trusted),
            ("env_id", env_id),
            ("env_kwargs", env_kwargs),
            ("algo", algo),
            ("manager_preferences", manager_preferences),
            ("relabel_fraction", relabel_fraction),
            ("init_from_ham", init_from_ham),
            ("option_end", option_end),
        )
        if value is not None
    }
    if isinstance(workers_dir, ManagerSetup):
        if preparation:
            raise ValueError(
                f"train_manager got a prepared set-up and also {sorted(preparation)}: give those to prepare_manager"
            )
        setup = workers_dir
    else:
        setup = prepare_manager(workers_dir, **preparation)
    workers = setup.workers
    hyperparams, selection_config, env_kwargs = setup.hyperparams, setup.selection, setup.env_kwargs
    factory = setup.env_factory()
    out_dir = Path(out_dir)
    paths = AgentPaths(out_dir, "manager", out_dir / "manager" / "manager.zip")
    _check_manager_resume(paths, run.resume, setup, asdict(selection_config))
    ham_report: dict[str, Any] = {}
    outcome = train_agent(
        factory,
        hyperparams,
        paths,
        algo=setup.algo,
        run=_agent_run(run, paths, run.timesteps),
        extra_callbacks=[SelectionStatsCallback(), *extra_callbacks],
        prepare_model=(
            ham_start_hook(setup.ham_start, factory, run.seed, ham_report)
            if setup.ham_start is not None
            else None
        ),
    )
    hierarchy = Hierarchy(
        outcome.model,
        workers,
        selection_config,
        env_id=setup.env_id,
        env_kwargs=env_kwargs,
        worker_meta=workers.bundle_meta(),
        metadata={
            "seed": run.seed,
            "timesteps_trained": outcome.num_timesteps,
            "config": hyperparams.raw,
            "metrics": outcome.metrics,
            "backend": outcome.backend,
            **({"init_from_ham": ham_report} if ham_report else {}),
        },
    )
    hierarchy.save(out_dir / "hierarchy.zip")
    return hierarchy, outcome

"""
Hyperparameter tuning with Optuna at every level: a worker, the manager, the flat baseline, and HAM's switch.

One trial samples a ``zoo_configs`` block with :func:`~sb3_hddpg.experiments.hyperparams_opt.sampler_for` (one sampler per
level; per algorithm for the levels that train one, as its record names), trains it with :func:`~sb3_hddpg.training.training.train_agent` (the same code as ``train-*``), reports ``n_evaluations``
evaluations to the pruner through :class:`~sb3_hddpg.callbacks.TrialPruningCallback`, and returns the last
evaluation's mean reward (rl_zoo3's objective: the best of several noisy evaluations would favour lucky
configurations). Which trial is *best* is a separate choice (:data:`RANKINGS`): by that value, or by the
trial's best evaluation, the checkpoint every ``train-*`` command keeps. A policy stuck on one constant
action scores the same at every evaluation, and can win the first ranking by a point over one that
learns and swings. A trial that diverges (NaN reward or weights, or an exception about NaN) is pruned, not
failed: it is a bad configuration, not a bug. HAM trains nothing: its trial is one evaluation.

:func:`tune` runs ``n_jobs`` processes (not threads: training holds the GIL between torch calls) on one
study in a shared storage (see :mod:`sb3_hddpg.experiments.study_storage`). ``n_trials`` is the *study's* target of
finished (complete or pruned) trials, so a re-run after an interruption completes the same study, and any
number of processes, on any number of machines, together finish exactly that many.
"""

from __future__ import annotations

import contextlib
import copy
import datetime
import functools
import logging
import math
import re
import tempfile
import time
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import optuna
import torch
import yaml
from optuna.trial import FrozenTrial, TrialState

from sb3_hddpg.artifacts.io import atomic_write_bytes
from sb3_hddpg.artifacts.manifests import load_workers, read_workers_manifest
from sb3_hddpg.artifacts.records import ModelsManifest
from sb3_hddpg.artifacts.workers import observed_components, shared_env_of
from sb3_hddpg.baselines.ham import DEFAULT_MARGIN, HAMSwitch
from sb3_hddpg.callbacks.pruning import TrialPruningCallback
from sb3_hddpg.envs.contract import state_layout_of
from sb3_hddpg.envs.terms_env import TermsEnv, make_term_view
from sb3_hddpg.episode_sets import CURVE, TUNING, episode_set
from sb3_hddpg.evaluation import evaluate
from sb3_hddpg.experiments.executors import make_executor
from sb3_hddpg.experiments.hyperparams_opt import base_params, sampler_for
from sb3_hddpg.experiments.runner import Job, run_jobs
from sb3_hddpg.experiments.study_storage import TrialClaimLock, make_storage, quiet_experimental, sqlite_path
from sb3_hddpg.hierarchy.hierarchy import SelectionConfig
from sb3_hddpg.training.config import (
    DEFAULT_CONFIG,
    MANAGER_KEY,
    default_config,
    load_config_file,
    load_hyperparams,
    parse_block,
    select_block,
)
from sb3_hddpg.training.run_options import RunOptions
from sb3_hddpg.training.training import (
    WORKER_ENV_IDS,
    AgentPaths,
    ManagerEnvFactory,
    TrainingInterrupted,
    algo_class,
    make_snake_env,
    train_agent,
    worker_env_factory,
)

logger = logging.getLogger(__name__)

#: What can be tuned.
LEVELS = ("worker", "manager", "flat", "ham")
#: ``--sampler`` choices.
SAMPLERS = ("tpe", "random")
#: ``--pruner`` choices.
PRUNERS = ("median", "halving", "none")
#: The env of the manager, the flat baseline and HAM on the snake arm: the combined reward.
SHARED_ENV_ID = "hddpg/SnakeReach-v0"
#: The state component HAM's switch rule reads (the snake's per-link obstacle clearances).
HAM_COMPONENT = "joint_obstacle_distances"
#: How :func:`best_trials` ranks completed trials: ``last`` by the Optuna value, a trial's last evaluation
#: (rl_zoo3's objective); ``peak`` by its best evaluation, the checkpoint that ``train-*`` and the benchmark
#: keep. HAM's trial is one evaluation: both are the same there.
RANKINGS = ("last", "peak")
#: Trial states that count towards ``n_trials``.
FINISHED_STATES = (TrialState.COMPLETE, TrialState.PRUNED)
#: Startup trials of TPE (random ones before it models anything) and of the median pruner, as in rl_zoo3.
N_STARTUP_TRIALS = 10
N_STARTUP_TRIALS_PRUNER = 5

_NAN_MESSAGE = re.compile(r"\bnan\b|non-finite|not finite|\binf\b|infinit", re.IGNORECASE)


def check_budget_fraction(fraction: float | None, final_budget: int | None, timesteps: int | None) -> None:
    """
    A trial budget given as a share: ``fraction`` in (0, 1] of a ``final_budget`` >= 1, and not with
    ``timesteps`` too (nothing to check without ``fraction``).

    :raises ValueError: naming the field, the expected and the actual value.
    """
    if fraction is None:
        return
    if not 0 < fraction <= 1:
        raise ValueError(f"Expected budget_fraction in (0, 1], actually: {fraction!r}")
    if final_budget is None or final_budget < 1:
        raise ValueError(
            f"Expected final_budget >= 1 env steps with budget_fraction, actually: {final_budget!r}"
        )
    if timesteps is not None:
        raise ValueError(
            f"Expected timesteps or budget_fraction, not both; actually: {timesteps} and {fraction}"
        )


@dataclass(frozen=True)
class TuningTarget:
    """
    What a study tunes, and how each trial is trained and evaluated. Picklable, so that every trial
    process rebuilds the same objective.

    :param level: ``worker``, ``manager``, ``flat`` or ``ham``.
    :param worker: the worker to tune (``goal`` or ``avoid``; level ``worker`` only).
    :param workers_dir: a ``train-workers`` run folder (levels ``manager`` and ``ham``).
    :param config: the base ``zoo_configs`` file whose block the sampled values override (default: the
        bundled one); its other keys (``learning_starts``, ``env_kwargs``...) are kept.
    :param timesteps: training steps per trial (default: ``budget_fraction`` of ``final_budget``, else the
        base block's ``n_timesteps``).
    :param budget_fraction: each trial's env steps as this share of ``final_budget``, the method's budget in
        the benchmark, so that every method's study spends the same share of what it finally trains with.
    :param final_budget: the method's final budget in env steps (needed with ``budget_fraction``).
    :param block: level ``flat`` only: another block of the base config to tune instead of the env's, e.g.
        ``flat-her`` (the benchmark's ``sac-her`` / ``ddpg-her``: the goal worker's tricks on the reach task).
    :param episode_set: the episodes every trial is evaluated on (:mod:`sb3_hddpg.episode_sets`): the tuning
        set, disjoint from the curve episodes the benchmark picks checkpoints on and from every test set;
        ``curve`` resumes a study made before studies had their own episodes.
    :param n_evaluations: evaluations per trial, evenly spread, each reported to the pruner.
    :param eval_episodes: episodes per evaluation.
    :param seed: the training seed of every trial (the same for all, so trials differ only by their
        hyperparameters).
    :param n_seeds: training seeds per trial, ``seed``, ``seed + 1``...: a trial's value is the mean over
        them of each run's last evaluation (its ``peak`` score the mean of each run's best), so that a
        configuration is ranked on what it does across seeds rather than on one seed's luck. Each costs
        the trial budget again.
    :param algo: the algorithm (levels ``worker``, ``flat`` and ``manager``: one whose record plays the role,
        each with its own search space and bundled base config ``zoo_configs/<algo>.yml``).
    :param backend: the trials' training backend, ``sb3`` or ``sbx`` (``None``: the base block's
        ``backend`` key, else ``sb3``).
    :param env: another env with several objectives (:func:`~sb3_hddpg.envs.terms_env.terms_env`, the
        same as ``train-workers --env``; ``None``: the snake arm). Level ``worker`` tunes the worker of one
        of its terms on that term's view, ``flat`` a flat agent on its shared env; level ``manager`` acts in
        it instead of the shared env recorded in the workers' manifest (which is the default, as in
        ``train-manager``).
    """

    level: str
    worker: str | None = None
    workers_dir: str | None = None
    config: str | None = None
    timesteps: int | None = None
    n_evaluations: int = 5
    eval_episodes: int = 5
    seed: int = 0
    algo: str = "ddpg"
    backend: str | None = None
    env: TermsEnv | None = None
    n_seeds: int = 1
    budget_fraction: float | None = None
    final_budget: int | None = None
    episode_set: str = TUNING.name
    block: str | None = None

    def __post_init__(self) -> None:
        if self.block is not None and self.level != "flat":
            raise ValueError(f"Expected block only with level 'flat', actually: level {self.level!r}")
        check_budget_fraction(self.budget_fraction, self.final_budget, self.timesteps)
        if self.episode_set not in (TUNING.name, CURVE.name):
            raise ValueError(f"Expected episode_set 'tuning' or 'curve', actually: {self.episode_set!r}")
        if self.level not in LEVELS:
            raise ValueError(f"Unknown level {self.level!r}; choose from {list(LEVELS)}")
        sampler_for(self.level, self.algo)  # an unknown algorithm, or one for a DDPG-only level, fails here
        if self.level == "worker" and self.worker not in self.worker_names:
            raise ValueError(f"Level 'worker' needs a worker among {self.worker_names}, got {self.worker!r}")
        if self.level != "worker" and self.worker is not None:
            raise ValueError(f"A worker name only applies to level 'worker', not {self.level!r}")
        if self.level in ("manager", "ham") and not self.workers_dir:
            raise ValueError(f"Level {self.level!r} needs the run folder of train-workers (workers_dir)")
        if isinstance(self.n_seeds, bool) or not isinstance(self.n_seeds, int) or self.n_seeds < 1:
            raise ValueError(f"Expected n_seeds to be an integer >= 1, actually: {self.n_seeds!r}")
        if self.level == "ham" and self.n_seeds != 1:
            raise ValueError("Level 'ham' trains nothing: its trials have no seed to repeat (n_seeds 1)")
        if self.n_evaluations < 1 or self.eval_episodes < 1:
            raise ValueError(
                f"Expected n_evaluations >= 1 and eval_episodes >= 1, actually: "
                f"{self.n_evaluations} and {self.eval_episodes}"
            )
        if self.timesteps is not None and self.timesteps < self.n_evaluations:
            raise ValueError(
                f"Expected timesteps >= n_evaluations ({self.n_evaluations}), actually: {self.timesteps}"
            )

    @property
    def worker_names(self) -> list[str]:
        """The workers level ``worker`` can tune: :attr:`env`'s terms, else the snake arm's."""
        return list(self.env.terms) if self.env is not None else sorted(WORKER_ENV_IDS)

    @property
    def name(self) -> str:
        """
        A short name: ``worker-goal``, ``manager`` (``manager-sac``...), ``flat`` (``flat-td3``...) or ``ham``
        (the default study name).
        """
        if self.level == "worker":
            return f"worker-{self.worker}"
        return f"{self.level}-{self.algo}" if self.algo != "ddpg" else self.level

    @property
    def block_key(self) -> str | None:
        """The ``zoo_configs`` key of the tuned block (``None`` for HAM, which has none)."""
        if self.block is not None:
            return self.block
        if self.level in ("worker", "flat") and self.env is not None:
            return self.env.config_key  # as train-workers and train-flat --env read it
        if self.level == "worker":
            return WORKER_ENV_IDS[str(self.worker)]
        return {"manager": MANAGER_KEY, "flat": SHARED_ENV_ID}.get(self.level)

    @property
    def config_path(self) -> Path:
        """The base config file (default: the bundled one of the algorithm)."""
        if self.config:
            return Path(self.config)
        return default_config(self.algo) if self.algo != "ddpg" else DEFAULT_CONFIG

    @property
    def algo_class(self) -> type:
        """The SB3 class of :attr:`algo`."""

        return algo_class(self.algo)

    def sampler(self, trial: Any) -> dict[str, Any]:
        """The changes to the base block a trial samples (:func:`~sb3_hddpg.experiments.hyperparams_opt.sampler_for`)."""
        return sampler_for(self.level, self.algo)(trial)

    def base_block(self) -> dict[str, Any]:
        """The base config's block for :attr:`block_key` (empty for HAM)."""
        if self.block_key is None:
            return {}
        return select_block(load_config_file(self.config_path), self.block_key, source=str(self.config_path))

    def check(self) -> None:
        """
        Fail before any study or trial exists if a trial could not even start: the base config's block must
        parse, and for the levels over workers, the workers must load (hashes verified) and fit the env.
        Otherwise every trial would fail the same way, one after another.
        """
        hyperparams = None
        # RL Zoo falls back to the `default` block for a key it lacks: a named block must be there.
        if self.block is not None and self.block not in load_config_file(self.config_path):
            raise ValueError(
                f"Expected block {self.block!r} in {str(self.config_path)!r}, actually: no such block"
            )
        if self.block_key is not None:
            hyperparams = parse_block(
                dict(self.base_block(), n_envs=1),
                self.algo_class,
                source=f"{self.config_path}[{self.block_key}]",
                manager=self.level == "manager",
            )
        if self.level == "manager":
            _env_factory(self, hyperparams)().close()
        elif self.level == "ham":
            workers = load_workers(str(self.workers_dir))
            manifest = workers.manifest
            env = _ham_env(self, manifest)
            try:
                _make_ham(workers, env, _ham_default_threshold(env), manifest)
            finally:
                env.close()
        elif self.level == "worker" and self.env is not None:
            _env_factory(self, hyperparams)().close()  # e.g. block env_kwargs the env does not take fail here

    def base_params(self) -> tuple[dict[str, Any], list[str]]:
        """
        The base config's values as the sampler's parameters (:func:`~sb3_hddpg.experiments.hyperparams_opt.base_params`;
        for HAM its default threshold), and the names it cannot reproduce: a new study's first trial.
        """
        threshold = None
        if self.level == "ham":
            env = _ham_env(self, _workers_manifest(str(self.workers_dir)))
            try:
                threshold = _ham_default_threshold(env)
            finally:
                env.close()
        return base_params(self.level, self.base_block(), self.algo, threshold)

    def budget(self) -> int:
        """Training env steps per trial (a manager's decisions are this divided by its ``option_steps``)."""
        if self.timesteps is not None:
            return int(self.timesteps)
        if self.budget_fraction is not None and self.final_budget is not None:
            return max(self.n_evaluations, round(self.budget_fraction * self.final_budget))
        return int(self.base_block().get("n_timesteps", 0)) or 1

    def describe(self) -> dict[str, Any]:
        """What makes trials comparable, stored in the study so that a mismatching re-run is refused."""
        described: dict[str, Any] = {
            "level": self.level,
            "worker": self.worker,
            "timesteps": self.budget() if self.level != "ham" else None,
            "n_evaluations": self.n_evaluations if self.level != "ham" else 1,
            "eval_episodes": self.eval_episodes,
        }
        if self.n_seeds != 1:  # only when not 1: studies made before n_seeds stay resumable
            described["n_seeds"] = self.n_seeds
        if (
            self.episode_set != CURVE.name
        ):  # studies made before studies had their own episodes stay resumable
            described["episode_set"] = self.episode_set
        if self.block is not None:  # only when given: studies of the env's block stay resumable
            described["block"] = self.block
        if self.budget_fraction is not None:  # only when given: studies made before stay resumable
            described["budget_fraction"] = self.budget_fraction
            described["final_budget"] = self.final_budget
        if self.algo != "ddpg":  # DDPG studies made before other algorithms were tunable stay resumable
            described["algo"] = self.algo
        if self.env is not None:  # only when given: snake studies made before --env stay resumable
            described["env"] = {"env_id": self.env.env_id, "env_kwargs": self.env.env_kwargs}
        # Only when not the default: studies made before the backend choice (all SB3) stay resumable.
        if self.level != "ham" and (self.backend or self.base_block().get("backend")) == "sbx":
            described["backend"] = "sbx"
        return described


@dataclass(frozen=True)
class StudySettings:
    """
    How the study is searched and where it is stored.

    :param storage: an Optuna storage URL (see :func:`~sb3_hddpg.experiments.study_storage.default_storage_url`).
    :param study_name: the study's name in the storage; re-using it resumes the study.
    :param n_trials: the study's target of finished (complete or pruned) trials, over all processes and runs.
    :param timeout: seconds after which no new trial is started (``None``: no limit).
    :param sampler: ``tpe`` or ``random``.
    :param pruner: ``median``, ``halving`` or ``none``.
    :param seed: seeds the samplers: each process's seed is drawn from ``seed``, its index among ``n_jobs``
        and the study's trial count when it opened the study (see :func:`make_sampler`); ``None``: fresh
        entropy, so that independent processes (e.g. on several machines) do not propose the same trials.
    :param fixed_params: parameters held fixed, name -> value (Optuna's ``PartialFixedSampler``).
    :param heartbeat_interval: seconds between heartbeats of a running trial; a trial silent for twice as
        long is failed and re-queued.
    :param enqueue_base: a new study's first trial is the base config's own values (those in the search
        space, :meth:`TuningTarget.base_params`), so that its best trial is never worse than the base
        config at the trial budget, whatever the search finds.
    """

    storage: str
    study_name: str
    n_trials: int = 20
    timeout: float | None = None
    sampler: str = "tpe"
    pruner: str = "median"
    seed: int | None = None
    fixed_params: dict[str, Any] = field(default_factory=dict)
    heartbeat_interval: int = 30
    enqueue_base: bool = True

    def __post_init__(self) -> None:
        if self.sampler not in SAMPLERS:
            raise ValueError(f"Unknown sampler {self.sampler!r}; choose from {list(SAMPLERS)}")
        if self.pruner not in PRUNERS:
            raise ValueError(f"Unknown pruner {self.pruner!r}; choose from {list(PRUNERS)}")
        if self.n_trials < 1:
            raise ValueError(f"Expected n_trials >= 1, actually: {self.n_trials}")
        if self.heartbeat_interval < 1:
            raise ValueError(f"Expected heartbeat_interval >= 1 s, actually: {self.heartbeat_interval}")
        if self.timeout is not None and not self.timeout > 0:
            raise ValueError(f"Expected timeout > 0 s, actually: {self.timeout}")


def make_sampler(
    settings: StudySettings, process_index: int = 0, trials_before: int = 0
) -> optuna.samplers.BaseSampler:
    """
    The sampler of one process: TPE (multivariate, with constant liar so that parallel processes do not
    all sample next to the same promising point) or random, wrapped to hold ``fixed_params``.

    A seeded sampler's seed mixes ``settings.seed``, ``process_index`` and ``trials_before``: a resumed
    study's processes would otherwise replay their first run's random draws, and so train the
    configurations of its first trials a second time.

    :param settings: the study settings.
    :param process_index: the process's index among ``n_jobs``.
    :param trials_before: how many trials (in any state) the study held when this process opened it.
    """
    seed = (
        None
        if settings.seed is None
        else int(np.random.SeedSequence([settings.seed, process_index, trials_before]).generate_state(1)[0])
    )
    with quiet_experimental():
        if settings.sampler == "random":
            sampler: optuna.samplers.BaseSampler = optuna.samplers.RandomSampler(seed=seed)
        else:
            sampler = optuna.samplers.TPESampler(
                n_startup_trials=N_STARTUP_TRIALS, multivariate=True, constant_liar=True, seed=seed
            )
        if settings.fixed_params:
            sampler = optuna.samplers.PartialFixedSampler(dict(settings.fixed_params), sampler)
    return sampler


def make_pruner(name: str, n_evaluations: int) -> optuna.pruners.BasePruner:
    """
    rl_zoo3's pruners: ``median`` (after 5 trials, from a third of the evaluations on), ``halving``
    (successive halving, one evaluation as the least resource) or ``none``.

    :param name: one of :data:`PRUNERS`.
    :param n_evaluations: evaluations per trial.
    """
    if name == "median":
        return optuna.pruners.MedianPruner(
            n_startup_trials=N_STARTUP_TRIALS_PRUNER, n_warmup_steps=n_evaluations // 3
        )
    if name == "halving":
        return optuna.pruners.SuccessiveHalvingPruner(min_resource=1, reduction_factor=4)
    if name == "none":
        return optuna.pruners.NopPruner()
    raise ValueError(f"Unknown pruner {name!r}; choose from {list(PRUNERS)}")


def open_study(target: TuningTarget, settings: StudySettings, process_index: int = 0) -> optuna.Study:
    """
    Create the study, or load it if it exists (``load_if_exists``), and check that it tunes ``target``.

    :param target: what is tuned.
    :param settings: where and how.
    :param process_index: this process's index (for the sampler's seed).
    :return: the study, maximising the mean evaluation reward.
    """
    storage = make_storage(settings.storage, heartbeat_interval=settings.heartbeat_interval)
    study = optuna.create_study(
        storage=storage,
        study_name=settings.study_name,
        direction="maximize",
        load_if_exists=True,
        sampler=optuna.samplers.RandomSampler(),  # a placeholder: the seed depends on the trials stored
        pruner=make_pruner(settings.pruner, target.n_evaluations),
    )
    study.sampler = make_sampler(settings, process_index, len(study.get_trials(deepcopy=False)))
    expected = target.describe()
    stored = study.user_attrs.get("target")
    if stored is None:
        study.set_user_attr("target", expected)
    elif stored != expected:
        raise ValueError(
            f"Study {settings.study_name!r} in {_safe_url(settings.storage)} was made for {stored}, "
            f"not {expected}: re-run with the same settings to resume it, or choose another --study-name"
        )
    return study


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
        return _evaluate_ham(trial, target, float(changes["threshold"]))
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
    hyperparams: Any,
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
                _env_factory(target, hyperparams),
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


def run_trials(
    target: TuningTarget,
    settings: StudySettings,
    out_dir: str | Path,
    process_index: int = 0,
    threads: int = 1,
    deadline: float | None = None,
) -> int:
    """
    One process's share of the study: claim and run trials until the study has ``n_trials`` finished ones.

    When the remaining trials are all running in other processes, it waits instead of leaving: if one of
    them dies, its trial turns stale, is failed and re-queued, and a waiting process picks it up.

    :param target: what is tuned.
    :param settings: where and how.
    :param out_dir: the run folder.
    :param process_index: this process's index among ``n_jobs``.
    :param threads: torch threads for this process.
    :param deadline: ``time.time()`` after which no trial is started.
    :return: how many trials this process ran.
    """
    torch.set_num_threads(threads)
    study = open_study(target, settings, process_index)
    lock = TrialClaimLock(settings.storage, settings.study_name)

    def claimed_objective(trial: optuna.Trial) -> float:
        # The trial now exists with its number: other processes may count it and claim the next one.
        lock.release()
        return objective(trial, target, out_dir, threads)

    # A waiting process checks once a second: cheap (one query), and at the end of a study the process that
    # waits for the last trial must not add seconds of sleep to the wall time (benchmarks/parallel_scaling.py).
    poll = min(1.0, float(settings.heartbeat_interval))
    ran = 0
    try:
        while deadline is None or time.time() < deadline:
            lock.acquire()
            try:
                step = _next_step(study, settings.n_trials)
                if step == "done":
                    break
                if step == "wait":
                    lock.release()
                    time.sleep(poll)
                    continue
                with quiet_experimental():
                    study.optimize(claimed_objective, n_trials=1, gc_after_trial=True)
                ran += 1
            finally:
                lock.release()
    finally:
        lock.close()
        with contextlib.suppress(Exception):
            study._storage.engine.dispose()  # type: ignore[attr-defined]  # free connections before exit
    return ran


def tune(
    target: TuningTarget,
    settings: StudySettings,
    out_dir: str | Path,
    n_jobs: int = 1,
    threads: int = 1,
    ray_address: str | None = None,
) -> optuna.Study:
    """
    Tune ``target`` with ``n_jobs`` trial processes on one study, until it has ``settings.n_trials``
    finished trials or ``settings.timeout`` has passed.

    Each process gets one torch thread unless ``threads`` says otherwise, as every ``train-*`` command: for
    the small networks tuned here one thread is the faster (docs/PERFORMANCE.md, "Torch threads"), and two
    threads in a process that shares its cores with other work spin for each other (a trial ran 14x slower
    that way beside a benchmark). More processes (or machines) can join the same study at any time by
    running the same command against the same storage.

    :param target: what is tuned.
    :param settings: where and how.
    :param out_dir: the run folder (temporary trial folders; the default storage lives here too).
    :param n_jobs: trial processes on this machine (or Ray tasks, with ``ray_address``).
    :param threads: torch threads per process (a Ray task asks for as many CPUs).
    :param ray_address: run the trial processes as Ray tasks on the cluster at this address (``auto`` or
        ``HOST:PORT``); every node must reach ``settings.storage`` (a server, or a SQLite file on a
        filesystem they share at the same path). ``None``: local processes.
    :return: the study.
    """
    if n_jobs < 1:
        raise ValueError(f"Expected n_jobs >= 1, actually: {n_jobs}")
    shared = n_jobs > 1 or ray_address is not None  # trials in other processes than this one
    if shared and settings.storage.startswith("sqlite") and sqlite_path(settings.storage) is None:
        raise ValueError("An in-memory storage cannot be shared by several processes; use a file or a server")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    deadline = time.time() + settings.timeout if settings.timeout else None
    # Created here, once, so that the trial processes only load it.
    study = open_study(target, settings)
    if settings.enqueue_base and not study.trials:
        enqueue_base_trial(study, target, settings.fixed_params)
    jobs = [
        Job(
            f"tune-{index}",
            run_trials,
            (target, settings, str(out_dir), index, threads, deadline),
            threads=threads,
        )
        for index in range(n_jobs)
    ]
    # On Ctrl-C the trial processes got the signal too: they get 30 s to queue their trials again and leave.
    executor = make_executor(n_jobs, interrupt_grace=30.0, inline=n_jobs == 1, ray_address=ray_address)
    outcome = run_jobs(jobs, executor)
    for error in outcome.failures.values():
        if isinstance(error, TrainingInterrupted):
            raise error  # Ctrl-C or SIGTERM in a trial, its parameters queued again: the study resumes
    if outcome.failures:
        failed = [f"{key} ({outcome.failure_message(key)})" for key in outcome.failures]
        raise RuntimeError(f"Trial processes failed: {', '.join(failed)}; their errors are logged above")
    return study


def enqueue_base_trial(study: optuna.Study, target: TuningTarget, fixed: dict[str, Any]) -> dict[str, Any]:
    """
    Queue the base config's values (:meth:`TuningTarget.base_params`) as the study's next trial, marked
    with the user attribute ``base_config``; parameters held fixed keep their fixed values, and those the
    base config cannot express are sampled (listed in ``sampled_outside_space``).

    :return: the parameters queued.
    """
    params, outside = target.base_params()
    params = {name: value for name, value in params.items() if name not in fixed}
    study.enqueue_trial(params, user_attrs={"base_config": True, "sampled_outside_space": outside})
    return params


def trial_counts(study: optuna.Study) -> dict[str, int]:
    """How many trials are in each state, e.g. ``{"COMPLETE": 18, "PRUNED": 2}``."""
    counts: dict[str, int] = {}
    for trial in study.get_trials(deepcopy=False):
        counts[trial.state.name] = counts.get(trial.state.name, 0) + 1
    return counts


def trial_score(trial: FrozenTrial, rank_by: str = "last") -> float:
    """
    A completed trial's score under ``rank_by`` (see :data:`RANKINGS`): its value, or its best reported
    evaluation (its value when it reported none).
    """
    if rank_by not in RANKINGS:
        raise ValueError(f"Unknown ranking {rank_by!r}; choose from {list(RANKINGS)}")
    value = trial.value if trial.value is not None else -math.inf
    if rank_by == "peak":
        peaks = trial.user_attrs.get("seed_peaks")
        if peaks:  # each seed's best evaluation, averaged: not the luckiest seed's best
            return float(np.mean(peaks))
        return max([value, *trial.intermediate_values.values()])
    return value


def best_trials(study: optuna.Study, k: int = 5, rank_by: str = "last") -> list[FrozenTrial]:
    """The ``k`` best completed trials under ``rank_by`` (:data:`RANKINGS`), best first."""
    completed = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    return sorted(completed, key=lambda t: trial_score(t, rank_by), reverse=True)[:k]


def best_block(study: optuna.Study, target: TuningTarget, rank_by: str = "last") -> dict[str, Any]:
    """
    The best trial's config block: the base block with the best parameters, rebuilt by replaying the
    level's sampler on ``optuna.trial.FixedTrial(best.params)``.

    :param study: a study with at least one completed trial.
    :param target: what was tuned (not HAM, which has no block).
    :param rank_by: which trial is best (:data:`RANKINGS`).
    """
    if target.level == "ham":
        raise ValueError("HAM has no DDPG hyperparameters to save; its best threshold is in the study")
    best = best_trials(study, 1, rank_by)
    if not best:
        raise ValueError(f"Study {study.study_name!r} has no completed trial yet: no best parameters")
    changes = target.sampler(optuna.trial.FixedTrial(best[0].params))
    return merge_block(target.base_block(), changes)


def save_best_config(
    study: optuna.Study, target: TuningTarget, path: str | Path, rank_by: str = "last"
) -> Path:
    """
    Write the best parameters as a ``zoo_configs`` file that ``train-workers``, ``train-manager`` and
    ``train-flat --config`` accept as is.

    If ``path`` exists, only the tuned block is replaced (so tuning ``goal`` and then ``avoid`` into one file
    collects both); otherwise the file starts as a copy of the base config, so that every other block
    (``default``, the other workers, ``manager``) is still there.

    :param study: the tuned study.
    :param target: what was tuned.
    :param path: the YAML file to write.
    :param rank_by: which trial is best (:data:`RANKINGS`).
    :return: the path written.
    """
    path = Path(path)
    block = best_block(study, target, rank_by)
    key = str(target.block_key)
    config = load_config_file(path) if path.exists() else load_config_file(target.config_path)
    config[key] = block
    best = best_trials(study, 1, rank_by)[0]
    which = "last" if rank_by == "last" else "best"
    header = (
        f"# Written by hddpg-cli tune on {datetime.datetime.now().isoformat(timespec='seconds')}: "
        f"block {key!r} from study {study.study_name!r},\n"
        f"# trial {best.number}, {which} mean evaluation reward {trial_score(best, rank_by):.4g} "
        f"in {target.budget()} steps. RL Zoo format (zoo_configs/{target.algo}.yml).\n"
    )
    text = header + yaml.safe_dump(config, sort_keys=False, default_flow_style=False)
    atomic_write_bytes(path, text.encode())
    # What we promise: the commands read it back as written.
    load_hyperparams(key, target.algo_class, path, manager=key == MANAGER_KEY)
    return path


def save_plots(study: optuna.Study, out_dir: str | Path) -> dict[str, Path | str]:
    """
    Save the optimisation history and the parameter importances as PNG files in ``OUT/plots``.

    Importances are PED-ANOVA's (:class:`optuna.importance.PedAnovaImportanceEvaluator`), which, unlike the
    default fANOVA, needs no scikit-learn. Use a non-interactive matplotlib backend (``Agg``) on servers.

    :param study: the study.
    :param out_dir: the run folder.
    :return: plot name -> the PNG written, or the reason it was skipped.
    """
    # Lazily: matplotlib and Optuna's plotting add ~0.9 s to an import, and only this function needs them.
    import matplotlib.pyplot as plt
    from optuna.importance import PedAnovaImportanceEvaluator
    from optuna.visualization.matplotlib import plot_optimization_history, plot_param_importances

    folder = Path(out_dir) / "plots"
    n_completed = len(study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,)))
    plots: dict[str, Any] = {
        "optimization_history": functools.partial(plot_optimization_history, study),
        "param_importances": functools.partial(
            plot_param_importances, study, evaluator=PedAnovaImportanceEvaluator()
        ),
    }
    needed = {"optimization_history": 1, "param_importances": 2}
    results: dict[str, Path | str] = {}
    for name, plot in plots.items():
        if n_completed < needed[name]:
            results[name] = f"needs at least {needed[name]} completed trials, the study has {n_completed}"
            continue
        try:
            # PED-ANOVA warns about the accuracy of importances from few trials; the plot still helps.
            with quiet_experimental(), warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)
                axes = plot()
        except (ValueError, RuntimeError, ZeroDivisionError) as error:
            results[name] = f"{type(error).__name__}: {error}"
            continue
        figure = axes.figure
        folder.mkdir(parents=True, exist_ok=True)
        figure.tight_layout()
        figure.savefig(folder / f"{name}.png", dpi=120)
        plt.close(figure)
        results[name] = folder / f"{name}.png"
    return results


def merge_block(base: dict[str, Any], changes: dict[str, Any]) -> dict[str, Any]:
    """``base`` updated by ``changes``; ``wrapper_kwargs`` are merged key by key, ``noise_std`` dropped without noise."""
    block = copy.deepcopy(base)
    for key, value in changes.items():
        if key == "wrapper_kwargs":
            block[key] = {**(block.get(key) or {}), **value}
        else:
            block[key] = value
    if "noise_type" in block and block["noise_type"] is None:
        block.pop("noise_std", None)  # meaningless without noise; a reader would wonder which applies
    return block


def _next_step(study: optuna.Study, n_trials: int) -> str:
    """``run`` a trial, ``wait`` for others' running trials, or ``done``; call with the claim lock held."""
    with quiet_experimental():
        optuna.storages.fail_stale_trials(study)  # re-queues dead processes' trials as WAITING
    trials = study.get_trials(deepcopy=False)
    finished = sum(t.state in FINISHED_STATES for t in trials)
    running = sum(t.state == TrialState.RUNNING for t in trials)
    waiting = sum(t.state == TrialState.WAITING for t in trials)
    if finished >= n_trials:
        return "done"
    if waiting:
        return "run"  # optimize() takes queued trials first
    return "wait" if finished + running >= n_trials else "run"


def _env_factory(target: TuningTarget, hyperparams: Any) -> Any:
    """A picklable factory of the training env of ``target``, as the ``train-*`` commands build it."""
    env = target.env
    if target.level == "worker":
        if env is None:
            return worker_env_factory(str(target.worker), hyperparams.env_kwargs)
        # As train_workers builds a worker's env: the term's view, the block's env_kwargs on top.
        env_id, view_kwargs = env.term_view(str(target.worker))
        return functools.partial(
            make_term_view, env_id, {**view_kwargs, **hyperparams.env_kwargs}, str(target.worker)
        )
    if target.level == "flat":
        # As train_flat builds it: the block's env_kwargs, the chosen env's on top.
        env_id, env_kwargs = (env.env_id, env.env_kwargs) if env is not None else (SHARED_ENV_ID, {})
        return functools.partial(make_snake_env, env_id, {**hyperparams.env_kwargs, **env_kwargs})

    manifest = _workers_manifest(str(target.workers_dir))
    # As prepare_manager: --env, else the manifest's shared env (safe-loading checks), the block's kwargs on top.
    env_id, env_kwargs = _shared_env(target, manifest)
    names = list(manifest["workers"])
    wrapper = dict(hyperparams.wrapper_kwargs)
    # Each worker sees the state components it was trained on, as train-manager feeds it.
    wrapper["worker_states"] = {
        **observed_components(manifest, names),
        **(wrapper.get("worker_states") or {}),
    }
    selection = SelectionConfig(preferences=dict.fromkeys(names, 1.0), **wrapper)
    return ManagerEnvFactory(
        env_id,
        {**env_kwargs, **hyperparams.env_kwargs},
        str(target.workers_dir),
        names,
        selection.wrapper_kwargs(),
    )


def _shared_env(target: TuningTarget, manifest: ModelsManifest) -> tuple[str, dict[str, Any]]:
    """The env a manager (or HAM) over the manifest's workers acts in, chosen as train-manager does."""
    env = target.env
    return shared_env_of(manifest, env.env_id if env else None, env.env_kwargs if env else None)


def _worker_names(workers_dir: str) -> list[str]:
    return list(_workers_manifest(workers_dir)["workers"])


def _workers_manifest(workers_dir: str) -> ModelsManifest:
    folder = Path(workers_dir)
    manifest = folder / "workers" / "manifest.json"
    if not manifest.exists():
        manifest = folder / "manifest.json"
    if not manifest.exists():
        raise FileNotFoundError(f"No workers manifest in {workers_dir!r}; run train-workers first")

    return read_workers_manifest(manifest)


def _evaluate_ham(trial: optuna.Trial, target: TuningTarget, threshold: float) -> float:
    """HAM's trial: no training, one evaluation on the combined reward."""

    workers = load_workers(str(target.workers_dir))
    manifest = workers.manifest
    env = _ham_env(target, manifest)
    try:
        policy = _make_ham(workers, env, threshold, manifest)
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


def _ham_env(target: TuningTarget, manifest: ModelsManifest) -> Any:
    """
    The env HAM is evaluated in (as the manager's: ``--env``, else the manifest's shared env), refused
    with one line unless its state layout declares the component HAM's switch rule reads.
    """
    env_id, env_kwargs = _shared_env(target, manifest)
    env = make_snake_env(env_id, env_kwargs)
    if HAM_COMPONENT not in state_layout_of(env):
        env.close()
        raise ValueError(
            f"HAM's switch rule reads the state component {HAM_COMPONENT!r} (the snake arm's obstacle "
            f"clearances), which {env_id!r} does not declare: tune HAM on the snake arm only"
        )
    return env


def _ham_default_threshold(env: Any) -> float:
    """HAM's default threshold in ``env``: the number of links minus the default margin."""
    return float(len(state_layout_of(env).indices([HAM_COMPONENT]))) - DEFAULT_MARGIN


def _make_ham(workers: Mapping[str, Any], env: Any, threshold: float, manifest: ModelsManifest) -> HAMSwitch:
    """The HAM switch over the goal and avoid workers, each fed the state components it was trained on."""
    return HAMSwitch(
        workers["goal"],
        workers["avoid"],
        state_layout_of(env),
        threshold=threshold,
        worker_states=observed_components(manifest, list(workers)),
    )


def _jsonable(entry: dict[str, Any]) -> dict[str, Any]:
    """An evaluation summary with only JSON-safe finite numbers (NaN becomes ``None``)."""
    out: dict[str, Any] = {}
    for key, value in entry.items():
        if isinstance(value, float):
            out[key] = value if math.isfinite(value) else None
        elif isinstance(value, (int, str, bool)) or value is None:
            out[key] = value
        elif isinstance(value, dict):
            out[key] = _jsonable(value)
    return out


def _safe_url(url: str) -> str:
    with contextlib.suppress(Exception):
        from sqlalchemy.engine import make_url  # lazily: +0.6 s to import (see study_storage)

        return make_url(url).render_as_string(hide_password=True)
    return url


__all__ = [
    "LEVELS",
    "PRUNERS",
    "RANKINGS",
    "SAMPLERS",
    "StudySettings",
    "TuningTarget",
    "best_block",
    "best_trials",
    "check_budget_fraction",
    "make_pruner",
    "make_sampler",
    "objective",
    "open_study",
    "run_trials",
    "save_best_config",
    "save_plots",
    "trial_counts",
    "trial_score",
    "tune",
]

"""An Optuna study of a target: settings, sampler, pruner, storage, and the trial processes that run it."""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import optuna
import torch
from optuna.trial import TrialState

from hddpg_zoo.executors import make_executor
from hddpg_zoo.runner import Job, run_jobs
from hddpg_zoo.study_storage import TrialClaimLock, make_storage, quiet_experimental, sqlite_path
from hddpg_zoo.tuning.target import TuningTarget
from hddpg_zoo.tuning.trial import objective
from sb3_hddpg.training.agent import TrainingInterrupted

#: ``--sampler`` choices.
SAMPLERS = ("tpe", "random")
#: ``--pruner`` choices.
PRUNERS = ("median", "halving", "none")
#: Trial states that count towards ``n_trials``.
FINISHED_STATES = (TrialState.COMPLETE, TrialState.PRUNED)
#: Startup trials of TPE (random ones before it models anything) and of the median pruner, as in rl_zoo3.
N_STARTUP_TRIALS = 10
N_STARTUP_TRIALS_PRUNER = 5


@dataclass(frozen=True)
class StudySettings:
    """
    How the study is searched and where it is stored.

    :param storage: an Optuna storage URL (see :func:`~hddpg_zoo.study_storage.default_storage_url`).
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
    fixed_params: dict[str, object] = field(default_factory=dict)
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


class _DropInterruptions(logging.Filter):
    """
    Drop Optuna's "Trial N failed ... Traceback" record for a trial stopped by Ctrl-C or SIGTERM, and the
    "Trial N failed with value None" that follows it.
    """

    def __init__(self) -> None:
        super().__init__()
        self.stopped: set[str] = set()

    def filter(self, record: logging.LogRecord) -> bool:
        error = record.exc_info[1] if record.exc_info else None
        message = record.getMessage()
        if isinstance(error, (TrainingInterrupted, KeyboardInterrupt)):
            self.stopped.add(" ".join(message.split()[:2]))  # "Trial 3"
            return False
        return not any(message.startswith(f"{trial} failed with value") for trial in self.stopped)


@contextlib.contextmanager
def _quiet_interruptions() -> Iterator[None]:
    """
    While a trial runs: a stop by the user is not a failure to report with a traceback (each process
    printed one, and SIGTERM to ``tune`` gave 61 lines); the command says in one line how to resume.
    """
    # A logger's filter sees only what is logged to it, not what its children propagate: filter where
    # Optuna logs a trial's failure, and at the handlers of its root logger.
    optuna.logging.get_verbosity()  # makes Optuna set up its root logger and handler
    places: list[logging.Logger | logging.Handler] = [
        logging.getLogger("optuna.study._optimize"),
        *logging.getLogger("optuna").handlers,
    ]
    dropping = _DropInterruptions()
    for place in places:
        place.addFilter(dropping)
    try:
        yield
    finally:
        for place in places:
            place.removeFilter(dropping)


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
                with quiet_experimental(), _quiet_interruptions():
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
    threads in a process that shares its cores with other work spin for each other (a trial runs many times slower
    that way beside other work). More processes (or machines) can join the same study at any time by
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


def enqueue_base_trial(
    study: optuna.Study, target: TuningTarget, fixed: Mapping[str, object]
) -> dict[str, object]:
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


def _safe_url(url: str) -> str:
    with contextlib.suppress(Exception):
        from sqlalchemy.engine import make_url  # lazily: slow to import (see study_storage)

        return make_url(url).render_as_string(hide_password=True)
    return url

"""
The benchmark of paper Section 3.3-3.4: every method for every seed, one common metric, seed statistics.

Methods are records in :data:`METHOD_REGISTRY` (:class:`Method`: name, whether it needs its seed's
workers, how it runs, its budget, its colour); adding a method is one :func:`register_method` call. Built in:

- ``hddpg``: the two workers, then a manager with equal preferences (paper Algorithm 1);
- ``hddpg-goal`` / ``hddpg-avoid``: managers preferring one worker by ``bias`` (15 %, paper Figure 10);
- ``ham``: the hand-written switch over the same workers (:mod:`sb3_hddpg.baselines.ham`), no training;
- ``ddpg``, ``td3``, ``sac`` (and ``tqc``): one flat agent on the combined reward, each given the
  hierarchy's total env steps (workers + manager), configured by ``zoo_configs/<algo>.yml``.

**Scenarios.** ``standard`` runs every method once per seed. ``transfer`` (the paper's "minimal learning
period") trains each seed's workers once, then for every given preference (e.g. ``goal=2,avoid=1``) a
manager with those factors and each flat agent from scratch on the same scalarised reward
(:class:`~sb3_hddpg.wrappers.PreferenceReward`); :func:`transfer_results` compares the env steps each
needs to reach 90 % of its final score. A run on a preference is the method key ``<method>@<preference>``.

Workers are trained once per seed and shared by that seed's ``hddpg*`` and ``ham`` runs. Every run is an
independent process (``n_jobs`` at a time, one torch thread each); a run's dependencies (its seed's
workers) are scheduled before it. Every finished run writes a record atomically to
``DIR/records/<method>/seed-<s>.json``, which :func:`run_benchmark` skips when resuming.

**Metric.** Everything is measured with :func:`sb3_hddpg.evaluation.evaluate` on the env's combined
normalised reward, ``mean_reach_reward`` (per step the goal and avoid terms min-max normalised to
``[0, 1]`` and summed; at most 2 per step, 400 per episode), plus goal-touch rate, collisions, success
and clearance. The learning curves are the in-training evaluations (``evaluations/<name>.json``) on the
fixed seeds ``EVAL_SEED_BASE + k``; because ``train_agent`` keeps the best model by those evaluations,
the final scores are measured on a disjoint block of fixed test seeds, ``TEST_SEED_BASE + k``, the same
for every method and seed (selecting and scoring on the same episodes would flatter the learned methods
against HAM, which selects nothing).
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import csv
import functools
import json
import logging
import math
import multiprocessing
import os
import platform
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from sb3_hddpg.artifacts.io import atomic_write, atomic_write_json
from sb3_hddpg.baselines.ham import DEFAULT_MARGIN, load_ham, save_ham
from sb3_hddpg.callbacks.checkpoint import read_checkpoint_state
from sb3_hddpg.envs import SnakeArmEnv
from sb3_hddpg.envs.contract import TermNormaliser, state_layout_of
from sb3_hddpg.envs.terms_env import TermsEnv
from sb3_hddpg.evaluation import DEPENDENCE_WORKER, EVAL_SEED_BASE, evaluate, state_dependence
from sb3_hddpg.hierarchy.loading import load_policy
from sb3_hddpg.hierarchy.selection import parse_preferences
from sb3_hddpg.media import figures
from sb3_hddpg.policy import WORKER_ENV_IDS, RandomPolicy
from sb3_hddpg.stats import (
    bootstrap_ci,
    paired_difference_ci,
    probability_of_improvement,
    summarise,
    trend_slope,
)
from sb3_hddpg.training.backends import check_algo, check_backend
from sb3_hddpg.training.config import MANAGER_KEY, load_hyperparams
from sb3_hddpg.training.training import (
    FLAT_ENV_ID,
    sigterm_as_interrupt,
    train_flat,
    train_manager,
    train_workers,
    worker_hyperparams,
)

logger = logging.getLogger(__name__)


@functools.cache
def _config_budgets() -> dict[str, int]:
    """The bundled config's budgets (``n_timesteps``): each snake worker's and the manager's."""
    from stable_baselines3 import DDPG

    budgets = {name: hp.n_timesteps for name, hp in worker_hyperparams(sorted(WORKER_ENV_IDS)).items()}
    budgets[MANAGER_KEY] = load_hyperparams(MANAGER_KEY, DDPG, manager=True).n_timesteps
    return budgets


#: The pseudo-method of a seed's two workers, which the methods that need them depend on.
WORKERS = "workers"
#: ``standard``: every method once per seed; ``transfer``: managers and flat agents on new preferences.
SCENARIOS = ("standard", "transfer")
#: The preferences of the transfer scenario by default: the goal term weighted twice, then the avoid term.
DEFAULT_TRANSFER_PREFERENCES = ("goal=2,avoid=1", "goal=1,avoid=2")
#: The methods of the transfer scenario by default: the manager against flat DDPG.
DEFAULT_TRANSFER_METHODS = ("hddpg", "ddpg")
#: The share of its final score (measured from a random policy's) a run must reach in the transfer figure.
TRANSFER_FRACTION = 0.9
#: First seed of the final test episodes: disjoint from the learning-curve seeds ``EVAL_SEED_BASE + k``.
TEST_SEED_BASE = EVAL_SEED_BASE + 5_000
#: The metrics reported for the final test evaluation.
FINAL_METRICS = (
    "mean_reach_reward",
    "goal_reach_reward",
    "avoid_reach_reward",
    "goal_touch_rate",
    "collisions_per_episode",
    "success_rate",
    "min_clearance",
    "mean_reward",
    "action_saturation",
)

#: Bumped when a record's meaning changes.
RECORD_VERSION = 1
#: Steps per unit of the reported learning-curve slopes.
SLOPE_UNIT = 1000


# ---------------------------------------------------------------------------------------------- methods
@dataclass(frozen=True)
class Method:
    """
    One benchmark method: everything the benchmark knows of it, so that a new method is one record.

    :param name: its name in ``--methods`` and the results.
    :param run: ``run(task, settings, folder) -> fields`` trains (if it learns) and evaluates the task in
        its own process, in the seed's ``folder``, and returns the record's fields: ``history`` (the
        learning curve, every point with ``timesteps`` and ``total_timesteps``), ``test`` (the final test
        summary), ``worker_timesteps`` and anything else worth keeping. It must be a module-level function
        (or a ``functools.partial`` of one) registered at import, since it runs in a spawned process.
    :param cost: its training budget in env steps for the given settings (for scheduling).
    :param needs_workers: it uses its seed's workers, so it runs after them.
    :param colour: its colour in every figure (a matplotlib colour).
    :param default: run when ``--methods`` is not given.
    :param baseline: compared with ``hddpg`` (paired differences by seed) whenever both ran.
    :param takes_preference: it can learn a given preference (the transfer scenario).
    :param description: one line for the docs.
    """

    name: str
    run: Callable[[Task, BenchmarkSettings, Path], dict[str, Any]]
    cost: Callable[[BenchmarkSettings], int]
    needs_workers: bool = False
    colour: str = "tab:olive"
    default: bool = False
    baseline: bool = False
    takes_preference: bool = False
    description: str = ""


#: Every method the benchmark knows, by name, in registration order.
METHOD_REGISTRY: dict[str, Method] = {}


def register_method(method: Method) -> Method:
    """
    Add a method to :data:`METHOD_REGISTRY` (a name may be registered once; ``@`` is reserved).

    :param method: the record.
    :return: the record.
    """
    if method.name in METHOD_REGISTRY or method.name == WORKERS or "@" in method.name or not method.name:
        raise ValueError(f"Cannot register benchmark method {method.name!r}: taken or reserved")
    METHOD_REGISTRY[method.name] = method
    return method


def method_key(name: str, preference: str | None = None) -> str:
    """A run's key: the method's name, with ``@<preference>`` in the transfer scenario."""
    return name if preference is None else f"{name}@{preference}"


def split_key(key: str) -> tuple[str, str | None]:
    """The method name and the preference (``None``: none) of a run's key."""
    name, _, preference = key.partition("@")
    return name, preference or None


def canonical_preference(text: str) -> str:
    """
    A preference such as ``"goal=2, avoid=1"`` checked and written one way (``goal=2,avoid=1``: factors in
    the given order, ``%g``), so that it names the same runs however it was typed.

    :raises ValueError: naming the bad entry.
    """

    factors = parse_preferences(text)
    for name, value in factors.items():
        if not (math.isfinite(value) and value > 0):
            raise ValueError(
                f"Expected preference of {name!r} to be a finite number > 0, actually: {value!r}"
            )
    return ",".join(f"{name}={value:g}" for name, value in factors.items())


@dataclass
class BenchmarkSettings:
    """
    What to run; stored in ``DIR/benchmark.json`` so that ``--resume`` continues the same benchmark.

    :param methods: methods among :data:`METHOD_REGISTRY`.
    :param seeds: training seeds (each method runs once per seed).
    :param timesteps: the manager's budget, in its own (env) steps (``0``: the bundled config's manager
        block, ``n_timesteps``; resolved when the settings are made, so ``benchmark.json`` records it).
    :param worker_timesteps: each worker's budget (``None``: each worker's own config block, e.g. 150k steps
        for the goal worker and 30k for the avoid worker).
    :param flat_timesteps: a flat agent's budget (``None``: ``timesteps`` plus every worker's budget, so
        that a flat agent uses as many environment steps as the whole hierarchy).
    :param eval_freq: steps between learning-curve evaluations of every run (``None``: ``timesteps // 10``).
    :param eval_episodes: episodes per learning-curve evaluation.
    :param test_episodes: episodes of the final test evaluation.
    :param ham_threshold: HAM's switching threshold (``None``: its default).
    :param ham_hysteresis: HAM's hysteresis.
    :param bias: the biased managers' extra preference factor.
    :param scenario: ``standard`` or ``transfer`` (see the module's docstring).
    :param preferences: the transfer scenario's preferences, e.g. ``["goal=2,avoid=1"]``; every method runs
        once per preference and seed (empty in the standard scenario).
    :param backend: the training backend of every agent, ``sb3`` or ``sbx`` (saved models are SB3 either way).
    :param env: another env with several objectives, as ``{"env_id", "env_kwargs", "terms"}`` (a
        :class:`~sb3_hddpg.envs.terms_env.TermsEnv`'s fields, see :attr:`terms_env`; ``None``: the snake
        arm): its workers, managers and flat agents are trained and tested on it. Only the methods of
        :data:`ENV_METHODS` and the standard scenario apply there (HAM's switch rule and the biased
        managers are the snake's).
    """

    methods: list[str] = field(default_factory=lambda: list(DEFAULT_METHODS))
    seeds: list[int] = field(default_factory=lambda: list(range(5)))
    timesteps: int = 0
    worker_timesteps: int | None = None
    flat_timesteps: int | None = None
    eval_freq: int | None = None
    eval_episodes: int = 5
    test_episodes: int = 20
    ham_threshold: float | None = None
    ham_hysteresis: float = 0.0
    bias: float = 0.15
    scenario: str = "standard"
    preferences: list[str] = field(default_factory=list)
    backend: str = "sb3"
    env: dict[str, Any] | None = None

    def __post_init__(self) -> None:
        unknown = [m for m in self.methods if m not in METHOD_REGISTRY]
        if unknown:
            raise ValueError(f"Unknown methods {unknown}; choose from {list(METHOD_REGISTRY)}")
        if self.env is not None:
            self._check_env()
        self.backend = check_backend(self.backend)
        for method in self.methods:
            if method in FLAT_METHODS:
                check_algo(method, self.backend)
        if len(set(self.methods)) != len(self.methods) or not self.methods:
            raise ValueError(f"Expected distinct methods, at least one, actually: {self.methods}")
        if not self.seeds or len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"Expected distinct seeds, at least one, actually: {self.seeds}")
        if not self.timesteps:
            self.timesteps = _config_budgets()[MANAGER_KEY]
        for name in ("timesteps", "worker_timesteps", "eval_episodes", "test_episodes"):
            value = getattr(self, name)
            if value is not None and value < 1:
                raise ValueError(f"Expected `{name}` >= 1, actually: {getattr(self, name)}")
        if self.scenario not in SCENARIOS:
            raise ValueError(f"Unknown scenario {self.scenario!r}; choose from {list(SCENARIOS)}")
        if self.scenario == "standard":
            if self.preferences:
                raise ValueError("Preferences apply to the transfer scenario only (scenario='transfer')")
            return
        self.preferences = [canonical_preference(p) for p in self.preferences]
        if not self.preferences or len(set(self.preferences)) != len(self.preferences):
            raise ValueError(f"Expected distinct preferences, at least one, actually: {self.preferences}")
        fixed = [m for m in self.methods if not METHOD_REGISTRY[m].takes_preference]
        if fixed:
            choices = [m.name for m in METHOD_REGISTRY.values() if m.takes_preference]
            raise ValueError(
                f"Methods {fixed} cannot learn a given preference; the transfer scenario takes {choices}"
            )
        if "hddpg" not in self.methods or len(self.methods) < 2:
            raise ValueError(
                f"The transfer scenario compares hddpg with flat agents, actually: {self.methods}"
            )

    def _check_env(self) -> None:
        """Another env: its spec as plain JSON (so that ``benchmark.json`` resumes), and methods that apply."""
        env = self.env if isinstance(self.env, dict) else {}
        if set(env) != {"env_id", "env_kwargs", "terms"} or not isinstance(env["env_id"], str):
            raise ValueError(
                f"Expected `env` as {{'env_id', 'env_kwargs', 'terms'}}, actually: {str(self.env)[:200]}"
            )
        self.env = json.loads(json.dumps(env))  # tuples become lists, as benchmark.json stores them
        snake_only = [m for m in self.methods if m not in ENV_METHODS]
        if snake_only:
            raise ValueError(
                f"Methods {snake_only} are defined for the snake arm only; on {env['env_id']!r} choose from "
                f"{list(ENV_METHODS)}"
            )
        if self.scenario != "standard":
            raise ValueError(f"The {self.scenario!r} scenario is defined for the snake arm only")

    @property
    def terms_env(self) -> TermsEnv | None:
        """:attr:`env` as the :class:`~sb3_hddpg.envs.terms_env.TermsEnv` the training functions take."""
        if self.env is None:
            return None
        return TermsEnv(self.env["env_id"], dict(self.env["env_kwargs"]), tuple(self.env["terms"]))

    @property
    def method_keys(self) -> list[str]:
        """The runs of one seed: the methods, or in the transfer scenario each method on each preference."""
        if self.scenario == "transfer":
            return [method_key(m, p) for p in self.preferences for m in self.methods]
        return list(self.methods)

    @property
    def flat_budget(self) -> int:
        """A flat agent's budget: as many env steps as the hierarchy (workers + manager) by default."""
        if self.flat_timesteps is not None:
            return self.flat_timesteps
        return self.timesteps + self.workers_budget

    @property
    def workers_budget(self) -> int:
        """Env steps of a seed's workers together: ``worker_timesteps`` each, or each worker's config budget."""
        env = self.terms_env
        if env is not None:
            blocks = worker_hyperparams(list(env.terms), None, env)
            workers = [block.n_timesteps for block in blocks.values()]
        else:
            budgets = _config_budgets()
            workers = [budgets[name] for name in budgets if name != MANAGER_KEY]
        if self.worker_timesteps is not None:
            return self.worker_timesteps * len(workers)
        return sum(workers)

    def eval_freq_for(self, budget: int) -> int:
        """
        Steps between evaluations for a run of ``budget`` steps: the same for every run (default: a tenth
        of the manager's budget), so that all curves have points at the same own steps.
        """
        return min(self.eval_freq if self.eval_freq else max(self.timesteps // 10, 1), budget)


@dataclass(frozen=True)
class Task:
    """
    One unit of work in its own process.

    :param method: a run's key (a method, or ``<method>@<preference>``), or ``workers`` (a seed's two workers).
    :param seed: the training seed.
    """

    method: str
    seed: int

    @property
    def spec(self) -> Method | None:
        """The method's record (``None`` for the workers)."""
        return None if self.method == WORKERS else METHOD_REGISTRY[split_key(self.method)[0]]

    @property
    def preferences(self) -> dict[str, float] | None:
        """The preference factors of a transfer run (``None``: the method's own)."""

        preference = split_key(self.method)[1]
        return parse_preferences(preference) if preference else None

    @property
    def needs_workers(self) -> bool:
        return self.spec is not None and self.spec.needs_workers

    @property
    def label(self) -> str:
        return f"{self.method}/seed-{self.seed}"


def seed_dir(out: Path, seed: int) -> Path:
    """The folder of one seed's models."""
    return out / f"seed-{seed}"


def record_path(out: Path, task: Task) -> Path:
    """Where a finished task's record goes."""
    return out / "records" / task.method / f"seed-{task.seed}.json"


def read_record(out: Path, task: Task) -> dict[str, Any] | None:
    """A finished task's record, or ``None``."""
    path = record_path(out, task)
    if not path.exists():
        return None
    record = json.loads(path.read_text())
    return record if record.get("status") == "done" else None


def plan_tasks(settings: BenchmarkSettings) -> list[Task]:
    """Every task of a benchmark: per seed its workers (if any method needs them) and every run."""
    tasks = []
    for seed in settings.seeds:
        runs = [Task(key, seed) for key in settings.method_keys]
        if any(t.needs_workers for t in runs):
            tasks.append(Task(WORKERS, seed))
        tasks.extend(runs)
    return tasks


# ---------------------------------------------------------------------------------------------- one task
def _history(path: Path, offset: int) -> list[dict[str, Any]]:
    """An ``evaluations/<name>.json`` history with ``total_timesteps = timesteps + offset`` on every point."""
    history = json.loads(path.read_text())
    return [{**point, "total_timesteps": int(point["timesteps"]) + offset} for point in history]


def _test(policy_path: Path, settings: BenchmarkSettings) -> dict[str, Any]:
    """The final test evaluation of a saved policy, loaded the safe way a user would load it."""

    # Another env is the user's choice: its id may be loaded from the run's files (allowed_env_ids).
    env_id = settings.env["env_id"] if settings.env is not None else None
    loaded = load_policy(policy_path, allowed_env_ids=[env_id] if env_id else None)
    env = loaded.make_env()
    try:
        return evaluate(loaded.policy, env, n_episodes=settings.test_episodes, seed=TEST_SEED_BASE).summary()
    finally:
        env.close()


def _random_reference(settings: BenchmarkSettings) -> dict[str, Any]:
    """A random policy's evaluation on the learning-curve episodes: the floor of the transfer figure."""
    import gymnasium as gym

    env = gym.make(FLAT_ENV_ID)
    try:
        policy = RandomPolicy(env.action_space, seed=0)
        return evaluate(policy, env, n_episodes=settings.eval_episodes, seed=EVAL_SEED_BASE).summary()
    finally:
        env.close()


def _workers_steps(folder: Path) -> int:
    manifest = json.loads((folder / "workers" / "manifest.json").read_text())
    return int(sum(entry["timesteps_trained"] for entry in manifest["workers"].values()))


def run_task(task: Task, settings: BenchmarkSettings, out: str | Path) -> dict[str, Any]:
    """
    Run one task to the end and write its record atomically (the function each process runs).

    :param task: what to run.
    :param settings: the benchmark's settings.
    :param out: the benchmark folder.
    :return: the record written.
    """
    import torch

    torch.set_num_threads(1)
    out = Path(out)
    folder = seed_dir(out, task.seed)
    start = time.perf_counter()
    record: dict[str, Any] = {
        "record_version": RECORD_VERSION,
        "method": task.method,
        "seed": task.seed,
        "status": "done",
    }
    spec = task.spec
    if spec is None:
        record.update(_run_workers(task, settings, folder))
    else:
        record.update(spec.run(task, settings, folder))
        preference = split_key(task.method)[1]
        if preference is not None:
            record["preference"] = preference
            record["reference"] = _random_reference(settings)
    record["wall_time_s"] = time.perf_counter() - start
    atomic_write_json(record_path(out, task), record)
    return record


def _run_workers(task: Task, settings: BenchmarkSettings, folder: Path) -> dict[str, Any]:
    """Train (or finish) a seed's two workers."""

    manifest = train_workers(
        folder,
        env=settings.terms_env,
        timesteps=settings.worker_timesteps,
        seed=task.seed,
        resume=True,  # keeps finished workers and continues an interrupted one
        eval_freq=settings.eval_freq_for(settings.worker_timesteps or settings.workers_budget),
        eval_episodes=settings.eval_episodes,
        backend=settings.backend,
    )
    return {
        "worker_timesteps": _workers_steps(folder),
        "workers": {
            name: {"timesteps": entry["timesteps_trained"], "metrics": entry["metrics"]}
            for name, entry in manifest["workers"].items()
        },
        "history": {
            name: _history(folder / "evaluations" / f"{name}.json", 0) for name in manifest["workers"]
        },
    }


def _run_manager(prefer: str | None, task: Task, settings: BenchmarkSettings, folder: Path) -> dict[str, Any]:
    """A manager over the seed's workers, preferring ``prefer`` by ``bias`` (or with the task's factors)."""

    run_dir = folder / task.method
    env = settings.terms_env
    train_manager(
        folder,
        run_dir,
        env_id=env.env_id if env is not None else None,
        env_kwargs=env.env_kwargs if env is not None else None,
        prefer=prefer,
        bias=settings.bias,
        preferences=task.preferences,
        timesteps=settings.timesteps,
        seed=task.seed,
        resume=read_checkpoint_state(run_dir / "checkpoints" / "manager") is not None,
        eval_freq=settings.eval_freq_for(settings.timesteps),
        eval_episodes=settings.eval_episodes,
        backend=settings.backend,
    )
    offset = _workers_steps(folder)
    return {
        "worker_timesteps": offset,
        "history": _history(run_dir / "evaluations" / "manager.json", offset),
        "test": _test(run_dir / "hierarchy.zip", settings),
    }


def _run_flat(algo: str, task: Task, settings: BenchmarkSettings, folder: Path) -> dict[str, Any]:
    """A flat agent on the combined reward (or the task's scalarised one) for the hierarchy's total steps."""

    run_dir = folder / task.method
    env = settings.terms_env
    train_flat(
        run_dir,
        algo=algo,
        env_id=env.env_id if env is not None else FLAT_ENV_ID,
        env_kwargs=env.env_kwargs if env is not None else None,
        timesteps=settings.flat_budget,
        seed=task.seed,
        resume=True,
        eval_freq=settings.eval_freq_for(settings.flat_budget),
        eval_episodes=settings.eval_episodes,
        preferences=task.preferences,
        backend=settings.backend,
    )
    return {
        "worker_timesteps": 0,
        "history": _history(run_dir / "evaluations" / f"flat-{algo}.json", 0),
        "test": _test(run_dir / "flat" / f"{algo}.zip", settings),
    }


def _run_ham(task: Task, settings: BenchmarkSettings, folder: Path) -> dict[str, Any]:
    """Save the seed's HAM switch and evaluate it: one learning-curve point (it does not learn) and the test."""
    import gymnasium as gym

    env = gym.make(FLAT_ENV_ID)
    try:
        n_links = state_layout_of(env)["joint_obstacle_distances"]
        threshold = settings.ham_threshold
        if threshold is None:
            threshold = (n_links.stop - n_links.start) - DEFAULT_MARGIN
        offset = _workers_steps(folder)
        ham_path = save_ham(
            folder / "ham" / "ham.json",
            folder / "workers" / "manifest.json",
            threshold=threshold,
            hysteresis=settings.ham_hysteresis,
            env_id=FLAT_ENV_ID,
            metadata={"seed": task.seed, "worker_timesteps": offset},
        )
        switch, _ = load_ham(ham_path)
        curve = evaluate(switch, env, n_episodes=settings.eval_episodes, seed=EVAL_SEED_BASE).summary()
    finally:
        env.close()
    return {
        "worker_timesteps": offset,
        "history": [{"timesteps": 0, "total_timesteps": offset, **curve}],
        "test": _test(ham_path, settings),
        "threshold": threshold,
        "hysteresis": settings.ham_hysteresis,
    }


def _manager_cost(settings: BenchmarkSettings) -> int:
    return settings.timesteps


def _flat_cost(settings: BenchmarkSettings) -> int:
    return settings.flat_budget


def _no_cost(settings: BenchmarkSettings) -> int:
    return 0


register_method(
    Method(
        "hddpg",
        functools.partial(_run_manager, None),
        _manager_cost,
        needs_workers=True,
        colour="tab:red",
        default=True,
        takes_preference=True,
        description="the two workers, then a manager with equal preferences (paper Algorithm 1)",
    )
)
register_method(
    Method(
        "ham",
        _run_ham,
        _no_cost,
        needs_workers=True,
        colour="tab:gray",
        default=True,
        baseline=True,
        description="the hand-written switch over the same workers, no training",
    )
)
for _algo, _colour in (
    ("ddpg", "tab:blue"),
    ("td3", "tab:cyan"),
    ("sac", "tab:purple"),
    ("tqc", "tab:brown"),
):
    register_method(
        Method(
            _algo,
            functools.partial(_run_flat, _algo),
            _flat_cost,
            colour=_colour,
            default=_algo == "ddpg",
            baseline=True,
            takes_preference=True,
            description=f"flat {_algo.upper()} on the combined reward for the hierarchy's total env steps",
        )
    )
for _worker, _colour in (("goal", "tab:green"), ("avoid", "tab:orange")):
    register_method(
        Method(
            f"hddpg-{_worker}",
            functools.partial(_run_manager, _worker),
            _manager_cost,
            needs_workers=True,
            colour=_colour,
            default=True,
            description=f"a manager preferring the {_worker} worker by the bias (paper Figure 10)",
        )
    )

#: The built-in methods (the registry may hold more).
METHODS = tuple(METHOD_REGISTRY)
#: The methods run by default: the paper's three plus the biased managers of Figure 10.
DEFAULT_METHODS: tuple[str, ...] = tuple(m.name for m in METHOD_REGISTRY.values() if m.default)
#: Flat single-agent baselines (``train_flat``'s algorithms).
FLAT_METHODS = ("ddpg", "td3", "sac", "tqc")
#: The methods defined on any env with several objectives (``BenchmarkSettings.env``), and their default.
ENV_METHODS = ("hddpg", *FLAT_METHODS)
DEFAULT_ENV_METHODS = ("hddpg", "ddpg")


def comparison_pairs(settings: BenchmarkSettings) -> list[tuple[str, str]]:
    """
    The paired comparisons of the paper's claims, as (challenger, baseline) run keys: ``hddpg`` against
    every baseline method that ran (in the transfer scenario, on each preference).
    """
    suffixes = [f"@{p}" for p in settings.preferences] if settings.scenario == "transfer" else [""]
    baselines = [m for m in settings.methods if METHOD_REGISTRY[m].baseline]
    return [(f"hddpg{s}", f"{b}{s}") for s in suffixes for b in baselines if "hddpg" in settings.methods]


# ------------------------------------------------------------------------------------------- scheduling
def task_cost(task: Task, settings: BenchmarkSettings) -> int:
    """A task's training budget in environment steps (HAM trains nothing), for scheduling."""
    if task.spec is None:
        return settings.workers_budget
    return task.spec.cost(settings)


def run_benchmark(
    settings: BenchmarkSettings,
    out: str | Path,
    n_jobs: int = 1,
    resume: bool = False,
    on_event: Callable[[str, Task, dict[str, Any] | None], None] | None = None,
) -> dict[str, Any]:
    """
    Run every task not yet finished, ``n_jobs`` processes at a time, then compute and write the results.

    Workers of a seed go before the runs that need them; ready tasks go seed by seed and, within a seed,
    longest (by budget) first, so that the runs left at the end are short and every process stays busy.

    :param settings: what to run.
    :param out: the benchmark folder (``benchmark.json``, ``records/``, ``seed-*/``, results).
    :param n_jobs: processes at a time.
    :param resume: keep finished runs (their records) and continue interrupted ones from checkpoints.
    :param on_event: called with ``("start" | "done" | "skip" | "failed", task, record or None)``.
    :return: the results (also written to ``out/results.json``).
    """
    if n_jobs < 1:
        raise ValueError(f"Expected `n_jobs` >= 1, actually: {n_jobs}")
    out = Path(out)
    notify = on_event or (lambda kind, task, record: None)
    settings_path = out / "benchmark.json"
    stored = asdict(settings)
    if resume and settings_path.exists():
        previous = json.loads(settings_path.read_text())["settings"]
        # Settings added since that benchmark was made hold their defaults in it.
        defaults = asdict(BenchmarkSettings())
        previous = {**{f.name: defaults[f.name] for f in fields(BenchmarkSettings)}, **previous}
        if previous != stored:
            changed = sorted(k for k in stored if previous.get(k) != stored[k])
            raise ValueError(
                f"Cannot resume {str(out)!r} with different settings ({', '.join(changed)} changed); "
                "run with the same options, or use --force to start over"
            )
    atomic_write_json(settings_path, {"settings": stored, "machine": machine_info()})

    tasks = plan_tasks(settings)
    records: dict[Task, dict[str, Any]] = {}
    for task in tasks:
        record = read_record(out, task) if resume else None
        if record is not None:
            records[task] = record
            notify("skip", task, record)
    pending = [t for t in tasks if t not in records]
    failed: dict[Task, str] = {}
    start = time.perf_counter()

    def ready(task: Task) -> bool:
        return not task.needs_workers or Task(WORKERS, task.seed) in records

    def blocked(task: Task) -> bool:
        return task.needs_workers and Task(WORKERS, task.seed) in failed

    def priority(task: Task) -> tuple[int, int]:
        # Seed by seed, so that an interrupted benchmark holds complete seeds; within a seed the longest
        # first (the LPT rule), so that the runs left at the end are short and no process idles long.
        return settings.seeds.index(task.seed), -task_cost(task, settings)

    context = multiprocessing.get_context("spawn")  # a clean interpreter per process: no forked torch state
    pool = cf.ProcessPoolExecutor(max_workers=n_jobs, mp_context=context)
    with sigterm_as_interrupt():
        running: dict[cf.Future[dict[str, Any]], Task] = {}
        try:
            while pending or running:
                for task in [t for t in pending if blocked(t)]:
                    pending.remove(task)
                    failed[task] = f"its workers failed: {failed[Task(WORKERS, task.seed)]}"
                    notify("failed", task, None)
                for task in sorted((t for t in pending if ready(t)), key=priority):
                    if len(running) >= n_jobs:
                        break
                    pending.remove(task)
                    running[pool.submit(run_task, task, settings, str(out))] = task
                    notify("start", task, None)
                if not running:
                    break
                done, _ = cf.wait(running, return_when=cf.FIRST_COMPLETED)
                for future in done:
                    task = running.pop(future)
                    try:
                        records[task] = future.result()
                        notify("done", task, records[task])
                    except Exception as error:  # one failed run must not lose the others
                        logger.exception("benchmark task %s failed", task.label)
                        failed[task] = f"{type(error).__name__}: {error}"
                        notify("failed", task, None)
        except BaseException:
            # Ctrl-C or SIGTERM: ask every running task to checkpoint and stop (train_agent turns SIGTERM into a
            # checkpoint-and-exit), then leave; --resume continues from the checkpoints.
            for process in list(getattr(pool, "_processes", {}).values()):  # no public API lists them
                with contextlib.suppress(Exception):
                    process.terminate()
            pool.shutdown(wait=True, cancel_futures=True)
            raise
    pool.shutdown(wait=True)
    wall = time.perf_counter() - start
    results = compute_results(settings, [records[t] for t in tasks if t in records])
    results["wall_time_s_this_invocation"] = wall
    results["failures"] = {t.label: message for t, message in failed.items()}
    results["machine"] = machine_info()
    write_outputs(out, results, [records[t] for t in tasks if t in records])
    return results


def machine_info() -> dict[str, Any]:
    """The machine a benchmark ran on (for the record: timings depend on it)."""
    cpu = platform.processor() or ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"nproc": os.cpu_count(), "cpu": cpu, "platform": platform.platform()}


# ------------------------------------------------------------------------------------------- statistics
def normalised_term_sums(summary: dict[str, Any]) -> tuple[float, float]:
    """
    The episode sums of the normalised goal and avoid terms, from an evaluation summary's raw means.

    Normalisation is affine per step, so the mean episode sum of a normalised term is
    ``(mean raw sum - mean length * low) / (high - low)`` with the env's fixed ``reward_bounds``.
    """

    normaliser = TermNormaliser(SnakeArmEnv().reward_bounds)
    length = summary["mean_length"]
    goal, avoid = (normaliser.episode_sum(t, summary[f"mean_{t}_reward"], length) for t in ("goal", "avoid"))
    return goal, avoid


def _with_term_sums(summary: dict[str, Any]) -> dict[str, Any]:
    if "mean_goal_reward" not in summary or "mean_avoid_reward" not in summary:
        return summary  # another env: its normalised total is mean_reach_reward already
    goal, avoid = normalised_term_sums(summary)
    return {**summary, "goal_reach_reward": goal, "avoid_reach_reward": avoid}


def curve_statistics(history: Sequence[dict[str, Any]], window: int) -> dict[str, float]:
    """
    A learning curve's mean and trend slope (paper Figure 9) over the evaluations at own steps <= ``window``.

    :param history: the run's evaluations (``timesteps`` and ``mean_reach_reward``).
    :param window: the last own step counted (the same for every method, so curves are compared alike).
    :return: ``curve_mean`` and ``slope`` (reach reward per :data:`SLOPE_UNIT` steps; 0 with < 2 points).
    """
    points = [p for p in history if p["timesteps"] <= window] or list(history[:1])
    x = np.array([p["timesteps"] for p in points], dtype=float) / SLOPE_UNIT
    y = np.array([p["mean_reach_reward"] for p in points], dtype=float)
    slope = trend_slope(x, y) if len(set(x.tolist())) >= 2 else 0.0
    return {"curve_mean": float(y.mean()), "slope": slope}


def compute_results(settings: BenchmarkSettings, records: Iterable[dict[str, Any]]) -> dict[str, Any]:
    """
    Seed statistics of finished runs: per method the final test metrics (mean, 95 % bootstrap CI, IQM),
    the learning curve's mean and slope, and the paired comparisons of the paper's claims.

    :param settings: the benchmark's settings.
    :param records: finished records (``workers`` records are used for the worker summaries).
    :return: a JSON-ready dict.
    """
    by_method: dict[str, dict[int, dict[str, Any]]] = {}
    worker_records = {}
    for record in records:
        if record["method"] == WORKERS:
            worker_records[record["seed"]] = record
        else:
            by_method.setdefault(record["method"], {})[record["seed"]] = record
    window = settings.timesteps
    methods: dict[str, Any] = {}
    per_seed: dict[str, dict[int, dict[str, float]]] = {}
    for method in [m for m in settings.method_keys if m in by_method]:
        runs = by_method[method]
        seeds = sorted(runs)
        values: dict[int, dict[str, float]] = {}
        for seed in seeds:
            run = runs[seed]
            test = _with_term_sums(run["test"])
            # Records of runs from before a metric existed (resumed) lack it: it is left out, not faked.
            values[seed] = {key: float(test[key]) for key in FINAL_METRICS if key in test}
            values[seed].update(curve_statistics(run["history"], window))
            values[seed]["final_curve_reward"] = float(run["history"][-1]["mean_reach_reward"])
        per_seed[method] = values
        stats = {
            key: summarise([values[s][key] for s in seeds])
            for key in (*FINAL_METRICS, "curve_mean", "slope", "final_curve_reward")
            if all(key in values[s] for s in seeds)
        }
        selection = [
            runs[s]["test"].get("selection_rate") for s in seeds if runs[s]["test"].get("selection_rate")
        ]
        methods[method] = {
            "seeds": seeds,
            "per_seed": {str(s): values[s] for s in seeds},
            "stats": stats,
            "worker_timesteps": int(np.mean([runs[s]["worker_timesteps"] for s in seeds])),
            "own_timesteps": int(max(runs[seeds[0]]["history"][-1]["timesteps"], 0)),
        }
        if selection:
            methods[method]["selection_rate"] = {
                name: float(np.mean([rates.get(name, 0.0) for rates in selection]))
                for name in sorted(set().union(*selection))
            }
        # Issue 13's target 2, per seed: does the hierarchy's choice depend on the state?
        dependence = {str(s): state_dependence(runs[s]["test"], DEPENDENCE_WORKER) for s in seeds}
        if any(figure is not None for figure in dependence.values()):
            methods[method]["state_dependence"] = dependence
    comparisons = {}
    for a, b in comparison_pairs(settings):
        if a in per_seed and b in per_seed:
            comparisons[f"{a} vs {b}"] = compare(per_seed[a], per_seed[b])
    workers = {}
    for name in ("goal", "avoid"):
        finals = [
            _with_term_sums(r["workers"][name]["metrics"])["mean_reach_reward"]
            for r in worker_records.values()
            if name in r["workers"]
        ]
        if finals:
            workers[name] = {"validation_mean_reach_reward": summarise(finals)}
    results: dict[str, Any] = {
        "settings": asdict(settings),
        "scenario": settings.scenario,
        "metric": "mean_reach_reward: episode sum of the normalised "
        + (
            f"terms {settings.env['terms']} (max {len(settings.env['terms'])} per step)"
            if settings.env is not None
            else "goal and avoid terms (max 2 per step)"
        ),
        "test_seeds": [TEST_SEED_BASE, TEST_SEED_BASE + settings.test_episodes - 1],
        "curve_seeds": [EVAL_SEED_BASE, EVAL_SEED_BASE + settings.eval_episodes - 1],
        "curve_window": window,
        "slope_unit_steps": SLOPE_UNIT,
        "methods": methods,
        "comparisons": comparisons,
        "workers": workers,
        "colours": {key: METHOD_REGISTRY[split_key(key)[0]].colour for key in methods},
    }
    if settings.scenario == "transfer":
        results["transfer"] = transfer_results(settings, by_method)
    return results


# --------------------------------------------------------------------------------------------- transfer
def preference_score(summary: dict[str, Any], preferences: dict[str, float]) -> float:
    """
    An evaluation's score under preference factors: ``sum_t factor_t * (episode sum of normalised term t)``,
    the return of the manager (and of the flat agent) trained on that preference.

    :param summary: an evaluation summary (raw term means and ``mean_length``).
    :param preferences: term -> factor (terms not named: 1).
    """
    goal, avoid = normalised_term_sums(summary)
    parts = {"goal": goal, "avoid": avoid}
    unknown = sorted(set(preferences) - set(parts))
    if unknown:
        raise ValueError(f"Unknown reward terms {unknown} in the preferences; the terms: {list(parts)}")
    return float(sum(preferences.get(term, 1.0) * value for term, value in parts.items()))


def steps_to_fraction(
    history: Sequence[dict[str, Any]],
    score: Callable[[dict[str, Any]], float],
    fraction: float = TRANSFER_FRACTION,
    floor: float = 0.0,
) -> int | None:
    """
    The own steps at which a learning curve first reaches ``fraction`` of its final score, measured from
    ``floor``: the first evaluation with ``score >= floor + fraction * (final - floor)``, where ``final`` is
    the last evaluation's score. With ``floor`` a random policy's score this is "90 % of the way from
    random to where it ended"; with ``floor = 0`` it is 90 % of the final score itself.

    :param history: the curve's evaluations, in order (``timesteps``: the run's own steps).
    :param score: the score of one evaluation.
    :param fraction: in (0, 1].
    :param floor: the score counted as no progress.
    :return: the steps, or ``None`` if the curve ends at or below ``floor`` (it learned nothing to reach).
    """
    if not 0 < fraction <= 1:
        raise ValueError(f"Expected `fraction` in (0, 1], actually: {fraction}")
    if not history:
        raise ValueError("Expected a learning curve with at least one evaluation, actually: none")
    scores = [score(point) for point in history]
    if scores[-1] <= floor:
        return None
    target = floor + fraction * (scores[-1] - floor)
    return next(int(p["timesteps"]) for p, value in zip(history, scores) if value >= target)


def transfer_results(
    settings: BenchmarkSettings, by_method: dict[str, dict[int, dict[str, Any]]]
) -> dict[str, Any]:
    """
    The transfer figure (issue 13, target 5): per preference and flat method, per seed the own env steps
    each run needs to reach :data:`TRANSFER_FRACTION` of its final score on its learning curve (scored
    with the preference's factors, measured from a random policy's score on the same episodes), their
    ratio flat / hddpg (how many times fewer steps the manager over pre-trained workers needs), and the
    ratio's mean with a 95 % bootstrap CI over the seeds where both are defined.

    :param settings: the benchmark's settings (transfer scenario).
    :param by_method: run key -> seed -> record.
    """
    out: dict[str, Any] = {
        "fraction": TRANSFER_FRACTION,
        "definition": (
            f"own env steps until the learning curve first reaches {TRANSFER_FRACTION:.0%} of the way from a "
            "random policy's score to the run's final score (both scored with the preference's factors); "
            "ratio = flat steps / hddpg steps (the manager's workers are trained once, before)"
        ),
        "eval_freq": settings.eval_freq_for(settings.timesteps),
        "preferences": {},
    }
    flats = [m for m in settings.methods if m != "hddpg"]
    for preference in settings.preferences:
        factors = Task(method_key("hddpg", preference), 0).preferences or {}

        def score(point: dict[str, Any], factors: dict[str, float] = factors) -> float:
            return preference_score(point, factors)

        managers = by_method.get(method_key("hddpg", preference), {})
        entry: dict[str, Any] = {}
        for flat in flats:
            agents = by_method.get(method_key(flat, preference), {})
            per_seed: dict[str, dict[str, Any]] = {}
            for seed in sorted(set(managers) & set(agents)):
                manager, agent = managers[seed], agents[seed]
                floor = score(manager["reference"])
                manager_steps = steps_to_fraction(manager["history"], score, floor=floor)
                flat_steps = steps_to_fraction(agent["history"], score, floor=floor)
                per_seed[str(seed)] = {
                    "hddpg_steps": manager_steps,
                    "flat_steps": flat_steps,
                    "ratio": flat_steps / manager_steps if manager_steps and flat_steps else None,
                    "hddpg_final_score": score(manager["history"][-1]),
                    "flat_final_score": score(agent["history"][-1]),
                    "random_score": floor,
                    "worker_timesteps": manager["worker_timesteps"],
                }
            ratios = [v["ratio"] for v in per_seed.values() if v["ratio"] is not None]
            entry[flat] = {
                "per_seed": per_seed,
                "ratio": summarise(ratios) if ratios else None,
                "seeds_with_ratio": len(ratios),
            }
        out["preferences"][preference] = entry
    return out


def compare(a: dict[int, dict[str, float]], b: dict[int, dict[str, float]]) -> dict[str, Any]:
    """
    Paired comparison of two methods over their common seeds (same seed: same workers, same test episodes).

    :param a: seed -> metrics of the challenger.
    :param b: seed -> metrics of the baseline.
    :return: per metric the paired mean difference with its 95 % bootstrap CI, the relative gain of the
        means, and the probability of improvement; plus the ratio of mean slopes (the paper's
        "improvement rate").
    """
    seeds = sorted(set(a) & set(b))
    out: dict[str, Any] = {"seeds": seeds}
    for key in ("mean_reach_reward", "curve_mean", "slope", "success_rate", "collisions_per_episode"):
        if not all(key in a[s] and key in b[s] for s in seeds):
            continue  # a metric the env does not report (the snake's success and collisions)
        xa = np.array([a[s][key] for s in seeds])
        xb = np.array([b[s][key] for s in seeds])
        diff, low, high = paired_difference_ci(xa, xb)
        out[key] = {
            "difference": diff,
            "ci_low": low,
            "ci_high": high,
            "relative_gain": float(xa.mean() / xb.mean() - 1.0) if xb.mean() != 0 else None,
            "probability_of_improvement": probability_of_improvement(xa, xb),
        }
    mean_b_slope = float(np.mean([b[s]["slope"] for s in seeds]))
    out["slope_ratio"] = (
        float(np.mean([a[s]["slope"] for s in seeds]) / mean_b_slope) if mean_b_slope != 0 else None
    )
    return out


def curve_bands(
    records: Iterable[dict[str, Any]], x_key: str, confidence: float = 0.95
) -> dict[str, dict[str, list[float]]]:
    """
    Per method, the mean learning curve over seeds with a bootstrap CI band, at the evaluation points
    every seed shares.

    :param records: finished method records.
    :param x_key: ``timesteps`` (own steps) or ``total_timesteps`` (including worker pre-training).
    :return: method -> ``{"x", "mean", "low", "high"}``.
    """
    curves: dict[str, list[dict[float, float]]] = {}
    for record in records:
        if record["method"] == WORKERS:
            continue
        curves.setdefault(record["method"], []).append(
            {float(p[x_key]): float(p["mean_reach_reward"]) for p in record["history"]}
        )
    bands = {}
    for method, per_seed in curves.items():
        xs = sorted(set.intersection(*(set(c) for c in per_seed)))
        band: dict[str, list[float]] = {"x": xs, "mean": [], "low": [], "high": []}
        for x in xs:
            mean, low, high = bootstrap_ci([c[x] for c in per_seed], confidence=confidence, n_resamples=2000)
            band["mean"].append(mean)
            band["low"].append(low)
            band["high"].append(high)
        bands[method] = band
    return bands


# ---------------------------------------------------------------------------------------------- outputs
#: Columns of ``evaluations.csv`` before the metrics.
CSV_KEYS = ("method", "seed", "kind", "timesteps", "total_timesteps")


def evaluation_rows(records: Iterable[dict[str, Any]]) -> list[dict[str, Any]]:
    """Every evaluation of every run as flat rows (``kind``: ``curve``, ``test`` or ``worker-<name>``)."""
    rows: list[dict[str, Any]] = []
    for record in records:
        base = {"method": record["method"], "seed": record["seed"]}
        if record["method"] == WORKERS:
            for name, history in record["history"].items():
                rows.extend({**base, "kind": f"worker-{name}", **_flat(p)} for p in history)
            continue
        rows.extend({**base, "kind": "curve", **_flat(p)} for p in record["history"])
        last = record["history"][-1]
        rows.append(
            {
                **base,
                "kind": "test",
                "timesteps": last["timesteps"],
                "total_timesteps": last["total_timesteps"],
                **_flat(_with_term_sums(record["test"])),
            }
        )
    return rows


def _flat(point: dict[str, Any]) -> dict[str, Any]:
    row = {}
    for key, value in point.items():
        if isinstance(value, dict):
            row.update({f"{key}.{name}": v for name, v in value.items()})
        else:
            row[key] = value
    return row


def write_csv(path: Path, rows: list[dict[str, Any]]) -> Path:
    """Write rows as CSV atomically, with the union of their keys as columns."""
    metric_keys = sorted({k for row in rows for k in row} - set(CSV_KEYS))

    def write(tmp: Path) -> None:
        with open(tmp, "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=[*CSV_KEYS, *metric_keys], restval="")
            writer.writeheader()
            writer.writerows(rows)

    return atomic_write(path, write)


#: The files :func:`write_outputs` produces in the benchmark folder.
OUTPUT_FILES = (
    "results.json",
    "results.md",
    "evaluations.csv",
    "learning_curves.png",
    "figure9.png",
    "figure10.png",
)


def _ci_text(stats: dict[str, Any], fmt: str) -> str:
    return f"{stats['mean']:{fmt}} [{stats['ci_low']:{fmt}}, {stats['ci_high']:{fmt}}]"


def markdown_report(results: dict[str, Any]) -> str:
    """
    The results as Markdown tables (for docs): per method the test metrics and curve statistics as
    mean [95 % bootstrap CI] over seeds, then the paired comparisons.

    :param results: a ``results.json`` dict.
    """
    unit = results["slope_unit_steps"]
    lines = [
        "| method | seeds | reach reward (test) | IQM | goal part | avoid part | goal-touch rate | collisions / episode "
        f"| success | min clearance | saturated actions | curve mean | slope / {unit} steps | worker choices (test) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for method, entry in results["methods"].items():
        s = entry["stats"]
        choices = ", ".join(f"{k} {v:.0%}" for k, v in entry.get("selection_rate", {}).items()) or "-"
        # The deciding network's saturation (the manager's for hierarchies); absent in older results.
        saturation = f"{s['action_saturation']['mean']:.0%}" if "action_saturation" in s else "-"
        # The snake's own metrics; "-" on an env that does not report them.
        snake = {
            key: _ci_text(s[key], fmt) if key in s else "-"
            for key, fmt in (
                ("goal_reach_reward", ".1f"),
                ("avoid_reach_reward", ".1f"),
                ("goal_touch_rate", ".3f"),
                ("collisions_per_episode", ".2f"),
                ("success_rate", ".2f"),
            )
        }
        clearance = f"{s['min_clearance']['mean']:.3f}" if "min_clearance" in s else "-"
        lines.append(
            f"| {method} | {len(entry['seeds'])} | {_ci_text(s['mean_reach_reward'], '.1f')} "
            f"| {s['mean_reach_reward']['iqm']:.1f} | {snake['goal_reach_reward']} "
            f"| {snake['avoid_reach_reward']} | {snake['goal_touch_rate']} "
            f"| {snake['collisions_per_episode']} | {snake['success_rate']} "
            f"| {clearance} | {saturation} | {_ci_text(s['curve_mean'], '.1f')} "
            f"| {_ci_text(s['slope'], '.2f')} | {choices} |"
        )
    if results["comparisons"]:
        lines += [
            "",
            "| A vs B | metric | A - B [95 % CI], paired by seed | relative | P(A > B) |",
            "|---|---|---|---|---|",
        ]
        for pair, comparison in results["comparisons"].items():
            for metric in (
                "mean_reach_reward",
                "curve_mean",
                "slope",
                "success_rate",
                "collisions_per_episode",
            ):
                if metric not in comparison:
                    continue
                c = comparison[metric]
                relative = f"{c['relative_gain']:+.1%}" if c["relative_gain"] is not None else "-"
                lines.append(
                    f"| {pair} | {metric} | {c['difference']:+.2f} [{c['ci_low']:+.2f}, {c['ci_high']:+.2f}] "
                    f"| {relative} | {c['probability_of_improvement']:.2f} |"
                )
            ratio = comparison["slope_ratio"]
            lines.append(
                f"| {pair} | slope ratio A / B | {ratio:.2f} | | |"
                if ratio is not None
                else f"| {pair} | slope ratio A / B | undefined (B's slope is 0) | | |"
            )
    lines += _dependence_lines(results)
    lines += _transfer_lines(results)
    return "\n".join(lines) + "\n"


def _share_text(value: float | None) -> str:
    return f"{value:.1%}" if value is not None else "-"


def _dependence_lines(results: dict[str, Any]) -> list[str]:
    """The per-seed state-dependence table (issue 13, target 2), for the methods that report choices."""
    rows = []
    for method, entry in results["methods"].items():
        for seed, figure in entry.get("state_dependence", {}).items():
            if figure is None:
                continue
            ratio = f"{figure['ratio']:.2f}" if figure["ratio"] is not None else "undefined"
            rows.append(
                f"| {method} | {seed} | {_share_text(figure['near_share'])} ({figure['near_choices']}) "
                f"| {_share_text(figure['clear_share'])} ({figure['clear_choices']}) | {ratio} |"
            )
    if not rows:
        return []
    figure = next(f for e in results["methods"].values() for f in e.get("state_dependence", {}).values() if f)
    return [
        "",
        f"State dependence (test episodes): the {figure['worker']} worker's share of the choices made with the "
        f"nearest obstacle within {figure['near_clearance']:.3g} (half the sensor range) and with none within "
        f"{figure['clear_clearance']:.3g} (the sensor range); choices counted in brackets. A manager that "
        "decides by state has a ratio well above 1; a fixed mix, about 1.",
        "",
        f"| method | seed | {figure['worker']} share near | {figure['worker']} share none in range | ratio |",
        "|---|---|---|---|---|",
        *rows,
    ]


def _transfer_lines(results: dict[str, Any]) -> list[str]:
    """The transfer figure (issue 13, target 5): steps to reach the final score's fraction, and their ratio."""
    transfer = results.get("transfer")
    if not transfer:
        return []
    lines = [
        "",
        f"Transfer: {transfer['definition']}. Curves are evaluated every {transfer['eval_freq']} own steps, "
        "so a run that is there at its first evaluation counts that many; 'no gain': the curve ended at or below the random score.",
        "",
        "| preference | flat | seeds | hddpg steps (mean) | flat steps (mean) | ratio flat / hddpg [95 % CI] "
        "| per seed (flat / hddpg) |",
        "|---|---|---|---|---|---|---|",
    ]
    for preference, entry in transfer["preferences"].items():
        for flat, comparison in entry.items():
            seeds = comparison["per_seed"]
            manager = [v["hddpg_steps"] for v in seeds.values() if v["hddpg_steps"] is not None]
            agent = [v["flat_steps"] for v in seeds.values() if v["flat_steps"] is not None]
            ratio = comparison["ratio"]
            per_seed = ", ".join(
                f"{seed}: {v['flat_steps'] if v['flat_steps'] is not None else 'no gain'} / "
                f"{v['hddpg_steps'] if v['hddpg_steps'] is not None else 'no gain'}"
                for seed, v in seeds.items()
            )
            lines.append(
                f"| {preference} | {flat} | {comparison['seeds_with_ratio']}/{len(seeds)} "
                f"| {np.mean(manager) if manager else float('nan'):.0f} | {np.mean(agent) if agent else float('nan'):.0f} "
                f"| {_ci_text(ratio, '.2f') if ratio else 'undefined'} | {per_seed} |"
            )
    return lines


def write_outputs(out: Path, results: dict[str, Any], records: list[dict[str, Any]]) -> None:
    """Write ``results.json``, ``results.md``, ``evaluations.csv`` and the plots into ``out``."""

    method_records = [r for r in records if r["method"] != WORKERS]
    results["curves"] = {
        "own_steps": curve_bands(method_records, "timesteps"),
        "total_steps": curve_bands(method_records, "total_timesteps"),
    }
    atomic_write_json(out / "results.json", results)
    atomic_write(out / "results.md", lambda tmp: tmp.write_text(markdown_report(results)))
    write_csv(out / "evaluations.csv", evaluation_rows(records))
    figures.benchmark_learning_curves(results, out / "learning_curves.png")
    figures.figure9(results, out / "figure9.png")
    figures.figure10(results, out / "figure10.png")

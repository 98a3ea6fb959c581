"""
The benchmark of paper Section 3.3-3.4: every method for every seed, one common metric, seed statistics.

Methods (:data:`METHODS`):

- ``hddpg``: the two workers, then a manager with equal preferences (paper Algorithm 1);
- ``hddpg-goal`` / ``hddpg-avoid``: managers preferring one worker by ``bias`` (15 %, paper Figure 10);
- ``ham``: the hand-written switch over the same workers (:mod:`sb3_hddpg.baselines.ham`), no training;
- ``ddpg`` (and optionally ``td3``, ``sac``, ``tqc``): one flat agent on the combined reward.

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
import json
import logging
import multiprocessing
import os
import platform
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sb3_hddpg.evaluation import EVAL_SEED_BASE
from sb3_hddpg.io import atomic_write, atomic_write_json
from sb3_hddpg.stats import (
    bootstrap_ci,
    paired_difference_ci,
    probability_of_improvement,
    summarise,
    trend_slope,
)
from sb3_hddpg.training import sigterm_as_interrupt

logger = logging.getLogger(__name__)

#: Every method the benchmark knows.
METHODS = ("hddpg", "ham", "ddpg", "td3", "sac", "tqc", "hddpg-goal", "hddpg-avoid")
#: The methods run by default: the paper's three plus the biased managers of Figure 10.
DEFAULT_METHODS = ("hddpg", "ham", "ddpg", "hddpg-goal", "hddpg-avoid")
#: Flat single-agent baselines (``train_flat``'s algorithms).
FLAT_METHODS = ("ddpg", "td3", "sac", "tqc")
#: Methods that need the seed's workers, with the worker a manager prefers (``None``: no preference).
MANAGER_PREFERENCE = {"hddpg": None, "hddpg-goal": "goal", "hddpg-avoid": "avoid"}
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
#: The comparisons of the paper's claims: (challenger, baseline).
PAIRS = (("hddpg", "ddpg"), ("hddpg", "ham"), ("hddpg", "td3"), ("hddpg", "sac"), ("hddpg", "tqc"))
#: Bumped when a record's meaning changes.
RECORD_VERSION = 1
#: Steps per unit of the reported learning-curve slopes.
SLOPE_UNIT = 1000


@dataclass
class BenchmarkSettings:
    """
    What to run; stored in ``DIR/benchmark.json`` so that ``--resume`` continues the same benchmark.

    :param methods: methods among :data:`METHODS`.
    :param seeds: training seeds (each method runs once per seed).
    :param timesteps: the manager's budget, in its own (env) steps.
    :param worker_timesteps: each worker's budget.
    :param flat_timesteps: a flat agent's budget (``None``: ``timesteps`` plus every worker's budget, so
        that a flat agent uses as many environment steps as the whole hierarchy).
    :param eval_freq: steps between learning-curve evaluations of every run (``None``: ``timesteps // 10``).
    :param eval_episodes: episodes per learning-curve evaluation.
    :param test_episodes: episodes of the final test evaluation.
    :param ham_threshold: HAM's switching threshold (``None``: its default).
    :param ham_hysteresis: HAM's hysteresis.
    :param bias: the biased managers' extra preference factor (paper: 15 %).
    :param backend: the training backend of every agent, ``sb3`` or ``sbx`` (saved models are SB3 either way).
    """

    methods: list[str] = field(default_factory=lambda: list(DEFAULT_METHODS))
    seeds: list[int] = field(default_factory=lambda: list(range(5)))
    timesteps: int = 10_000
    worker_timesteps: int = 10_000
    flat_timesteps: int | None = None
    eval_freq: int | None = None
    eval_episodes: int = 5
    test_episodes: int = 20
    ham_threshold: float | None = None
    ham_hysteresis: float = 0.0
    bias: float = 0.15
    backend: str = "sb3"

    def __post_init__(self) -> None:
        from sb3_hddpg.backends import check_algo, check_backend

        self.backend = check_backend(self.backend)
        for method in self.methods:
            if method in FLAT_METHODS:
                check_algo(method, self.backend)
        unknown = [m for m in self.methods if m not in METHODS]
        if unknown:
            raise ValueError(f"Unknown methods {unknown}; choose from {list(METHODS)}")
        if len(set(self.methods)) != len(self.methods) or not self.methods:
            raise ValueError(f"Expected distinct methods, at least one, actually: {self.methods}")
        if not self.seeds or len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"Expected distinct seeds, at least one, actually: {self.seeds}")
        for name in ("timesteps", "worker_timesteps", "eval_episodes", "test_episodes"):
            if getattr(self, name) < 1:
                raise ValueError(f"Expected `{name}` >= 1, actually: {getattr(self, name)}")

    @property
    def flat_budget(self) -> int:
        """A flat agent's budget: as many env steps as the hierarchy (workers + manager) by default."""
        if self.flat_timesteps is not None:
            return self.flat_timesteps
        return self.timesteps + 2 * self.worker_timesteps

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

    :param method: a method, or ``workers`` (a seed's two workers).
    :param seed: the training seed.
    """

    method: str
    seed: int

    @property
    def needs_workers(self) -> bool:
        return self.method in MANAGER_PREFERENCE or self.method == "ham"

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
    """Every task of a benchmark: per seed its workers (if any method needs them) and every method."""
    tasks = []
    for seed in settings.seeds:
        methods = [Task(m, seed) for m in settings.methods]
        if any(t.needs_workers for t in methods):
            tasks.append(Task("workers", seed))
        tasks.extend(methods)
    return tasks


# ---------------------------------------------------------------------------------------------- one task
def _history(path: Path, offset: int) -> list[dict[str, Any]]:
    """An ``evaluations/<name>.json`` history with ``total_timesteps = timesteps + offset`` on every point."""
    history = json.loads(path.read_text())
    return [{**point, "total_timesteps": int(point["timesteps"]) + offset} for point in history]


def _test(policy_path: Path, settings: BenchmarkSettings) -> dict[str, Any]:
    """The final test evaluation of a saved policy, loaded the safe way a user would load it."""
    from sb3_hddpg.evaluation import evaluate
    from sb3_hddpg.loading import load_policy

    loaded = load_policy(policy_path)
    env = loaded.make_env()
    try:
        return evaluate(loaded.policy, env, n_episodes=settings.test_episodes, seed=TEST_SEED_BASE).summary()
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

    from sb3_hddpg.callbacks.checkpoint import read_checkpoint_state

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
    if task.method == "workers":
        from sb3_hddpg.training import train_workers

        manifest = train_workers(
            folder,
            timesteps=settings.worker_timesteps,
            seed=task.seed,
            resume=True,  # keeps finished workers and continues an interrupted one
            eval_freq=settings.eval_freq_for(settings.worker_timesteps),
            eval_episodes=settings.eval_episodes,
            backend=settings.backend,
        )
        record["worker_timesteps"] = _workers_steps(folder)
        record["workers"] = {
            name: {"timesteps": entry["timesteps_trained"], "metrics": entry["metrics"]}
            for name, entry in manifest["workers"].items()
        }
        record["history"] = {
            name: _history(folder / "evaluations" / f"{name}.json", 0) for name in manifest["workers"]
        }
    elif task.method in MANAGER_PREFERENCE:
        from sb3_hddpg.training import train_manager

        run_dir = folder / task.method
        train_manager(
            folder,
            run_dir,
            prefer=MANAGER_PREFERENCE[task.method],
            bias=settings.bias,
            timesteps=settings.timesteps,
            seed=task.seed,
            resume=read_checkpoint_state(run_dir / "checkpoints" / "manager") is not None,
            eval_freq=settings.eval_freq_for(settings.timesteps),
            eval_episodes=settings.eval_episodes,
            backend=settings.backend,
        )
        offset = _workers_steps(folder)
        record["worker_timesteps"] = offset
        record["history"] = _history(run_dir / "evaluations" / "manager.json", offset)
        record["test"] = _test(run_dir / "hierarchy.zip", settings)
    elif task.method == "ham":
        record.update(_run_ham(task, settings, folder))
    elif task.method in FLAT_METHODS:
        from sb3_hddpg.training import train_flat

        run_dir = folder / task.method
        train_flat(
            run_dir,
            algo=task.method,
            timesteps=settings.flat_budget,
            seed=task.seed,
            resume=True,
            eval_freq=settings.eval_freq_for(settings.flat_budget),
            eval_episodes=settings.eval_episodes,
            backend=settings.backend,
        )
        record["worker_timesteps"] = 0
        record["history"] = _history(run_dir / "evaluations" / f"flat-{task.method}.json", 0)
        record["test"] = _test(run_dir / "flat" / f"{task.method}.zip", settings)
    else:
        raise ValueError(f"Unknown task {task.label}")
    record["wall_time_s"] = time.perf_counter() - start
    atomic_write_json(record_path(out, task), record)
    return record


def _run_ham(task: Task, settings: BenchmarkSettings, folder: Path) -> dict[str, Any]:
    """Save the seed's HAM switch and evaluate it: one learning-curve point (it does not learn) and the test."""
    import gymnasium as gym

    from sb3_hddpg.baselines.ham import load_ham, save_ham
    from sb3_hddpg.evaluation import evaluate
    from sb3_hddpg.training import FLAT_ENV_ID

    env = gym.make(FLAT_ENV_ID)
    try:
        n_links = env.unwrapped.state_layout["joint_obstacle_distances"]  # type: ignore[attr-defined]
        threshold = settings.ham_threshold
        if threshold is None:
            from sb3_hddpg.baselines.ham import DEFAULT_MARGIN

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


# ------------------------------------------------------------------------------------------- scheduling
def task_cost(task: Task, settings: BenchmarkSettings) -> int:
    """A task's training budget in environment steps (HAM trains nothing), for scheduling."""
    if task.method == "workers":
        return 2 * settings.worker_timesteps
    if task.method in FLAT_METHODS:
        return settings.flat_budget
    if task.method in MANAGER_PREFERENCE:
        return settings.timesteps
    return 0


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
        # Benchmarks from before the backend choice trained on SB3.
        previous = {"backend": "sb3", **json.loads(settings_path.read_text())["settings"]}
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
        return not task.needs_workers or Task("workers", task.seed) in records

    def blocked(task: Task) -> bool:
        return task.needs_workers and Task("workers", task.seed) in failed

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
                    failed[task] = f"its workers failed: {failed[Task('workers', task.seed)]}"
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
    from sb3_hddpg.envs import SnakeArmEnv

    bounds = SnakeArmEnv().reward_bounds
    length = summary["mean_length"]
    out = []
    for term in ("goal", "avoid"):
        low, high = bounds[term]
        out.append((summary[f"mean_{term}_reward"] - length * low) / (high - low))
    return out[0], out[1]


def _with_term_sums(summary: dict[str, Any]) -> dict[str, Any]:
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
        if record["method"] == "workers":
            worker_records[record["seed"]] = record
        else:
            by_method.setdefault(record["method"], {})[record["seed"]] = record
    window = settings.timesteps
    methods: dict[str, Any] = {}
    per_seed: dict[str, dict[int, dict[str, float]]] = {}
    for method in [m for m in settings.methods if m in by_method]:
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
    comparisons = {}
    for a, b in PAIRS:
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
    return {
        "settings": asdict(settings),
        "metric": "mean_reach_reward: episode sum of the normalised goal and avoid terms (max 2 per step)",
        "test_seeds": [TEST_SEED_BASE, TEST_SEED_BASE + settings.test_episodes - 1],
        "curve_seeds": [EVAL_SEED_BASE, EVAL_SEED_BASE + settings.eval_episodes - 1],
        "curve_window": window,
        "slope_unit_steps": SLOPE_UNIT,
        "methods": methods,
        "comparisons": comparisons,
        "workers": workers,
    }


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
        if record["method"] == "workers":
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
    rows = []
    for record in records:
        base = {"method": record["method"], "seed": record["seed"]}
        if record["method"] == "workers":
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
        lines.append(
            f"| {method} | {len(entry['seeds'])} | {_ci_text(s['mean_reach_reward'], '.1f')} "
            f"| {s['mean_reach_reward']['iqm']:.1f} | {_ci_text(s['goal_reach_reward'], '.1f')} "
            f"| {_ci_text(s['avoid_reach_reward'], '.1f')} | {_ci_text(s['goal_touch_rate'], '.3f')} "
            f"| {_ci_text(s['collisions_per_episode'], '.2f')} | {_ci_text(s['success_rate'], '.2f')} "
            f"| {s['min_clearance']['mean']:.3f} | {saturation} | {_ci_text(s['curve_mean'], '.1f')} "
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
    return "\n".join(lines) + "\n"


def write_outputs(out: Path, results: dict[str, Any], records: list[dict[str, Any]]) -> None:
    """Write ``results.json``, ``results.md``, ``evaluations.csv`` and the plots into ``out``."""
    from sb3_hddpg import plots

    method_records = [r for r in records if r["method"] != "workers"]
    results["curves"] = {
        "own_steps": curve_bands(method_records, "timesteps"),
        "total_steps": curve_bands(method_records, "total_timesteps"),
    }
    atomic_write_json(out / "results.json", results)
    atomic_write(out / "results.md", lambda tmp: tmp.write_text(markdown_report(results)))
    write_csv(out / "evaluations.csv", evaluation_rows(records))
    plots.learning_curves(results, out / "learning_curves.png")
    plots.figure9(results, out / "figure9.png")
    plots.figure10(results, out / "figure10.png")


def load_results(out: str | Path) -> dict[str, Any]:
    """The ``results.json`` of a finished benchmark."""
    return json.loads((Path(out) / "results.json").read_text())

"""
A benchmark's tasks: one run of a method (or a seed's workers) on one seed, each in its own process; the plan
of every task of a benchmark, the paired comparisons its results make, and each task's cost for scheduling.
"""

from __future__ import annotations

from dataclasses import dataclass

from hddpg_zoo.benchmark.methods import METHOD_REGISTRY, WORKERS, Method, split_key
from hddpg_zoo.benchmark.settings import BenchmarkSettings
from sb3_hddpg.hierarchy.selection import parse_preferences


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


def plan_tasks(settings: BenchmarkSettings) -> list[Task]:
    """Every task of a benchmark: per seed its workers (if any method needs them) and every run."""
    tasks = []
    for seed in settings.seeds:
        runs = [Task(key, seed) for key in settings.method_keys]
        if any(t.needs_workers for t in runs):
            tasks.append(Task(WORKERS, seed))
        tasks.extend(runs)
    return tasks


def comparison_pairs(settings: BenchmarkSettings) -> list[tuple[str, str]]:
    """
    The paired comparisons of the paper's claims, as (challenger, baseline) run keys: ``hddpg`` against
    every baseline method that ran (in the transfer scenario, on each preference), and so does every other
    challenger (e.g. ``hddpg-sac``), which is also paired with ``hddpg``.
    """
    suffixes = [f"@{p}" for p in settings.preferences] if settings.scenario == "transfer" else [""]
    baselines = [m for m in settings.methods if METHOD_REGISTRY[m].baseline]
    challengers = [m for m in settings.methods if m == "hddpg" or METHOD_REGISTRY[m].challenger]
    pairs = [(c, b) for c in challengers for b in baselines if b != c]
    pairs += [(c, "hddpg") for c in challengers if c != "hddpg" and "hddpg" in settings.methods]
    return [(f"{c}{s}", f"{b}{s}") for s in suffixes for c, b in pairs]


def task_cost(task: Task, settings: BenchmarkSettings) -> int:
    """A task's training budget in environment steps (HAM trains nothing), for scheduling."""
    if task.spec is None:
        return settings.workers_budget
    return task.spec.cost(settings)

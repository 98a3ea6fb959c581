"""
A benchmark's progress: how many of its runs are done, and the time the rest should take at the pace of
those finished so far (a long run on a shared machine is planned by it).
"""

from __future__ import annotations

from collections.abc import Mapping
from statistics import fmean
from typing import Any

from hddpg_zoo.benchmark.settings import BenchmarkSettings
from hddpg_zoo.benchmark.tasks import Task, plan_tasks, task_cost


class Progress:
    """
    The runs of a benchmark done so far and an estimate of its time left.

    A run still to do is expected to take what the finished runs of the same method (or the workers) took on
    average, every invocation counted; a method with no finished run yet is expected to take its budget in
    env steps at the pace, per env step of budget, of all the runs finished so far. The runs in progress count
    as not started, and the total is shared by ``n_jobs`` processes: an estimate, not a promise.

    :param settings: the benchmark's settings.
    :param n_jobs: the runs trained at a time.
    """

    def __init__(self, settings: BenchmarkSettings, n_jobs: int) -> None:
        if n_jobs < 1:
            raise ValueError(f"Expected n_jobs >= 1, actually: {n_jobs}")
        self._settings = settings
        self._n_jobs = n_jobs
        self._tasks = plan_tasks(settings)
        self._seconds: dict[Task, float] = {}

    def finished(self, task: Task, record: Mapping[str, Any]) -> None:
        """Count a run done (finished now, or kept from an earlier invocation), with its record's wall time."""
        seconds = record.get("wall_time_s_total", record.get("wall_time_s"))
        self._seconds[task] = float(seconds) if isinstance(seconds, (int, float)) else 0.0

    @property
    def done(self) -> int:
        """The runs done."""
        return len(self._seconds)

    @property
    def total(self) -> int:
        """Every run of the benchmark."""
        return len(self._tasks)

    def seconds_left(self) -> float | None:
        """The estimated wall time left (see the class), ``None`` before any run has finished."""
        if not self._seconds:
            return None
        by_method: dict[str, list[float]] = {}
        for task, seconds in self._seconds.items():
            by_method.setdefault(task.method, []).append(seconds)
        budget = sum(task_cost(task, self._settings) for task in self._seconds)
        per_step = sum(self._seconds.values()) / budget if budget else 0.0
        left = [
            fmean(by_method[task.method])
            if task.method in by_method
            else per_step * task_cost(task, self._settings)
            for task in self._tasks
            if task not in self._seconds
        ]
        return sum(left) / self._n_jobs

    def summary(self) -> str:
        """``"12/120 runs done; about 3.5 h left at this pace"`` (without the estimate before any run ends)."""
        text = f"{self.done}/{self.total} runs done"
        left = self.seconds_left()
        if left is None or self.done == self.total:
            return text
        shown = f"{left / 3600:.1f} h" if left >= 5400 else f"{max(1, round(left / 60))} min"
        return f"{text}; about {shown} left at this pace"


__all__ = ["Progress"]

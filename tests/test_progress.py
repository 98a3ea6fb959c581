"""A benchmark's progress and its time left, at the pace of the runs finished so far."""

from __future__ import annotations

import pytest

from hddpg_zoo.benchmark import WORKERS, BenchmarkSettings, Task, task_cost
from hddpg_zoo.benchmark.progress import Progress


def test_time_left_at_the_pace_of_each_methods_finished_runs():
    settings = BenchmarkSettings(methods=["ham", "ddpg"], seeds=[0, 1])
    progress = Progress(settings, n_jobs=2)
    assert (progress.done, progress.total, progress.seconds_left()) == (0, 6, None)
    assert progress.summary() == "0/6 runs done"

    # Only the workers finished: the flat agent is expected at their pace per env step of budget.
    progress.finished(Task(WORKERS, 0), {"wall_time_s": 30.0, "wall_time_s_total": 100.0})
    per_step = 100.0 / task_cost(Task(WORKERS, 0), settings)
    flat = per_step * task_cost(Task("ddpg", 0), settings)
    assert progress.seconds_left() == pytest.approx((100.0 + 2 * flat) / 2)  # HAM's budget is 0 steps

    # Then each method at the mean of its own finished runs, every invocation counted.
    progress.finished(Task("ddpg", 0), {"wall_time_s": 300.0, "wall_time_s_total": 300.0})
    progress.finished(Task("ham", 0), {"wall_time_s": 50.0, "wall_time_s_total": 50.0})
    assert progress.seconds_left() == pytest.approx((100.0 + 50.0 + 300.0) / 2)
    assert progress.summary() == "3/6 runs done; about 4 min left at this pace"

    progress.finished(Task("ddpg", 1), {"wall_time_s": 100.0, "wall_time_s_total": 100.0})
    assert progress.seconds_left() == pytest.approx((100.0 + 50.0) / 2)
    for task in (Task(WORKERS, 1), Task("ham", 1)):
        progress.finished(task, {"wall_time_s": 1.0, "wall_time_s_total": 1.0})
    assert progress.summary() == "6/6 runs done"


def test_hours_are_shown_beyond_ninety_minutes_and_n_jobs_is_checked():
    progress = Progress(BenchmarkSettings(methods=["ham"], seeds=[0, 1, 2]), n_jobs=1)
    progress.finished(Task(WORKERS, 0), {"wall_time_s": 3600.0, "wall_time_s_total": 3600.0})
    progress.finished(Task("ham", 0), {"wall_time_s": 0.0, "wall_time_s_total": 0.0})
    assert progress.summary() == "2/6 runs done; about 2.0 h left at this pace"
    with pytest.raises(ValueError, match="n_jobs"):
        Progress(BenchmarkSettings(), n_jobs=0)

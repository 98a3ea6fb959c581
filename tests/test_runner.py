"""
The one process runner of benchmark, tuning and quickstart: scheduling, failures, progress, processes.

The tests of what every executor that runs jobs in other processes must do run for the local pool and for
the Ray executor (on a local Ray cluster; skipped without Ray); tests/test_ray_executor.py holds what only
the Ray executor does.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import time

import pytest

from hddpg_zoo.runner import Executor, InlineExecutor, Job, LocalProcessExecutor, run_jobs
from tests.jobs import (
    STOP_BOUND,
    broken,
    checkpoint_on_interrupt,
    checkpointed_pids,
    die,
    pid_after,
    sigterm_once_started,
    square,
    started_pids,
)


@pytest.fixture(params=[pytest.param("local", marks=pytest.mark.slow), "ray"])
def process_executor(request: pytest.FixtureRequest) -> Executor:
    """
    A 2-slot executor that runs jobs in other processes: the local pool (its processes import torch: about
    25 s on a loaded machine, so slow), or the Ray executor on the module's Ray cluster (whose workers stay
    up from test to test), without retries, so that a killed job fails as locally.
    """
    if request.param == "local":
        return LocalProcessExecutor(2)
    request.getfixturevalue("ray_cluster")
    from hddpg_zoo.ray_executor import RayExecutor

    return RayExecutor(max_retries=0)


#: How each executor reports a job whose process was killed.
KILLED = {
    "LocalProcessExecutor": f"RuntimeError: its process exited with code {-signal.SIGKILL}",
    "RayExecutor": "WorkerCrashedError: ",
}


def test_dependencies_first_then_group_then_longest_first():
    order: list[str] = []
    jobs = [
        Job("short-0", square, (1,), cost=1, group=0),
        Job("long-1", square, (2,), cost=9, group=1),
        Job("long-0", square, (3,), cost=9, group=0, after=("base-0",)),
        Job("base-0", square, (4,), cost=0, group=0),
    ]
    outcome = run_jobs(
        jobs, InlineExecutor(), on_event=lambda kind, job, value: order.append(f"{kind} {job.key}")
    )
    starts = [e.split()[1] for e in order if e.startswith("start")]
    # Group 0 first, longest first among the ready ones; long-0 waits for base-0, then goes before group 1.
    assert starts == ["short-0", "base-0", "long-0", "long-1"]
    assert outcome.results == {"short-0": 1, "long-1": 4, "long-0": 9, "base-0": 16}
    assert not outcome.failures


def test_a_failure_fails_its_dependants_only():
    progress: list[tuple[str, float]] = []
    jobs = [
        Job("bad", broken, ("no luck",)),
        Job("needs-bad", square, (2,), after=("bad",)),
        Job("needs-needs-bad", square, (5,), after=("needs-bad",)),
        Job("fine", square, (3,)),
    ]
    outcome = run_jobs(jobs, InlineExecutor(), on_progress=lambda key, value: progress.append((key, value)))
    assert outcome.results == {"fine": 9}
    assert outcome.failure_message("bad") == "ValueError: no luck"
    assert outcome.failure_message("needs-bad") == "RuntimeError: bad failed: ValueError: no luck"
    assert outcome.failure_message("needs-needs-bad").startswith("RuntimeError: needs-bad failed: ")
    assert progress == [("fine", 3)]
    with pytest.raises(ValueError, match="no luck"):
        run_jobs(jobs, InlineExecutor(), fail_fast=True)
    with pytest.raises(ValueError, match="unknown jobs"):
        run_jobs([Job("a", square, (1,), after=("b",))], InlineExecutor())


def test_processes_return_results_errors_progress_and_survive_a_killed_one(process_executor):
    progress: dict[str, float] = {}
    order: list[str] = []
    jobs = [
        Job("square", square, (7,)),
        Job("after-square", square, (4,), after=("square",)),
        Job("bad", broken, ("in a child",)),
        Job("needs-bad", square, (5,), after=("bad",)),
        Job("killed", die),
        Job("pid-a", pid_after, (0.5,)),
        Job("pid-b", pid_after, (0.5,)),
    ]
    outcome = run_jobs(
        jobs,
        process_executor,
        on_event=lambda event, job, value: order.append(f"{event} {job.key}"),
        on_progress=progress.__setitem__,
    )
    assert outcome.results["square"] == 49 and outcome.results["after-square"] == 16
    assert order.index("done square") < order.index("start after-square")
    assert progress == {"square": 7, "after-square": 4}  # relayed from the jobs' processes to this one
    # The child's own error, re-created here, fails it and its dependant only.
    assert outcome.failure_message("bad") == "ValueError: in a child"
    assert outcome.failure_message("needs-bad").startswith("RuntimeError: bad failed: ValueError")
    assert outcome.failure_message("killed").startswith(KILLED[type(process_executor).__name__])
    # The others ran to the end in other processes (not this one), a dead one being replaced.
    assert {"pid-a", "pid-b"} <= set(outcome.results) and os.getpid() not in outcome.results.values()


def test_sigterm_to_the_parent_makes_running_jobs_checkpoint_and_stop(process_executor, tmp_path):
    jobs = [Job(f"long-{i}", checkpoint_on_interrupt, (str(tmp_path),)) for i in range(3)]
    handler = signal.getsignal(signal.SIGTERM)
    sigterm_once_started(tmp_path, 2)
    started = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        run_jobs(jobs, process_executor)
    assert time.monotonic() - started < STOP_BOUND  # nobody waited for the long jobs
    # The two running jobs saved their checkpoints (none was killed); the third never started.
    assert len(started_pids(tmp_path)) == 2
    assert checkpointed_pids(tmp_path) == started_pids(tmp_path)
    assert not [p for p in multiprocessing.active_children() if p.name.startswith("job-")]
    assert signal.getsignal(signal.SIGTERM) is handler  # the parent's handler is restored

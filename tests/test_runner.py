"""The one process runner of benchmark, tuning and quickstart: scheduling, failures, progress, processes."""

from __future__ import annotations

import multiprocessing
import os
import signal
import threading
import time
from pathlib import Path

import pytest

from sb3_hddpg.experiments.runner import (
    InlineExecutor,
    Job,
    LocalProcessExecutor,
    report_progress,
    run_jobs,
)


def square(x: int) -> int:
    report_progress(x)
    return x * x


def broken(message: str) -> int:
    raise ValueError(message)


def die() -> int:
    os.kill(os.getpid(), signal.SIGKILL)
    return 0


def pid_after(seconds: float) -> int:
    time.sleep(seconds)
    return os.getpid()


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


@pytest.mark.slow  # spawns processes that import torch: about 25 s on a loaded machine
def test_processes_return_results_errors_progress_and_survive_a_killed_one():
    progress: dict[str, float] = {}
    jobs = [
        Job("square", square, (7,)),
        Job("bad", broken, ("in a child",)),
        Job("killed", die),
        Job("pid-a", pid_after, (0.5,)),
        Job("pid-b", pid_after, (0.5,)),
    ]
    outcome = run_jobs(jobs, LocalProcessExecutor(2), on_progress=progress.__setitem__)
    assert outcome.results["square"] == 49 and progress == {"square": 7}
    assert isinstance(outcome.failures["bad"], ValueError)  # the child's own error, re-created here
    assert (
        outcome.failure_message("killed") == f"RuntimeError: its process exited with code {-signal.SIGKILL}"
    )
    # The others ran to the end in child processes (not this one), a dead one being replaced.
    assert {"pid-a", "pid-b"} <= set(outcome.results) and os.getpid() not in outcome.results.values()


def checkpoint_on_sigterm(folder: str) -> int:
    """A long job that, like ``train_agent``, turns SIGTERM into saving a checkpoint and stopping."""
    from sb3_hddpg.training.training import sigterm_as_interrupt

    with sigterm_as_interrupt():
        try:
            (Path(folder) / f"started-{os.getpid()}").touch()
            time.sleep(120)
        except KeyboardInterrupt:
            (Path(folder) / f"checkpoint-{os.getpid()}").touch()
            raise
    return 0


@pytest.mark.slow  # spawns processes that import torch
def test_sigterm_to_the_parent_makes_running_jobs_checkpoint_and_stop(tmp_path):
    jobs = [Job(f"long-{i}", checkpoint_on_sigterm, (str(tmp_path),)) for i in range(3)]

    def sigterm_once_two_started() -> None:
        deadline = time.monotonic() + 120
        while len(list(tmp_path.glob("started-*"))) < 2 and time.monotonic() < deadline:
            time.sleep(0.1)
        os.kill(os.getpid(), signal.SIGTERM)

    handler = signal.getsignal(signal.SIGTERM)
    threading.Thread(target=sigterm_once_two_started, daemon=True).start()
    started = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        run_jobs(jobs, LocalProcessExecutor(2))
    assert time.monotonic() - started < 100  # nobody waited for the 120 s jobs
    # The two running jobs saved their checkpoints; the third never started; no process is left.
    started_pids = {p.name.split("-")[1] for p in tmp_path.glob("started-*")}
    assert len(started_pids) == 2
    assert {p.name.split("-")[1] for p in tmp_path.glob("checkpoint-*")} == started_pids
    assert not [p for p in multiprocessing.active_children() if p.name.startswith("job-")]
    assert signal.getsignal(signal.SIGTERM) is handler  # the parent's handler is restored

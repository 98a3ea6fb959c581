"""
One process runner for the commands that fan out independent runs: ``benchmark``, ``tune --n-jobs`` and
``quickstart``.

A :class:`Job` is a module-level function with its arguments, a key, a cost and the keys it runs after.
:func:`run_jobs` schedules them on an :class:`Executor`, which says where they run:

- :class:`LocalProcessExecutor`: ``n_jobs`` spawned processes on this machine, one torch thread each (or the
  job's ``threads``), each reused for the next job like a process pool; a process that dies fails its job
  only, and is replaced;
- :class:`InlineExecutor`: in this process, one job at a time (the same code path without processes, handy
  for debugging and profiling).
- :class:`~hddpg_zoo.ray_executor.RayExecutor` (its own module, Ray being optional): each job a
  Ray task on an existing cluster.

An executor implements four methods: ``open``, ``submit``, ``wait``, ``stop``;
:func:`~hddpg_zoo.executors.make_executor` picks one from a command's options.

**Scheduling.** A job runs once every job it runs ``after`` has finished (and fails without running when one
of them failed); ready jobs go group by group (e.g. seed by seed, so that an interrupted benchmark holds
complete seeds) and, within a group, longest (by ``cost``) first (the LPT rule: the jobs left at the end are
short, so no process idles long).

**Interruption.** Ctrl-C or SIGTERM (turned into ``KeyboardInterrupt`` for the duration) stops the scheduler:
running jobs get ``interrupt_grace`` seconds to stop on their own (a terminal's Ctrl-C reaches them too), are
then sent SIGTERM (which :func:`~sb3_hddpg.training.agent.train_agent` turns into a checkpoint and exit),
and the interrupt is re-raised once they have left; their checkpoints make the run resumable.

**Failures** are reported per job (the error, its traceback logged once): one failed job does not stop the
others, unless ``fail_fast``.

**Progress.** Inside a job, :func:`report_progress` sends a number (e.g. steps done) to the parent's
``on_progress(key, value)``.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import multiprocessing.connection
import queue as queue_module
import time
import traceback
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess
from multiprocessing.queues import Queue
from typing import Any, Protocol

import torch

from sb3_hddpg.training.agent import TrainingInterrupted, sigterm_as_interrupt

logger = logging.getLogger(__name__)

#: Seconds between looks at the progress of running jobs.
POLL_INTERVAL = 0.25


@dataclass(frozen=True)
class Job:
    """
    One unit of work, run in a process of its own (with a spawning executor).

    :param key: its name among the jobs of a run (unique).
    :param fn: what runs: a module-level function (or a ``functools.partial`` of one), so that a spawned
        process can import it.
    :param args: its positional arguments (picklable).
    :param kwargs: its keyword arguments (picklable).
    :param cost: its expected size (e.g. env steps): larger jobs of a group start first.
    :param group: jobs of a lower group start first.
    :param after: keys of the jobs it needs finished first.
    :param threads: torch threads of its process.
    """

    key: str
    fn: Callable[..., Any]
    args: tuple[object, ...] = ()
    kwargs: Mapping[str, object] = field(default_factory=dict)
    cost: float = 0.0
    group: int = 0
    after: tuple[str, ...] = ()
    threads: int = 1


@dataclass(frozen=True)
class Finished:
    """
    A job's end, as an executor reports it.

    :param key: the job's key.
    :param ok: it returned ``value``; otherwise ``value`` is the error it raised.
    :param value: what it returned, or the exception.
    :param details: the error's traceback (empty when it returned).
    """

    key: str
    ok: bool
    value: object
    details: str = ""


@dataclass
class RunOutcome:
    """
    What :func:`run_jobs` produced.

    :param results: key -> value of every job that returned.
    :param failures: key -> the error of every job that failed (or was not run because one it needs failed).
    """

    results: dict[str, Any] = field(default_factory=dict)
    failures: dict[str, BaseException] = field(default_factory=dict)

    def failure_message(self, key: str) -> str:
        """``Type: message`` of a failed job's error."""
        return describe(self.failures[key])


class Executor(Protocol):
    """Where jobs run. :func:`run_jobs` calls ``open`` once, then ``submit``/``wait``, then ``stop`` once."""

    #: Jobs it runs at a time.
    slots: int

    def open(self, on_progress: Callable[[str, float], None]) -> None:
        """Get ready; ``on_progress(key, value)`` receives the jobs' :func:`report_progress` calls."""

    def submit(self, job: Job) -> None:
        """Start a job (at most ``slots`` are running)."""

    def wait(self, timeout: float) -> list[Finished]:
        """The jobs that ended within ``timeout`` seconds (relaying progress meanwhile)."""

    def stop(self, interrupted: bool) -> None:
        """
        Release everything. ``interrupted``: the run was interrupted, so stop running jobs the resumable way
        (see the module docstring) before returning.
        """


def describe(error: BaseException) -> str:
    """An error as one line, ``Type: message``."""
    return f"{type(error).__name__}: {error}"


# ------------------------------------------------------------------------------------------- the scheduler
def run_jobs(
    jobs: Iterable[Job],
    executor: Executor,
    on_event: Callable[[str, Job, Any], None] | None = None,
    on_progress: Callable[[str, float], None] | None = None,
    fail_fast: bool = False,
) -> RunOutcome:
    """
    Run jobs on ``executor`` in dependency and priority order (see the module docstring) until all ended.

    :param jobs: the jobs (keys unique; ``after`` names keys among them).
    :param executor: where they run.
    :param on_event: called with ``("start" | "done" | "failed", job, value or error)``.
    :param on_progress: called with ``(key, value)`` for each :func:`report_progress` of a running job.
    :param fail_fast: re-raise the first failure (after stopping the running jobs) instead of going on.
    :return: every job's result or error.
    """
    pending = {job.key: job for job in jobs}
    unknown = {dep for job in pending.values() for dep in job.after} - set(pending)
    if unknown:
        raise ValueError(f"Jobs run after unknown jobs: {sorted(unknown)}")
    notify = on_event or (lambda kind, job, value: None)
    outcome = RunOutcome()
    running: dict[str, Job] = {}

    def fail(job: Job, error: BaseException) -> None:
        outcome.failures[job.key] = error
        notify("failed", job, error)

    def schedule() -> None:
        # A job after a failed one fails too, and so on down the chain.
        while blocked := [j for j in pending.values() if any(d in outcome.failures for d in j.after)]:
            for job in blocked:
                del pending[job.key]
                dep = next(d for d in job.after if d in outcome.failures)
                fail(job, RuntimeError(f"{dep} failed: {outcome.failure_message(dep)}"))
        ready = [j for j in pending.values() if all(d in outcome.results for d in j.after)]
        for job in sorted(ready, key=lambda j: (j.group, -j.cost))[: executor.slots - len(running)]:
            del pending[job.key]
            running[job.key] = job
            notify("start", job, None)
            executor.submit(job)

    executor.open(on_progress or (lambda key, value: None))
    interrupted = True
    try:
        with sigterm_as_interrupt():
            schedule()
            while running:
                for end in executor.wait(POLL_INTERVAL):
                    job = running.pop(end.key)
                    if end.ok:
                        outcome.results[job.key] = end.value
                        notify("done", job, end.value)
                        continue
                    # An executor reports a failed job's exception; anything else is wrapped as one.
                    error = (
                        end.value if isinstance(end.value, BaseException) else RuntimeError(repr(end.value))
                    )
                    if not isinstance(error, (TrainingInterrupted, KeyboardInterrupt)):
                        # a job stopped by Ctrl-C or SIGTERM did not fail: the command says so in one line
                        logger.error("job %s failed: %s\n%s", job.key, describe(error), end.details)
                    fail(job, error)
                    if fail_fast:
                        raise error
                schedule()
            interrupted = False
    finally:
        executor.stop(interrupted)
    return outcome


# -------------------------------------------------------------------------------------- inside a job
_reporter: Callable[[float], None] | None = None


def report_progress(value: float) -> None:
    """From inside a running job: send ``value`` (e.g. steps done) to the run's ``on_progress``."""
    if _reporter is not None:
        _reporter(value)


@contextlib.contextmanager
def reporting_to(reporter: Callable[[float], None]) -> Iterator[None]:
    """Inside a job's process (for another executor, e.g. Ray's): send its :func:`report_progress` to ``reporter``."""
    global _reporter
    previous, _reporter = _reporter, reporter
    try:
        yield
    finally:
        _reporter = previous


def _call(job: Job) -> Finished:
    """Run ``job`` here, catching what it raises (not interrupts: those stop the run)."""
    try:
        return Finished(job.key, True, job.fn(*job.args, **job.kwargs))
    except Exception as error:
        return Finished(job.key, False, error, traceback.format_exc())


# ------------------------------------------------------------------------------------------- in-process
class InlineExecutor:
    """Runs each job in this process when submitted: one at a time, no processes, the same results."""

    slots = 1

    def __init__(self) -> None:
        self._ended: list[Finished] = []

    def open(self, on_progress: Callable[[str, float], None]) -> None:
        self._on_progress = on_progress

    def submit(self, job: Job) -> None:
        global _reporter
        _reporter = lambda value: self._on_progress(job.key, value)  # noqa: E731
        try:
            self._ended.append(_call(job))
        finally:
            _reporter = None

    def wait(self, timeout: float) -> list[Finished]:
        ended, self._ended = self._ended, []
        return ended

    def stop(self, interrupted: bool) -> None:
        self._ended = []


# ------------------------------------------------------------------------------------------- processes
def _process_main(connection: Connection, progress: Queue[tuple[str, float]]) -> None:
    """A spawned process: run the jobs it is sent, one at a time, until told to stop (``None``)."""
    global _reporter
    with contextlib.suppress(KeyboardInterrupt, EOFError):  # Ctrl-C while idle, or the parent gone
        while (job := connection.recv()) is not None:
            torch.set_num_threads(job.threads)
            _reporter = lambda value, key=job.key: progress.put((key, value))  # noqa: E731
            end = _call(job)
            try:
                connection.send(end)
            except Exception as error:  # a result or error that does not pickle
                connection.send(Finished(job.key, False, RuntimeError(describe(error)), end.details))


@dataclass
class _Slot:
    process: BaseProcess
    connection: Connection
    job: Job | None = None


class LocalProcessExecutor:
    """
    ``n_jobs`` spawned processes on this machine (spawn, not fork: the parent has torch loaded, and forked
    torch processes can deadlock; a forked child would also share the parent's database connections).

    :param n_jobs: processes at a time.
    :param interrupt_grace: on an interrupt, seconds running jobs get to stop on their own before they are
        sent SIGTERM (``None``: wait for them however long they take).
    """

    def __init__(self, n_jobs: int, interrupt_grace: float | None = 0.0) -> None:
        if n_jobs < 1:
            raise ValueError(f"Expected `n_jobs` >= 1, actually: {n_jobs}")
        self.slots = n_jobs
        self.interrupt_grace = interrupt_grace
        self._context = multiprocessing.get_context("spawn")
        self._slots: list[_Slot] = []

    def open(self, on_progress: Callable[[str, float], None]) -> None:
        self._on_progress = on_progress
        self._progress = self._context.Queue()

    def submit(self, job: Job) -> None:
        slot = next((s for s in self._slots if s.job is None and s.process.is_alive()), None)
        if slot is None:
            self._slots = [s for s in self._slots if s.process.is_alive()]
            parent, child = self._context.Pipe()
            process = self._context.Process(
                target=_process_main, args=(child, self._progress), name=f"job-{len(self._slots)}"
            )
            process.start()
            child.close()
            slot = _Slot(process, parent)
            self._slots.append(slot)
        slot.job = job
        slot.connection.send(job)

    def wait(self, timeout: float) -> list[Finished]:
        busy = [s for s in self._slots if s.job is not None]
        handles = [s.connection for s in busy] + [s.process.sentinel for s in busy]
        ready = set(multiprocessing.connection.wait(handles, timeout))
        self._relay_progress()
        ended = []
        for slot in busy:
            if slot.connection not in ready and slot.process.sentinel not in ready:
                continue
            job, slot.job = slot.job, None
            assert job is not None
            try:
                ended.append(slot.connection.recv())
            except (EOFError, OSError):  # the process died without an answer (killed, crashed)
                slot.process.join()
                error = RuntimeError(f"its process exited with code {slot.process.exitcode}")
                ended.append(Finished(job.key, False, error))
        return ended

    def _relay_progress(self) -> None:
        while True:
            try:
                key, value = self._progress.get_nowait()
            except queue_module.Empty:
                return
            self._on_progress(key, value)

    def stop(self, interrupted: bool) -> None:
        for slot in self._slots:
            with contextlib.suppress(OSError):
                slot.connection.send(None)  # queued behind a running job: its process leaves after it
        if interrupted:
            self._stop_running()
        for slot in self._slots:
            while slot.process.is_alive():
                # Read (and drop) what a job stopped by the interrupt still sends, so that it cannot block
                # on a full pipe.
                with contextlib.suppress(EOFError, OSError):
                    if slot.connection.poll(POLL_INTERVAL):
                        slot.connection.recv()
            slot.process.join()
            slot.connection.close()
        self._slots = []
        self._progress.close()

    def _stop_running(self) -> None:
        """Give running jobs ``interrupt_grace`` seconds to stop on their own, then SIGTERM them."""
        if self.interrupt_grace is None:
            return
        deadline = time.monotonic() + self.interrupt_grace
        for slot in [s for s in self._slots if s.job is not None]:
            slot.process.join(max(0.0, deadline - time.monotonic()))
            if slot.process.is_alive():
                slot.process.terminate()

"""
What a running ``hddpg-cli benchmark`` says and does as its tasks end: a line per event with the progress and
time left, and with ``--snapshot`` a snapshot of its finished seeds each time a seed's last run finishes.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hddpg_zoo.benchmark import BenchmarkSettings, Task, plan_tasks, read_record
from hddpg_zoo.benchmark.benchmark_file import read_benchmark_file
from hddpg_zoo.benchmark.progress import Progress
from hddpg_zoo.snapshot import check_destination, snapshot_benchmark
from sb3_hddpg.artifacts.io import FolderLockedError
from sb3_hddpg.cli.app import console
from sb3_hddpg.cli.options import usage_errors
from sb3_hddpg.metric_labels import metric_label

#: What a benchmark calls on each task event: ``(kind, task, record or None)``.
EventHandler = Callable[[str, Task, dict[str, Any] | None], None]


def seeds_text(seeds: tuple[int, ...]) -> str:
    """Seeds as a user reads them: ``"0, 1, 2"``, or ``"none"``."""
    return ", ".join(str(seed) for seed in seeds) or "none"


def event_printer(settings: BenchmarkSettings, n_jobs: int | None, ray_address: str | None) -> EventHandler:
    """
    One line per task event (started, kept, failed, finished), stamped with the minutes since now; a
    finished run's line ends with the benchmark's progress and, run locally or on ``n_jobs`` Ray tasks, its
    estimated time left.
    """
    started = time.perf_counter()
    jobs = n_jobs or (1 if ray_address is None else None)  # a whole Ray cluster: its size is not known here
    progress = Progress(settings, jobs or 1)

    def event(kind: str, task: Task, record: dict[str, Any] | None) -> None:
        elapsed = time.perf_counter() - started
        stamp = f"[dim]{elapsed / 60:6.1f} min[/]"
        if record is not None:
            progress.finished(task, record)
        if kind == "start":
            console.print(f"{stamp} started  {task.label}")
        elif kind == "skip":
            console.print(f"{stamp} [dim]kept     {task.label} (finished earlier)[/]")
        elif kind == "failed":
            console.print(f"{stamp} [red]failed   {task.label}[/] (see the log above; --resume retries)")
        elif record is not None:
            score = record.get("test", {}).get("mean_reach_reward")
            detail = (
                f"test {metric_label('mean_reach_reward').short} {score:.1f}"
                if score is not None
                else "workers trained"
            )
            wall, total = record["wall_time_s"], record["wall_time_s_total"]
            # A task resumed after an interruption: its time in this invocation, and in all of them.
            spent = f"{wall:.0f} s" + (f", {total:.0f} s in all" if total - wall >= 1 else "")
            shown = progress.summary() if jobs is not None else f"{progress.done}/{progress.total} runs done"
            console.print(f"{stamp} [green]finished[/] {task.label}: {detail} ({spent}); [dim]{shown}[/]")

    return event


def check_snapshot_option(settings: BenchmarkSettings, out: Path, dest: Path | None, resume: bool) -> None:
    """Refuse, as a usage error before anything runs, a ``--snapshot`` folder the benchmark may not fill."""
    if dest is None:
        return
    with usage_errors("'--snapshot'"):
        header = out / "benchmark.json"
        invocations = (
            read_benchmark_file(header).get("invocations", []) if resume and header.is_file() else []
        )
        check_destination(out, dest, settings, invocations)


def snapshotting(
    handler: EventHandler, out: Path, dest: Path | None, settings: BenchmarkSettings
) -> EventHandler:
    """``handler``, and with a ``--snapshot`` folder a snapshot each time a seed's last run finishes."""
    if dest is None:
        return handler
    tasks = plan_tasks(settings)

    def event(kind: str, task: Task, record: dict[str, Any] | None) -> None:
        handler(kind, task, record)
        seed_tasks = [t for t in tasks if t.seed == task.seed]
        if kind == "done" and all(read_record(out, t) is not None for t in seed_tasks):
            take_snapshot(out, dest)

    return event


def take_snapshot(out: Path, dest: Path) -> None:
    """
    Snapshot a benchmark's finished seeds into ``dest`` and say so; a snapshot that fails is said too, and
    the benchmark goes on: its own folder keeps every run, and the next snapshot takes them.
    """
    try:
        snapshot = snapshot_benchmark(out, dest)
    except (OSError, ValueError, FolderLockedError) as error:
        console.print(f"[yellow]snapshot into {dest} failed[/]: {error}")
        return
    console.print(f"[dim]snapshot: finished seeds {seeds_text(snapshot.seeds)} in {dest}[/]")

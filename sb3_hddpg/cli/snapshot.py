"""``hddpg-cli snapshot RUN DEST``: a benchmark's finished seeds in a compact folder that resumes anywhere."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import typer

from sb3_hddpg.artifacts.io import FolderLockedError
from sb3_hddpg.cli.app import app, console
from sb3_hddpg.cli.options import usage_errors
from sb3_hddpg.experiments.benchmark import BenchmarkSettings, Task, plan_tasks, read_record
from sb3_hddpg.experiments.benchmark.benchmark_file import read_benchmark_file
from sb3_hddpg.experiments.snapshot import check_destination, snapshot_benchmark

#: What a benchmark calls on each task event: ``(kind, task, record or None)``.
EventHandler = Callable[[str, Task, dict[str, Any] | None], None]


def _seeds_text(seeds: tuple[int, ...]) -> str:
    return ", ".join(str(seed) for seed in seeds) or "none"


@app.command("snapshot")
def snapshot_command(
    run: Path = typer.Argument(
        ..., help="A benchmark folder (the --out of hddpg-cli benchmark), even a running one."
    ),
    dest: Path = typer.Argument(
        ..., help="The snapshot's folder: new, empty, or an earlier snapshot of the same benchmark."
    ),
    per_preference: bool = typer.Option(
        False,
        "--per-preference-models",
        help="Copy the front's managers trained for one preference each too (their records are always copied).",
    ),
) -> None:
    """
    Copy the seeds of RUN whose every run has finished into DEST: their records, final models (with
    index.json, as export-models writes them) and the workers' learning curves, then benchmark.json; no
    checkpoints or logs. DEST resumes the benchmark on any machine (hddpg-cli benchmark ... --out DEST
    --resume), serves --workers-from and is an export; taken again, the snapshot adds what finished since.
    """
    with usage_errors("'RUN'"):
        if not (run / "benchmark.json").is_file():
            raise FileNotFoundError(f"not a benchmark folder (no benchmark.json): {str(run)!r}")
    with usage_errors():
        snapshot = snapshot_benchmark(run, dest, per_preference=per_preference)
    console.print(
        f"Snapshot of {run} in {snapshot.folder}: {len(snapshot.copied)} runs copied, {snapshot.models} models "
        f"in its index.json; finished seeds: {_seeds_text(snapshot.seeds)}; not finished: "
        f"{_seeds_text(snapshot.pending)}"
    )


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
    console.print(f"[dim]snapshot: finished seeds {_seeds_text(snapshot.seeds)} in {dest}[/]")

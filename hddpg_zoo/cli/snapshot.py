"""``hddpg-cli snapshot RUN DEST``: a benchmark's finished seeds in a compact folder that resumes anywhere."""

from __future__ import annotations

from pathlib import Path

import typer

from hddpg_zoo.cli.benchmark_events import seeds_text
from hddpg_zoo.snapshot import snapshot_benchmark
from sb3_hddpg.cli.app import app, console
from sb3_hddpg.cli.options import usage_errors


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
        help="Copy the front's managers trained for one preference each too (their records are always copied), "
        "for the seeds copied this time.",
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
        f"in its index.json; finished seeds: {seeds_text(snapshot.seeds)}; not finished: "
        f"{seeds_text(snapshot.pending)}"
    )

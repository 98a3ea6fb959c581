"""``hddpg-cli grow``: a support of workers grown where the front gains most (optimistic linear support)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from sb3_hddpg.cli.app import app, console
from sb3_hddpg.cli.options import (
    ResumeOpt,
    run_options_of,
    takes_options,
    usage_errors,
)
from sb3_hddpg.cli.train import training_interrupt_exits
from sb3_hddpg.training.grow import SUPPORT_FILE, SupportOptions, check_growable, grow

_GrowWorkersOpt = Annotated[
    Path,
    typer.Option(
        "--workers",
        help="Run folder of train-workers holding a per-term worker with its critic for every term; the new "
        "workers are added to it.",
    ),
]
_SupportOpt = Annotated[
    int, typer.Option("--support", help="The most workers the support holds, per-term ones included.")
]
_BudgetOpt = Annotated[int, typer.Option("--budget", help="Env steps all new workers may train together.")]
_ToleranceOpt = Annotated[
    float,
    typer.Option(
        "--tolerance",
        help="Stop when the largest optimistic gain is below this fraction of the front's value.",
    ),
]
_StartStatesOpt = Annotated[
    int, typer.Option("--start-states", help="Development episodes whose start states value each worker.")
]
_ConfigOpt = Annotated[
    Path | None,
    typer.Option(
        "--config",
        help="Hyperparameters in RL Zoo format for the new workers (block <env>/mix, else the env's).",
    ),
]


@app.command("grow")
@takes_options("seed", "n_envs", "eval_freq", "eval_episodes", "checkpoint_freq", "threads", "progress_bar")
def grow_command(
    context: typer.Context,
    workers: _GrowWorkersOpt = Path("runs/workers"),
    support: _SupportOpt = 4,
    budget: _BudgetOpt = 150_000,
    tolerance: _ToleranceOpt = 0.01,
    start_states: _StartStatesOpt = 32,
    config: _ConfigOpt = None,
    resume: ResumeOpt = False,
) -> None:
    """Add workers on weightings of the terms where the front gains most (optimistic linear support), each warm-started from its nearest neighbour."""
    with usage_errors("'--support'"):
        options = SupportOptions(support, budget, tolerance, start_states)
    if not (workers / "workers" / "manifest.json").is_file() and not (workers / "manifest.json").is_file():
        raise typer.BadParameter(
            f"no workers manifest in {str(workers)!r}; run train-workers first", param_hint="'--workers'"
        )
    root = workers if (workers / "workers" / "manifest.json").is_file() else workers.parent
    run = run_options_of(context)
    with usage_errors("'--workers'"):  # before anything trains; a failure while training is no usage error
        check_growable(root, resume)
    with training_interrupt_exits():
        record = grow(root, options, run=run, config=config)
    table = Table(title=f"Support in {root / 'workers'}")
    for column in ("worker", "weights", "gain", "env steps", "warm start"):
        table.add_column(column)
    for step in record.added:
        weights = ", ".join(f"{t}={w:.3g}" for t, w in step.weights.items())
        table.add_row(step.name, weights, f"{step.gain:.4g}", str(step.steps), step.warm_start or "-")
    console.print(table)
    console.print(f"Stopped: {record.stopped}.  Record: {root / 'workers' / SUPPORT_FILE}")

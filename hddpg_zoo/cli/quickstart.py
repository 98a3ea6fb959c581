"""``hddpg-cli quickstart``: the main job. Workers, manager and baselines on a small budget, compared."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TaskID, TextColumn, TimeElapsedColumn
from rich.table import Table

from hddpg_zoo.cli.options import ExecutorOpt, ExperimentBackendOpt, RayAddressOpt, cluster_address
from hddpg_zoo.quickstart import (
    BUDGETS,
    MAIN_HIERARCHY,
    PAPER_HIERARCHY,
    STAGES,
    QuickstartObserver,
    QuickstartResult,
    run_quickstart,
)
from sb3_hddpg.cli.app import app, console
from sb3_hddpg.cli.options import ForceOpt, count, prepare_out_dir, seed_range
from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID
from sb3_hddpg.evaluation import EVAL_SEED_BASE
from sb3_hddpg.metric_labels import (
    SELECTION_LABEL,
    MetricLabel,
    manager_warnings,
    metric_label,
    units_caption,
)

#: The training budget column: every agent's in env steps (a manager's decisions run several each).
TRAIN_STEPS = MetricLabel("training", "env steps", digits=0, short="trained")


class _RichObserver(QuickstartObserver):
    """An overall bar over the stages, and one bar per task of the current stage."""

    def __init__(self, progress: Progress) -> None:
        self.progress = progress
        self.overall = progress.add_task("[bold]quickstart", total=len(STAGES), unit="stage")
        self.tasks: dict[str, TaskID] = {}
        self.stage = -1
        self.stage_tasks: list[str] = []

    def on_stage(self, index: int, name: str) -> None:
        self.stage = index
        self.stage_tasks = []
        self.progress.update(
            self.overall, completed=index, description=f"[bold]{index + 1}/{len(STAGES)} {name}"
        )

    def on_task(self, task: str, completed: float, total: float) -> None:
        if task not in self.tasks:
            self.tasks[task] = self.progress.add_task(f"  {task}", total=total)
            self.stage_tasks.append(task)
        self.progress.update(self.tasks[task], completed=completed, total=total)
        # The overall bar moves inside a stage by the mean progress of the stage's tasks.
        fractions = [
            self.progress.tasks[self.tasks[t]].percentage / 100 for t in self.stage_tasks if t in self.tasks
        ]
        if fractions:
            self.progress.update(self.overall, completed=self.stage + sum(fractions) / len(fractions))

    def on_message(self, message: str) -> None:
        self.progress.console.print(f"[green]✓[/] {message}")

    def finish(self) -> None:
        self.progress.update(self.overall, completed=len(STAGES), description="[bold]quickstart done")


def comparison_table(result: QuickstartResult) -> Table:
    """The methods on the shared seeds, one row each, each column in one unit."""

    summary = next(iter(result.summaries.values()))
    episodes = summary["episodes"]
    # The closest approach to an obstacle is in results.json; the table keeps to what fits a terminal
    # (80 columns: short headers, their units in the caption).
    keys = ("mean_reach_reward", "goal_touch_rate", "collisions_per_episode", "success_rate")
    labels = [metric_label(key) for key in keys]
    table = Table(
        title=f"{SNAKE_REACH_ENV_ID}: each method's saved model, mean ± std over the same {episodes} episodes "
        f"(seeds {EVAL_SEED_BASE}..{EVAL_SEED_BASE + episodes - 1})",
        caption=f"{units_caption([*labels, SELECTION_LABEL, TRAIN_STEPS])}. {labels[0].short}: "
        f"{labels[0].label}, the snake's reach reward. {MAIN_HIERARCHY}: a DQN manager choosing a worker by "
        f"state, started from HAM's switch, told the preference (here goal=1,avoid=1; any other with "
        f"evaluate --preference); "
        f"{PAPER_HIERARCHY}: the paper's simplex DDPG manager",
    )
    table.add_column("method")
    for label in labels:
        table.add_column(label.short or label.label, justify="right", overflow="fold")
    table.add_column(SELECTION_LABEL.short)
    table.add_column(TRAIN_STEPS.short, justify="right")
    for name, s in result.summaries.items():
        cells = [metric_label(key).format(s[key]) for key in keys]
        cells[0] += f" ± {metric_label(keys[0]).format(s['std_reach_reward'])}"
        rates = s.get("selection_rate", {})
        steps = result.methods[name]["train_timesteps"]
        table.add_row(
            name,
            *cells,
            " / ".join(f"{n} {100 * r:.0f}" for n, r in rates.items()) or "-",
            f"{steps:,}" if steps else "-",
        )
    return table


@app.command("quickstart")
def quickstart_command(
    context: typer.Context,
    out: Path = typer.Option(
        Path("runs/quickstart"),
        "--out",
        help="Run folder (with --force, an earlier quickstart's is replaced).",
    ),
    budget: str = typer.Option(
        "small", "--budget", help="small (about 10 min on 2 CPU cores) or tiny (seconds; for tests)."
    ),
    seed: int = typer.Option(0, "--seed", callback=seed_range, help="Training seed of every agent."),
    force: ForceOpt = False,
    processes: int = typer.Option(
        2, "--processes", callback=count("processes"), help="Agents trained at a time, one process each."
    ),
    keep_checkpoints: bool = typer.Option(
        False,
        "--keep-checkpoints",
        help="Keep every agent's replay buffer in RUN/checkpoints/ (about 275 MB in all at --budget small) "
        "so that train-* --resume can extend an agent exactly; by default the run folder is about 31 MB.",
    ),
    backend: ExperimentBackendOpt = "sb3",
    executor: ExecutorOpt = "local",
    ray_address: RayAddressOpt = None,
) -> None:
    """Train both workers, a manager, a flat DDPG (and HAM), compare them on the same seeds, save everything."""
    if budget not in BUDGETS:
        raise typer.BadParameter(f"must be one of {list(BUDGETS)}, got {budget!r}", param_hint="'--budget'")
    address = cluster_address(executor, ray_address)
    prepare_out_dir(context, out, resume=False, force=force)
    console.print(
        f"Run folder: [bold]{out}[/]  (budget {budget}, seed {seed}, {processes} processes, backend {backend}"
        + (f", on the Ray cluster at {address})" if address else ")")
    )
    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=console,
        transient=False,
    ) as progress:
        observer = _RichObserver(progress)
        result = run_quickstart(
            out,
            budget=budget,
            seed=seed,
            processes=processes,
            observer=observer,
            keep_checkpoints=keep_checkpoints,
            backend=backend,
            ray_address=address,
        )
        observer.finish()
    console.print(comparison_table(result))
    for name, summary in result.summaries.items():
        for warning in manager_warnings(summary):
            console.print(f"[yellow]{name}[/]: {warning}")
    # One seed at a quickstart budget says little about the method; say where the real comparison is.
    console.print(
        "One seed at a small budget: a check that the pipeline works, not a comparison of the methods. "
        "The 10-seed run of record at the full budget (the hierarchies against HAM, hand-written skills, "
        "each worker alone and flat agents, on test episodes no choice used, with rliable's intervals) is in "
        "docs/RESULTS.md; run it with hddpg-cli benchmark."
    )
    for label in ("bundle", "paper_bundle", "gif", "selection", "comparison", "learning_curves", "results"):
        if label in result.files:
            console.print(f"  {label:16} {result.files[label]}")
    console.print(f"Done in {result.wall_seconds / 60:.1f} min. Everything is in [bold]{result.run_dir}[/]")

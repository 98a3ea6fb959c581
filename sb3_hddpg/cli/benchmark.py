"""``hddpg-cli benchmark``: HDDPG against HAM and flat agents over several seeds (paper Section 3.3-3.4)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import typer
from rich.table import Table

from sb3_hddpg.benchmark import (
    DEFAULT_METHODS,
    METHODS,
    OUTPUT_FILES,
    BenchmarkSettings,
    Task,
    run_benchmark,
)
from sb3_hddpg.cli.app import app, console
from sb3_hddpg.cli.options import (
    BACKEND_HELP,
    at_least,
    backend_name,
    positive_float,
    prepare_out_dir,
    usage_errors,
)


def _ci(stats: dict[str, Any], fmt: str = ".1f") -> str:
    return f"{stats['mean']:{fmt}} [{stats['ci_low']:{fmt}}, {stats['ci_high']:{fmt}}]"


def results_table(results: dict[str, Any]) -> Table:
    """The per-method table: final test metrics and learning-curve statistics, mean [95 % CI] over seeds."""
    table = Table(
        title=(
            f"Benchmark: mean [95 % bootstrap CI] over seeds; test episodes from seed {results['test_seeds'][0]}; "
            f"curve window {results['curve_window']} own steps"
        )
    )
    columns = (
        "method",
        "seeds",
        "reach reward (test)",
        "IQM",
        "goal touch",
        "collisions/ep",
        "success",
        "min clearance",
        "curve mean",
        f"slope /{results['slope_unit_steps']} steps",
    )
    for column in columns:
        table.add_column(column, justify="left" if column == "method" else "right")
    for method, entry in results["methods"].items():
        s = entry["stats"]
        table.add_row(
            method,
            str(len(entry["seeds"])),
            _ci(s["mean_reach_reward"]),
            f"{s['mean_reach_reward']['iqm']:.1f}",
            _ci(s["goal_touch_rate"], ".1%"),
            _ci(s["collisions_per_episode"], ".2f"),
            _ci(s["success_rate"], ".0%"),
            f"{s['min_clearance']['mean']:.3f}",
            _ci(s["curve_mean"]),
            _ci(s["slope"], ".2f"),
        )
    return table


def comparisons_table(results: dict[str, Any]) -> Table:
    """The paired comparisons: difference [95 % CI], relative gain, probability of improvement."""
    table = Table(title="Paired comparisons over common seeds (A - B)")
    for column in ("A vs B", "metric", "difference [95 % CI]", "relative", "P(A > B)"):
        table.add_column(column, justify="left" if column in ("A vs B", "metric") else "right")
    for pair, comparison in results["comparisons"].items():
        for metric in ("mean_reach_reward", "curve_mean", "slope"):
            c = comparison[metric]
            relative = f"{c['relative_gain']:+.1%}" if c["relative_gain"] is not None else "-"
            table.add_row(
                pair,
                metric,
                f"{c['difference']:+.2f} [{c['ci_low']:+.2f}, {c['ci_high']:+.2f}]",
                relative,
                f"{c['probability_of_improvement']:.2f}",
            )
    return table


@app.command("benchmark")
def benchmark_command(
    methods: str = typer.Option(
        ",".join(DEFAULT_METHODS), "--methods", help=f"Comma-separated methods among {list(METHODS)}."
    ),
    seeds: int = typer.Option(
        5, "--seeds", callback=at_least(1), help="Seeds 0..N-1, one run per method each."
    ),
    timesteps: int = typer.Option(
        10_000, "--timesteps", callback=at_least(1), help="Manager steps (the curve window of every method)."
    ),
    worker_timesteps: int = typer.Option(
        10_000, "--worker-timesteps", callback=at_least(1), help="Steps per worker (trained once per seed)."
    ),
    flat_timesteps: int | None = typer.Option(
        None,
        "--flat-timesteps",
        callback=at_least(1),
        help="Flat agents' steps (default: --timesteps + 2 x --worker-timesteps, the hierarchy's total).",
    ),
    eval_freq: int | None = typer.Option(
        None,
        "--eval-freq",
        callback=at_least(1),
        help="Steps between curve evaluations of every run (default: --timesteps / 10).",
    ),
    eval_episodes: int = typer.Option(
        5, "--eval-episodes", callback=at_least(1), help="Episodes per learning-curve evaluation."
    ),
    test_episodes: int = typer.Option(
        20, "--test-episodes", callback=at_least(1), help="Episodes of the final test evaluation."
    ),
    ham_threshold: float | None = typer.Option(
        None,
        "--ham-threshold",
        help="HAM's threshold on the summed joint-obstacle distances (default: n_joints - 0.5).",
    ),
    ham_hysteresis: float = typer.Option(0.0, "--ham-hysteresis", help="HAM's hysteresis (>= 0)."),
    bias: float = typer.Option(
        0.15, "--bias", callback=positive_float, help="The biased managers' extra preference factor."
    ),
    n_jobs: int = typer.Option(
        1, "--n-jobs", callback=at_least(1), help="Runs in parallel (one process each)."
    ),
    out: Path = typer.Option(Path("runs/benchmark"), "--out", help="Benchmark folder."),
    resume: bool = typer.Option(False, "--resume", help="Keep finished runs and continue interrupted ones."),
    force: bool = typer.Option(False, "--force", help="Overwrite a folder that already holds results."),
    backend: str = typer.Option(
        "sb3", "--backend", callback=backend_name, help=BACKEND_HELP.split(" Default:")[0] + " Default: sb3."
    ),
) -> None:
    """Train and evaluate every method on every seed; write results.json, evaluations.csv and plots."""
    chosen = [m.strip() for m in methods.split(",") if m.strip()]
    unknown = [m for m in chosen if m not in METHODS]
    if unknown or not chosen:
        raise typer.BadParameter(
            f"unknown method {unknown[0] if unknown else methods!r}; choose from {list(METHODS)}",
            param_hint="'--methods'",
        )
    if ham_hysteresis < 0:
        raise typer.BadParameter(f"must be >= 0, got {ham_hysteresis}", param_hint="'--ham-hysteresis'")
    with usage_errors("'--backend'"):  # e.g. tqc, which the sbx backend does not train
        BenchmarkSettings(methods=chosen, backend=backend)
    settings = BenchmarkSettings(
        methods=chosen,
        seeds=list(range(seeds)),
        timesteps=timesteps,
        worker_timesteps=worker_timesteps,
        flat_timesteps=flat_timesteps,
        eval_freq=eval_freq,
        eval_episodes=eval_episodes,
        test_episodes=test_episodes,
        ham_threshold=ham_threshold,
        ham_hysteresis=ham_hysteresis,
        bias=bias,
        backend=backend,
    )
    prepare_out_dir(out, resume, force)
    started = time.perf_counter()

    def event(kind: str, task: Task, record: dict[str, Any] | None) -> None:
        elapsed = time.perf_counter() - started
        stamp = f"[dim]{elapsed / 60:6.1f} min[/]"
        if kind == "start":
            console.print(f"{stamp} started  {task.label}")
        elif kind == "skip":
            console.print(f"{stamp} [dim]kept     {task.label} (finished earlier)[/]")
        elif kind == "failed":
            console.print(f"{stamp} [red]failed   {task.label}[/] (see the log above; --resume retries)")
        elif record is not None:
            score = record.get("test", {}).get("mean_reach_reward")
            detail = f"test reach reward {score:.1f}" if score is not None else "workers trained"
            console.print(
                f"{stamp} [green]finished[/] {task.label}: {detail} ({record['wall_time_s']:.0f} s)"
            )

    results = run_benchmark(settings, out, n_jobs=n_jobs, resume=resume, on_event=event)
    console.print(results_table(results))
    if results["comparisons"]:
        console.print(comparisons_table(results))
    console.print(
        f"Wall time: {results['wall_time_s_this_invocation'] / 60:.1f} min.  Outputs in {out}: {', '.join(OUTPUT_FILES)}"
    )
    if results["failures"]:
        for label, message in results["failures"].items():
            console.print(f"[red]failed[/] {label}: {message}")
        raise typer.Exit(1)

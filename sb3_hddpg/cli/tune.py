"""``hddpg-cli tune``: Optuna hyperparameter search at any level, in several processes, on a shared study."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

import optuna
import typer
import yaml
from rich.table import Table

from sb3_hddpg.cli.app import app, console
from sb3_hddpg.cli.options import (
    ENV_HELP,
    BackendOpt,
    EpisodeStepsOpt,
    EvalEpisodesOpt,
    ExecutorOpt,
    InfoKeyOpt,
    RayAddressOpt,
    TermBoundsOpt,
    TermsOpt,
    at_least,
    cluster_address,
    positive_float,
    refuse_protected_out,
    seed_range,
    terms_env_option,
    usage_errors,
)
from sb3_hddpg.envs.ids import WORKER_ENV_IDS
from sb3_hddpg.experiments.hyperparams_opt import check_fixed_params, tunable_algorithms
from sb3_hddpg.experiments.study_storage import check_storage_url, default_storage_url
from sb3_hddpg.experiments.tuning import (
    LEVELS,
    PRUNERS,
    RANKINGS,
    SAMPLERS,
    StudySettings,
    TargetError,
    TuningTarget,
    best_trials,
    save_best_config,
    save_plots,
    trial_counts,
    trial_score,
    tune,
)
from sb3_hddpg.training.agent import TrainingInterrupted
from sb3_hddpg.training.backends import resolve_backend


def parse_fixed(items: list[str]) -> dict[str, object]:
    """``["net_arch=small", "batch_size=64"]`` -> ``{"net_arch": "small", "batch_size": 64}`` (YAML values)."""
    fixed: dict[str, object] = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise typer.BadParameter(f"expected NAME=VALUE, got {item!r}", param_hint="'--fix'")
        fixed[name.strip()] = yaml.safe_load(value)
    return fixed


def trials_table(title: str, trials: list) -> Table:
    """A rich table of trials: rank, number, last and best evaluation, parameters, duration."""
    table = Table(title=title)
    for column in ("rank", "trial", "last", "best", "parameters", "duration"):
        table.add_column(column, justify="left" if column == "parameters" else "right")
    for rank, trial in enumerate(trials, 1):
        params = ", ".join(
            f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in trial.params.items()
        )
        duration = trial.duration.total_seconds() if trial.duration is not None else float("nan")
        table.add_row(
            str(rank),
            str(trial.number),
            f"{trial.value:.2f}",
            f"{trial_score(trial, 'peak'):.2f}",
            params,
            f"{duration:.0f} s",
        )
    return table


#: The option of each tuning-target field (the library's errors name the field).
_TARGET_OPTIONS = {
    "level": "'--level'",
    "algo": "'--algo'",
    "worker": "'--worker'",
    "workers_dir": "'--workers'",
    "env": "'--env'",
    "block": "'--block'",
    "n_seeds": "'--seeds-per-trial'",
    "budget_fraction": "'--budget-fraction' / '--final-budget' / '--timesteps'",
    "timesteps": "'--timesteps'",
    "n_evaluations": "'--n-evaluations' / '--eval-episodes'",
}


@contextlib.contextmanager
def _target_errors() -> Iterator[None]:
    """A target the library refuses, as a usage error naming the option of the field at fault."""
    try:
        yield
    except TargetError as error:
        raise typer.BadParameter(str(error), param_hint=_TARGET_OPTIONS.get(error.field)) from error


def _check_search_options(
    sampler: str, pruner: str, storage: str | None, config: Path | None, rank_by: str = "last"
) -> None:
    """The sampler, pruner, storage URL, config file and ranking: usage errors naming the option."""
    if rank_by not in RANKINGS:
        raise typer.BadParameter(
            f"must be one of {list(RANKINGS)}, got {rank_by!r}", param_hint="'--rank-by'"
        )
    if sampler not in SAMPLERS:
        raise typer.BadParameter(
            f"must be one of {list(SAMPLERS)}, got {sampler!r}", param_hint="'--sampler'"
        )
    if pruner not in PRUNERS:
        raise typer.BadParameter(f"must be one of {list(PRUNERS)}, got {pruner!r}", param_hint="'--pruner'")
    if storage is not None and "://" not in storage:
        raise typer.BadParameter(
            f"expected a URL such as sqlite:///path/study.db or postgresql+psycopg://user@host/db, got {storage!r}",
            param_hint="'--storage'",
        )
    if config is not None and not config.is_file():
        raise typer.BadParameter(f"no such file: {str(config)!r}", param_hint="'--config'")


def _print_outcome(
    study: optuna.Study,
    target: TuningTarget,
    out: Path,
    top: int,
    save_config: Path | None,
    storage: str | None,
    rank_by: str = "last",
) -> None:
    """Trial counts, the best trials, the saved config and plots, and how to open the dashboard."""
    counts = trial_counts(study)
    console.print("Trials: " + ", ".join(f"{state.lower()} {n}" for state, n in sorted(counts.items())))
    best = best_trials(study, top, rank_by)
    if not best:
        console.print("[yellow]No completed trial yet[/]: no best parameters, config or plots.")
        return
    which = "last" if rank_by == "last" else "best"
    console.print(
        trials_table(f"Best trials of {study.study_name} (mean evaluation reward; ranked by {which})", best)
    )
    base = [t for t in study.trials if t.user_attrs.get("base_config")]
    if base:
        state = base[0].state
        shown = (
            f"{trial_score(base[0], rank_by):.2f}"
            if state == optuna.trial.TrialState.COMPLETE
            else state.name.lower()
        )
        console.print(
            f"Base config (trial {base[0].number}): {shown}; "
            f"best: {trial_score(best[0], rank_by):.2f} (trial {best[0].number}), {which} evaluations"
        )
    if save_config is not None:
        saved = save_best_config(study, target, save_config, rank_by)
        console.print(f"[green]✓[/] best config -> {saved}")
    for plot, result in save_plots(study, out).items():
        if isinstance(result, Path):
            console.print(f"[green]✓[/] {plot} -> {result}")
        else:
            console.print(f"[yellow]skipped {plot}[/]: {result}")
    console.print(f"Dashboard: optuna-dashboard {storage or '<your --storage URL>'}")


@app.command("tune")
def tune_command(
    level: str = typer.Option(..., "--level", help=f"What to tune: {' | '.join(LEVELS)}."),
    worker: str | None = typer.Option(
        None,
        "--worker",
        help=f"The worker to tune with --level worker: {' | '.join(sorted(WORKER_ENV_IDS))}, or a term of --env.",
    ),
    workers_dir: Path | None = typer.Option(
        None, "--workers", help="Run folder of train-workers (for --level manager and --level ham)."
    ),
    algo: str = typer.Option(
        "ddpg",
        "--algo",
        help="The algorithm with --level worker, flat or manager: "
        f"{' | '.join(tunable_algorithms('flat'))} (its own search space and bundled config "
        "zoo_configs/<algo>.yml).",
    ),
    n_trials: int = typer.Option(
        20,
        "--n-trials",
        callback=at_least(1),
        help="Finished (complete or pruned) trials the study should have, over all processes and re-runs.",
    ),
    timeout: float | None = typer.Option(
        None, "--timeout", callback=positive_float, help="Start no trial after this many seconds."
    ),
    timesteps: int | None = typer.Option(
        None,
        "--timesteps",
        callback=at_least(1),
        help=(
            "Env steps per trial, at every level (a manager makes this / option_steps decisions; default: "
            "the config's n_timesteps)."
        ),
    ),
    block: str | None = typer.Option(
        None,
        "--block",
        help=(
            "Level flat: tune this block of the base config instead of the env's, e.g. flat-her (the benchmark's "
            "sac-her / ddpg-her). Default: the env's block."
        ),
    ),
    budget_fraction: float | None = typer.Option(
        None,
        "--budget-fraction",
        help=(
            "Env steps per trial as this share (0, 1] of --final-budget, the method's budget in the benchmark: "
            "every method's study at the same share (instead of --timesteps). Default: not used."
        ),
    ),
    final_budget: int | None = typer.Option(
        None,
        "--final-budget",
        callback=at_least(1),
        help="The tuned method's final budget in env steps, for --budget-fraction (e.g. 340000 for a flat agent).",
    ),
    n_evaluations: int = typer.Option(
        5, "--n-evaluations", callback=at_least(1), help="Evaluations per trial, reported to the pruner."
    ),
    eval_episodes: EvalEpisodesOpt = 5,
    seeds_per_trial: int = typer.Option(
        1,
        "--seeds-per-trial",
        callback=at_least(1),
        help=(
            "Training seeds per trial (--seed, --seed + 1, ...): a trial's value is the mean over them, so "
            "configurations are ranked across seeds, not on one seed's luck; each seed costs --timesteps "
            "again. Give every method's study the same value. Not with --level ham."
        ),
    ),
    n_jobs: int = typer.Option(
        1,
        "--n-jobs",
        callback=at_least(1),
        help="Trial processes on this machine (one per core is fastest), or Ray tasks with --executor ray.",
    ),
    threads: int = typer.Option(
        1,
        "--threads",
        callback=at_least(1),
        help="Torch threads per trial process: 1 is faster for small networks and never oversubscribes "
        "cores shared with other work.",
    ),
    executor: ExecutorOpt = "local",
    ray_address: RayAddressOpt = None,
    sampler: str = typer.Option("tpe", "--sampler", help=f"Sampler: {' | '.join(SAMPLERS)}."),
    pruner: str = typer.Option("median", "--pruner", help=f"Pruner: {' | '.join(PRUNERS)}."),
    storage: str | None = typer.Option(
        None,
        "--storage",
        help="Optuna storage URL, e.g. postgresql+psycopg://user:pw@host/db (default: sqlite OUT/study.db).",
    ),
    study_name: str | None = typer.Option(
        None,
        "--study-name",
        help="Study name; an existing study resumes (default: the level, e.g. worker-goal).",
    ),
    seed: int | None = typer.Option(
        None,
        "--seed",
        callback=seed_range,
        help="Seeds training (default 0) and the sampler (default: unseeded, so parallel runs differ).",
    ),
    out: Path | None = typer.Option(
        None,
        "--out",
        help="Run folder for the study file, plots and trial scratch (default: runs/tune/NAME).",
    ),
    save_config: Path | None = typer.Option(
        None, "--save-config", help="Write the best parameters as a zoo_configs YAML for train-* --config."
    ),
    config: Path | None = typer.Option(
        None,
        "--config",
        help="Base zoo_configs file whose untuned keys trials keep (default: the bundled one).",
    ),
    fix: list[str] = typer.Option(
        [], "--fix", help="Hold a parameter fixed, e.g. --fix net_arch=small (repeat)."
    ),
    heartbeat: int = typer.Option(
        30,
        "--heartbeat",
        callback=at_least(1),
        help="Seconds between a running trial's heartbeats; a trial silent for twice that is retried.",
    ),
    top: int = typer.Option(5, "--top", callback=at_least(1), help="Best trials to show."),
    rank_by: str = typer.Option(
        "last",
        "--rank-by",
        help="Which trial is best (shown, and saved by --save-config): last = by its last evaluation "
        "(the Optuna value, RL Zoo's objective); peak = by its best evaluation (the checkpoint train-* "
        "and benchmark keep).",
    ),
    enqueue_base: bool = typer.Option(
        True,
        "--enqueue-base/--no-enqueue-base",
        help=(
            "A new study's first trial is the base config's own values (those in the search space), so the "
            "best trial is never worse than the base config at the trial budget."
        ),
    ),
    backend: BackendOpt = None,
    env: str | None = typer.Option(
        None,
        "--env",
        help=ENV_HELP + " Default: the snake arm; for --level manager, the env of the workers' manifest.",
    ),
    terms: TermsOpt = None,
    term_bounds: TermBoundsOpt = None,
    info_key: InfoKeyOpt = None,
    episode_steps: EpisodeStepsOpt = None,
) -> None:
    """Search hyperparameters with Optuna; several processes or machines can share one study."""
    import matplotlib  # lazily: slow to import with pyplot, only when a study runs

    matplotlib.use("Agg")  # plots are files; never open a window

    shared = terms_env_option(env, terms, term_bounds, info_key, episode_steps)
    if level == "ham" and save_config is not None:
        raise typer.BadParameter("HAM has no DDPG hyperparameters to save", param_hint="'--save-config'")
    _check_search_options(sampler, pruner, storage, config, rank_by)
    with _target_errors():
        target = TuningTarget(
            level=level,
            worker=worker,
            workers_dir=str(workers_dir) if workers_dir is not None else None,
            config=str(config) if config is not None else None,
            timesteps=timesteps,
            n_evaluations=n_evaluations,
            eval_episodes=eval_episodes,
            seed=seed if seed is not None else 0,
            algo=algo,
            backend=backend,
            env=shared,
            n_seeds=seeds_per_trial,
            budget_fraction=budget_fraction,
            final_budget=final_budget,
            block=block,
        )
    fixed = parse_fixed(fix)
    with usage_errors("'--fix'"):
        check_fixed_params(level, fixed, algo)
    if storage is not None:
        with usage_errors("'--storage'"):
            check_storage_url(storage)
    with usage_errors("'--workers'" if level in ("manager", "ham") else "'--config'"):
        target.check()
    if level != "ham":
        with usage_errors("'--backend'"):  # also a config's `backend: sbx` where SBX is not installed
            resolve_backend(backend, target.base_block().get("backend"))
    address = cluster_address(executor, ray_address)
    name = study_name or target.name
    out = refuse_protected_out(out or Path("runs") / "tune" / name)
    settings = StudySettings(
        storage=storage or default_storage_url(out),
        study_name=name,
        n_trials=n_trials,
        timeout=timeout,
        sampler=sampler,
        pruner=pruner,
        seed=seed,
        fixed_params=fixed,
        heartbeat_interval=heartbeat,
        enqueue_base=enqueue_base,
    )
    shown_storage = storage.split("@")[-1] if storage else settings.storage
    per_trial = "one evaluation" if level == "ham" else f"{target.budget()} steps"
    if seeds_per_trial > 1:
        per_trial += f" x {seeds_per_trial} seeds ({target.seed}..{target.seed + seeds_per_trial - 1})"
    console.print(
        f"Tuning [bold]{target.name}[/] in study [bold]{name}[/] ({shown_storage}): "
        f"{n_trials} trials of {per_trial}, {n_jobs} process(es)"
        + (f" on the Ray cluster at {address}" if address else "")
    )
    try:
        study = tune(target, settings, out, n_jobs=n_jobs, threads=threads, ray_address=address)
    except TrainingInterrupted as interrupted:
        console.print(f"[yellow]{interrupted}[/] Re-run the same command to resume the study.")
        raise typer.Exit(130) from None

    _print_outcome(
        study, target, out, top, save_config, settings.storage if storage is None else None, rank_by
    )

"""``hddpg-cli tune``: Optuna hyperparameter search at any level, in several processes, on a shared study."""

from __future__ import annotations

import contextlib
import importlib.util
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated

import optuna
import typer
import yaml
from rich.table import Table

from hddpg_zoo.cli.options import ExecutorOpt, RayAddressOpt, check_jobs, cluster_address, positive_float
from hddpg_zoo.hyperparams_opt import check_fixed_params, tunable_algorithms
from hddpg_zoo.study_storage import check_storage_url, default_storage_url
from hddpg_zoo.tuning import (
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
from sb3_hddpg.artifacts.run_folder import check_out_folder, mark_run_folder, record_written
from sb3_hddpg.cli.app import app, console
from sb3_hddpg.cli.errors import CommandStopped
from sb3_hddpg.cli.options import (
    ENV_HELP,
    BackendOpt,
    EpisodeStepsOpt,
    EvalEpisodesOpt,
    InfoKeyOpt,
    TermBoundsOpt,
    TermsOpt,
    at_least,
    count,
    existing_file,
    refuse_protected_out,
    seed_range,
    terms_env_option,
    usage_errors,
)
from sb3_hddpg.envs.ids import WORKER_ENV_IDS
from sb3_hddpg.names import check_plain_name
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
    "n_evaluations": "'--n-evaluations'",
    "eval_episodes": "'--eval-episodes'",
}


@contextlib.contextmanager
def _target_errors() -> Iterator[None]:
    """A target the library refuses, as a usage error naming the option of the field at fault."""
    try:
        yield
    except TargetError as error:
        raise typer.BadParameter(str(error), param_hint=_TARGET_OPTIONS.get(error.field)) from error


def _check_search_options(
    sampler: str,
    pruner: str,
    storage: str | None,
    config: Path | None,
    rank_by: str = "last",
    level: str = "worker",
    save_config: Path | None = None,
) -> None:
    """The sampler, pruner, storage URL, config file, ranking and saved config: usage errors naming the option."""
    if level == "ham" and save_config is not None:
        raise typer.BadParameter("HAM has no DDPG hyperparameters to save", param_hint="'--save-config'")
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
    try:
        existing_file(config)
    except typer.BadParameter as error:
        raise typer.BadParameter(error.message, param_hint="'--config'") from None


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


# The options of `tune_command`.
_LevelOpt = Annotated[str, typer.Option("--level", help=f"What to tune: {' | '.join(LEVELS)}.")]
_WorkerOpt = Annotated[
    str | None,
    typer.Option(
        "--worker",
        help=f"The worker to tune with --level worker: {' | '.join(sorted(WORKER_ENV_IDS))}, or a term of --env.",
    ),
]
_WorkersDirOpt = Annotated[
    Path | None,
    typer.Option("--workers", help="Run folder of train-workers (for --level manager and --level ham)."),
]
_AlgoOpt = Annotated[
    str,
    typer.Option(
        "--algo",
        help="The algorithm with --level worker, flat or manager: "
        f"{' | '.join(tunable_algorithms('flat'))} (its own search space and bundled config "
        "zoo_configs/<algo>.yml).",
    ),
]
_NTrialsOpt = Annotated[
    int,
    typer.Option(
        "--n-trials",
        callback=count("n_trials"),
        help="Finished (complete or pruned) trials the study should have, over all processes and re-runs.",
    ),
]
_TimeoutOpt = Annotated[
    float | None,
    typer.Option("--timeout", callback=positive_float, help="Start no trial after this many seconds."),
]
_TimestepsOpt = Annotated[
    int | None,
    typer.Option(
        "--timesteps",
        callback=at_least(1),
        help="Env steps per trial, at every level (a manager makes this / option_steps decisions; default: "
        "the config's n_timesteps).",
    ),
]
_BlockOpt = Annotated[
    str | None,
    typer.Option(
        "--block",
        help="Level flat: tune this block of the base config instead of the env's, e.g. flat-her (the benchmark's "
        "sac-her / ddpg-her). Default: the env's block.",
    ),
]
_BudgetFractionOpt = Annotated[
    float | None,
    typer.Option(
        "--budget-fraction",
        help="Env steps per trial as this share (0, 1] of --final-budget, the method's budget in the benchmark: "
        "every method's study at the same share (instead of --timesteps). Default: not used.",
    ),
]
_FinalBudgetOpt = Annotated[
    int | None,
    typer.Option(
        "--final-budget",
        callback=at_least(1),
        help="The tuned method's final budget in env steps, for --budget-fraction (e.g. 340000 for a flat agent).",
    ),
]
_NEvaluationsOpt = Annotated[
    int,
    typer.Option(
        "--n-evaluations",
        callback=count("evaluations"),
        help="Evaluations per trial, reported to the pruner.",
    ),
]
_SeedsPerTrialOpt = Annotated[
    int,
    typer.Option(
        "--seeds-per-trial",
        callback=count("seeds_per_trial"),
        help="Training seeds per trial (--seed, --seed + 1, ...): a trial's value is the mean over them, so "
        "configurations are ranked across seeds, not on one seed's luck; each seed costs --timesteps "
        "again. Give every method's study the same value. Not with --level ham.",
    ),
]
_NJobsOpt = Annotated[
    int,
    typer.Option(
        "--n-jobs",
        callback=at_least(1),
        help="Trial processes on this machine (one per core is fastest), or Ray tasks with --executor ray.",
    ),
]
_ThreadsOpt = Annotated[
    int,
    typer.Option(
        "--threads",
        callback=at_least(1),
        help="Torch threads per trial process: 1 is faster for small networks and never oversubscribes "
        "cores shared with other work.",
    ),
]
_SamplerOpt = Annotated[str, typer.Option("--sampler", help=f"Sampler: {' | '.join(SAMPLERS)}.")]
_PrunerOpt = Annotated[str, typer.Option("--pruner", help=f"Pruner: {' | '.join(PRUNERS)}.")]
_StorageOpt = Annotated[
    str | None,
    typer.Option(
        "--storage",
        help="Optuna storage URL, e.g. postgresql+psycopg://user:pw@host/db (default: sqlite OUT/study.db).",
    ),
]
_StudyNameOpt = Annotated[
    str | None,
    typer.Option(
        "--study-name", help="Study name; an existing study resumes (default: the level, e.g. worker-goal)."
    ),
]
_SeedOpt = Annotated[
    int | None,
    typer.Option(
        "--seed",
        callback=seed_range,
        help="Seeds training (default 0) and the sampler (default: unseeded, so parallel runs differ).",
    ),
]
_OutOpt = Annotated[
    Path | None,
    typer.Option(
        "--out", help="Run folder for the study file, plots and trial scratch (default: runs/tune/NAME)."
    ),
]
_SaveConfigOpt = Annotated[
    Path | None,
    typer.Option(
        "--save-config", help="Write the best parameters as a zoo_configs YAML for train-* --config."
    ),
]
_ConfigOpt = Annotated[
    Path | None,
    typer.Option(
        "--config", help="Base zoo_configs file whose untuned keys trials keep (default: the bundled one)."
    ),
]
_FixOpt = Annotated[
    list[str] | None,
    typer.Option("--fix", help="Hold a parameter fixed, e.g. --fix net_arch=small (repeat)."),
]
_HeartbeatOpt = Annotated[
    int,
    typer.Option(
        "--heartbeat",
        callback=at_least(1),
        help="Seconds between a running trial's heartbeats; a trial silent for twice that is retried.",
    ),
]
_TopOpt = Annotated[int, typer.Option("--top", callback=at_least(1), help="Best trials to show.")]
_RankByOpt = Annotated[
    str,
    typer.Option(
        "--rank-by",
        help="Which trial is best (shown, and saved by --save-config): last = by its last evaluation "
        "(the Optuna value, RL Zoo's objective); peak = by its best evaluation (the checkpoint train-* "
        "and benchmark keep).",
    ),
]
_EnqueueBaseOpt = Annotated[
    bool,
    typer.Option(
        "--enqueue-base/--no-enqueue-base",
        help="A new study's first trial is the base config's own values (those in the search space), so the "
        "best trial is never worse than the base config at the trial budget.",
    ),
]
_EnvOpt = Annotated[
    str | None,
    typer.Option(
        "--env",
        help=ENV_HELP + " Default: the snake arm; for --level manager, the env of the workers' manifest.",
    ),
]


@app.command("tune")
def tune_command(
    level: _LevelOpt,
    worker: _WorkerOpt = None,
    workers_dir: _WorkersDirOpt = None,
    algo: _AlgoOpt = "ddpg",
    n_trials: _NTrialsOpt = 20,
    timeout: _TimeoutOpt = None,
    timesteps: _TimestepsOpt = None,
    block: _BlockOpt = None,
    budget_fraction: _BudgetFractionOpt = None,
    final_budget: _FinalBudgetOpt = None,
    n_evaluations: _NEvaluationsOpt = 5,
    eval_episodes: EvalEpisodesOpt = 5,
    seeds_per_trial: _SeedsPerTrialOpt = 1,
    n_jobs: _NJobsOpt = 1,
    threads: _ThreadsOpt = 1,
    executor: ExecutorOpt = "local",
    ray_address: RayAddressOpt = None,
    sampler: _SamplerOpt = "tpe",
    pruner: _PrunerOpt = "median",
    storage: _StorageOpt = None,
    study_name: _StudyNameOpt = None,
    seed: _SeedOpt = None,
    out: _OutOpt = None,
    save_config: _SaveConfigOpt = None,
    config: _ConfigOpt = None,
    fix: _FixOpt = None,
    heartbeat: _HeartbeatOpt = 30,
    top: _TopOpt = 5,
    rank_by: _RankByOpt = "last",
    enqueue_base: _EnqueueBaseOpt = True,
    backend: BackendOpt = None,
    env: _EnvOpt = None,
    terms: TermsOpt = None,
    term_bounds: TermBoundsOpt = None,
    info_key: InfoKeyOpt = None,
    episode_steps: EpisodeStepsOpt = None,
) -> None:
    """Search hyperparameters with Optuna; several processes or machines can share one study."""
    _files_only_plots()
    shared = terms_env_option(env, terms, term_bounds, info_key, episode_steps)
    _check_search_options(sampler, pruner, storage, config, rank_by, level, save_config)
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
    fixed = _checked_target(target, fix or [], storage, backend)
    check_jobs(n_jobs, executor)
    address = cluster_address(executor, ray_address)
    settings, out = _study_settings(
        target,
        out,
        storage,
        study_name,
        n_trials,
        timeout,
        sampler,
        pruner,
        seed,
        fixed,
        heartbeat,
        enqueue_base,
    )
    _run_study(target, settings, out, storage, n_jobs, threads, address, top, save_config, rank_by)


def _checked_target(
    target: TuningTarget, fix: list[str], storage: str | None, backend: str | None
) -> dict[str, object]:
    """
    Check what the study tunes before anything runs: the fixed parameters, the storage URL, the target's
    files and the backend.

    :return: the fixed parameters, parsed.
    """
    fixed = parse_fixed(fix)
    with usage_errors("'--fix'"):
        check_fixed_params(target.level, fixed, target.algo)
    if storage is not None:
        with usage_errors("'--storage'"):
            check_storage_url(storage)
    with usage_errors("'--workers'" if target.level in ("manager", "ham") else "'--config'"):
        target.check()
    if target.level != "ham":
        with usage_errors("'--backend'"):  # also a config's `backend: sbx` where SBX is not installed
            resolve_backend(backend, target.base_block().get("backend"))
    return fixed


def _announce(
    target: TuningTarget, settings: StudySettings, storage: str | None, n_jobs: int, address: str | None
) -> None:
    """One line saying what is tuned, in which study and storage, how many trials of what, and where."""
    shown_storage = storage.split("@")[-1] if storage else settings.storage
    per_trial = "one evaluation" if target.level == "ham" else f"{target.budget()} steps"
    if target.n_seeds > 1:
        per_trial += f" x {target.n_seeds} seeds ({target.seed}..{target.seed + target.n_seeds - 1})"
    console.print(
        f"Tuning [bold]{target.name}[/] in study [bold]{settings.study_name}[/] ({shown_storage}): "
        f"{settings.n_trials} trials of {per_trial}, {n_jobs} process(es)"
        + (f" on the Ray cluster at {address}" if address else "")
    )


def _files_only_plots() -> None:
    """Plots are files: never open a window."""
    if (
        importlib.util.find_spec("matplotlib") is None
    ):  # no plots without the bench extra (save_plots says so)
        return
    import matplotlib  # lazily: slow to import with pyplot, only when a study runs

    matplotlib.use("Agg")


def _study_settings(
    target: TuningTarget,
    out: Path | None,
    storage: str | None,
    study_name: str | None,
    n_trials: int,
    timeout: float | None,
    sampler: str,
    pruner: str,
    seed: int | None,
    fixed: dict[str, object],
    heartbeat: int,
    enqueue_base: bool,
) -> tuple[StudySettings, Path]:
    """The study's settings (its storage beside the output folder unless ``--storage``), and that folder."""
    with usage_errors("'--study-name'"):
        # The name becomes the default folder's and an export's file name: a plain name, never a path.
        name = check_plain_name(study_name or target.name, "--study-name")
    out = refuse_protected_out(out or Path("runs") / "tune" / name)
    with usage_errors("'--out'"):
        check_out_folder(out)  # a folder of the user's is never taken over (its study, plots, scratch)
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
    return settings, out


def _run_study(
    target: TuningTarget,
    settings: StudySettings,
    out: Path,
    storage: str | None,
    n_jobs: int,
    threads: int,
    address: str | None,
    top: int,
    save_config: Path | None,
    rank_by: str,
) -> None:
    """Say what is tuned, run the study (Ctrl-C: exit 130, the study resumable) and print its outcome."""
    _announce(target, settings, storage, n_jobs, address)
    mark_run_folder(out, "tune", reopen=True)
    try:
        try:
            study = tune(target, settings, out, n_jobs=n_jobs, threads=threads, ray_address=address)
        except TrainingInterrupted:
            # The trial's own message advises --resume, an option of train-*, not of tune: say what holds.
            raise CommandStopped(
                f"tuning interrupted; study {settings.study_name!r} keeps its finished trials and queues the "
                "interrupted one again: re-run the same command to resume the study"
            ) from None
        _print_outcome(
            study, target, out, top, save_config, settings.storage if storage is None else None, rank_by
        )
    finally:  # its plots too: a re-run resumes the study into the same folder
        record_written(out)

"""``hddpg-cli benchmark``: HDDPG against HAM and flat agents over several seeds (paper Section 3.3-3.4)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from hddpg_zoo.benchmark import (
    DEFAULT_ENV_METHODS,
    DEFAULT_METHODS,
    DEFAULT_TRANSFER_METHODS,
    DEFAULT_TRANSFER_PREFERENCES,
    ENV_METHODS,
    ENV_ONLY_METHODS,
    FRONT_METHODS,
    METHOD_REGISTRY,
    SCENARIOS,
    BenchmarkSettings,
    check_redo,
    check_workers_source,
    default_env_methods,
    output_files_in,
    run_benchmark,
)
from hddpg_zoo.benchmark.front import FRONT_SETTINGS
from hddpg_zoo.benchmark.machine_paths import check_machine_paths
from hddpg_zoo.benchmark.method_inputs import EnvChoice
from hddpg_zoo.benchmark.tables import TextTable, console_tables, wall_time_text
from hddpg_zoo.cli.benchmark_events import check_snapshot_option, event_printer, snapshotting, take_snapshot
from hddpg_zoo.cli.benchmark_protocol import ProtocolOpt, protocol_command
from hddpg_zoo.cli.export_models import export_run
from hddpg_zoo.cli.front_options import (
    FrontCriticStepsOpt,
    FrontGpiOpt,
    FrontManagerOpt,
    FrontMotionOpt,
    FrontOptionStepsOpt,
    FrontPerPreferenceOpt,
    FrontStartOpt,
    FrontSupportOpt,
    FrontSweepOpt,
    FrontTimestepsOpt,
    MorlPythonOpt,
)
from hddpg_zoo.cli.options import (
    ExecutorOpt,
    ExperimentBackendOpt,
    RayAddressOpt,
    between,
    build_settings,
    check_jobs,
    cluster_address,
    positive_float,
)
from hddpg_zoo.records import BenchmarkResults
from sb3_hddpg.artifacts.limits import MAX_BENCHMARK_SEEDS
from sb3_hddpg.cli.app import app, console
from sb3_hddpg.cli.errors import CommandStopped
from sb3_hddpg.cli.options import (
    ENV_HELP,
    SNAKE_DEFAULT,
    EpisodeStepsOpt,
    ForceOpt,
    InfoKeyOpt,
    TermBoundsOpt,
    TermsOpt,
    at_least,
    count,
    prepare_out_dir,
    terms_env_option,
    usage_errors,
)
from sb3_hddpg.envs.terms_env import TermsEnv


def _rich_table(table: TextTable) -> Table:
    """A library table drawn by rich."""
    drawn = Table(title=table.title)
    for column in table.columns:
        drawn.add_column(
            column,
            justify="left" if column in table.left else "right",
            overflow="fold" if table.fold else "ellipsis",
        )
    for row in table.rows:
        drawn.add_row(*row)
    return drawn


def _chosen_methods(methods: str | None, transfer: bool, shared: TermsEnv | None = None) -> list[str]:
    """The ``--methods`` list (default: the scenario's, or on another env than the snake its own), each known."""
    if methods is None:
        defaults = default_env_methods(shared) if shared is not None else DEFAULT_METHODS
        methods = ",".join(DEFAULT_TRANSFER_METHODS if transfer else defaults)
    chosen = [m.strip() for m in methods.split(",") if m.strip()]
    unknown = [m for m in chosen if m not in METHOD_REGISTRY]
    if unknown or not chosen:
        raise typer.BadParameter(
            f"unknown method {unknown[0] if unknown else methods!r}; choose from {list(METHOD_REGISTRY)}",
            param_hint="'--methods'",
        )
    return chosen


# The options of `benchmark_command`.
_MethodsOpt = Annotated[
    str | None,
    typer.Option(
        "--methods",
        help=f"Comma-separated methods among {list(METHOD_REGISTRY)} (default: {','.join(DEFAULT_METHODS)}; "
        f"with --scenario transfer: {','.join(DEFAULT_TRANSFER_METHODS)}).",
    ),
]
_ScenarioOpt = Annotated[
    str,
    typer.Option(
        "--scenario",
        help=f"One of {list(SCENARIOS)}: 'transfer' trains each seed's workers once, then per --preference a "
        "manager and each flat method from scratch on that preference's reward, and reports the ratio of "
        "env steps each needs to get 90 % of the way from a random policy's score to its own final score; "
        "'front' trains per seed a preference-conditioned manager and a manager for each preference of the "
        "ratio sweep (7 for two workers), and measures every hierarchy's front (the env's rule over a "
        "threshold sweep: HAM on the snake arm, the time-to-collision switch on highway-env; each worker "
        "alone) and its hypervolumes (docs/MANAGER.md; on another env docs/ENVIRONMENTS.md).",
    ),
]
_PreferenceOpt = Annotated[
    list[str] | None,
    typer.Option(
        "--preference",
        help="A preference of the transfer scenario, e.g. goal=2,avoid=1 (repeat the option for more; default: "
        f"{' and '.join(DEFAULT_TRANSFER_PREFERENCES)}).",
    ),
]
_SeedsOpt = Annotated[
    int,
    typer.Option(
        "--seeds", callback=between(1, MAX_BENCHMARK_SEEDS), help="Seeds 0..N-1, one run per method each."
    ),
]
_TimestepsOpt = Annotated[
    int | None,
    typer.Option(
        "--timesteps",
        callback=at_least(1),
        help="Manager steps (decisions; x option_steps env steps each), whose env steps are the curve window of every method (default: the config's manager n_timesteps).",
    ),
]
_WorkerTimestepsOpt = Annotated[
    int | None,
    typer.Option(
        "--worker-timesteps",
        callback=at_least(1),
        help="Steps per worker, trained once per seed (default: each worker's config n_timesteps).",
    ),
]
_FlatTimestepsOpt = Annotated[
    int | None,
    typer.Option(
        "--flat-timesteps",
        callback=at_least(1),
        help="Flat agents' steps (default: the hierarchy's total, manager's plus every worker's).",
    ),
]
_EvalFreqOpt = Annotated[
    int | None,
    typer.Option(
        "--eval-freq",
        callback=at_least(1),
        help="Env steps between curve evaluations of every run (default: a tenth of the manager's env steps).",
    ),
]
_EvalEpisodesOpt = Annotated[
    int,
    typer.Option(
        "--eval-episodes", callback=count("episodes"), help="Episodes per learning-curve evaluation."
    ),
]
_TestEpisodesOpt = Annotated[
    int | None,
    typer.Option(
        "--test-episodes",
        callback=count("episodes"),
        help="Test episodes per trained model (default: 20 development episodes; 100 with --final-test).",
    ),
]
_FinalTestOpt = Annotated[
    bool,
    typer.Option(
        "--final-test",
        help="Score every run on the final test set (episode seeds from 900000), for the runs of record only: "
        "never make a choice from it. Default: the development episodes (from 15000).",
    ),
]
_HamThresholdOpt = Annotated[
    float | None,
    typer.Option(
        "--ham-threshold",
        help="HAM's threshold on the summed joint-obstacle distances (default: n_joints - 0.5).",
    ),
]
_HamHysteresisOpt = Annotated[float, typer.Option("--ham-hysteresis", help="HAM's hysteresis (>= 0).")]
_BiasOpt = Annotated[
    float,
    typer.Option("--bias", callback=positive_float, help="The biased managers' extra preference factor."),
]
_NJobsOpt = Annotated[
    int | None,
    typer.Option(
        "--n-jobs",
        callback=at_least(1),
        help="Runs in parallel, one process each (default: 1; with --executor ray, every CPU of the cluster).",
    ),
]
_OutOpt = Annotated[Path, typer.Option("--out", help="Benchmark folder.")]
_ResumeOpt = Annotated[
    bool,
    typer.Option(
        "--resume",
        help="Keep finished runs and continue interrupted ones; --methods and --seeds may add runs.",
    ),
]
_RedoOpt = Annotated[
    str | None,
    typer.Option(
        "--redo",
        help="With --resume: comma-separated methods to run again, e.g. after their config block changed (a "
        "kept run made from another block is refused otherwise) or with a setting only they read "
        "(--ham-threshold: --redo ham); their runs so far are moved to OUT/replaced-<UTC time>/. "
        "Default: none.",
    ),
]
_AllowMixedOpt = Annotated[
    bool,
    typer.Option(
        "--allow-mixed-commits",
        help="With --resume: continue a benchmark whose earlier invocations ran another version or git commit "
        "(or one not recorded); refused otherwise. benchmark.json's invocations record the code each ran.",
    ),
]
_ExportDirOpt = Annotated[
    Path | None,
    typer.Option(
        "--export-models",
        help="Afterwards copy the final models into this folder with an index.json (see export-models).",
    ),
]
_SnapshotOpt = Annotated[
    Path | None,
    typer.Option(
        "--snapshot",
        help="Each time a seed's last run finishes, and at the end, copy the finished seeds into this folder "
        "(see snapshot): it resumes the benchmark on any machine.",
    ),
]
_WorkersFromOpt = Annotated[
    Path | None,
    typer.Option(
        "--workers-from",
        help="A finished benchmark folder whose workers each seed reuses instead of training its own (they "
        "must come from the same config, worker budget, backend, env and seeds: then they are the workers "
        "this run would train, and their sha256 is checked). Default: train them.",
    ),
]
_EnvOpt = Annotated[
    str | None,
    typer.Option(
        "--env",
        help=ENV_HELP
        + SNAKE_DEFAULT
        + f" There the methods are among {list(ENV_METHODS)} (default: {','.join(DEFAULT_ENV_METHODS)} on continuous "
        "actions; on discrete ones hddpg-dqn, each worker alone, flat dqn and ppo, and on highway-env ttc-tuned), "
        "standard scenario only.",
    ),
]
_WorkerAlgoOpt = Annotated[
    str | None,
    typer.Option(
        "--worker-algo",
        help="With --env: every worker's algorithm (default: dqn on discrete actions, ddpg on continuous ones), "
        "e.g. qrdqn or sac.",
    ),
]
#: The options whose values the benchmark's settings check, named in their errors.
_SETTINGS_OPTIONS = {
    "methods": "--methods",
    "seeds": "--seeds",
    "timesteps": "--timesteps",
    "worker_timesteps": "--worker-timesteps",
    "flat_timesteps": "--flat-timesteps",
    "eval_freq": "--eval-freq",
    "eval_episodes": "--eval-episodes",
    "test_episodes": "--test-episodes",
    "ham_threshold": "--ham-threshold",
    "ham_hysteresis": "--ham-hysteresis",
    "bias": "--bias",
    "scenario": "--scenario",
    "preferences": "--preference",
    "backend": "--backend",
    "env": "--env",
    "workers_from": "--workers-from",
    "final_test": "--final-test",
    "worker_algo": "--worker-algo",
    "front_manager": "--front-manager",
    "front_timesteps": "--front-timesteps",
    "front_sweep": "--front-sweep",
    "front_motion": "--front-motion",
    "front_option_steps": "--front-option-steps",
    "front_per_preference": "--front-per-preference",
    "front_support": "--front-support",
    "front_start": "--front-start",
    "front_critic_steps": "--front-critic-steps",
    "front_gpi": "--front-gpi",
    "morl_python": "--morl-python",
}


@app.command("benchmark")
def benchmark_command(
    context: typer.Context,
    methods: _MethodsOpt = None,
    scenario: _ScenarioOpt = "standard",
    preference: _PreferenceOpt = None,
    seeds: _SeedsOpt = 5,
    timesteps: _TimestepsOpt = None,
    worker_timesteps: _WorkerTimestepsOpt = None,
    flat_timesteps: _FlatTimestepsOpt = None,
    eval_freq: _EvalFreqOpt = None,
    eval_episodes: _EvalEpisodesOpt = 5,
    test_episodes: _TestEpisodesOpt = None,
    final_test: _FinalTestOpt = False,
    ham_threshold: _HamThresholdOpt = None,
    ham_hysteresis: _HamHysteresisOpt = 0.0,
    bias: _BiasOpt = 0.15,
    n_jobs: _NJobsOpt = None,
    executor: ExecutorOpt = "local",
    ray_address: RayAddressOpt = None,
    out: _OutOpt = Path("runs/benchmark"),
    resume: _ResumeOpt = False,
    redo: _RedoOpt = None,
    allow_mixed_commits: _AllowMixedOpt = False,
    force: ForceOpt = False,
    export_dir: _ExportDirOpt = None,
    snapshot_dir: _SnapshotOpt = None,
    backend: ExperimentBackendOpt = "sb3",
    workers_from: _WorkersFromOpt = None,
    env: _EnvOpt = None,
    worker_algo: _WorkerAlgoOpt = None,
    front_manager: FrontManagerOpt = "ddpg",
    front_timesteps: FrontTimestepsOpt = None,
    front_sweep: FrontSweepOpt = "ratio-sweep",
    front_motion: FrontMotionOpt = 0.0,
    front_option_steps: FrontOptionStepsOpt = None,
    front_per_preference: FrontPerPreferenceOpt = True,
    front_support: FrontSupportOpt = None,
    front_start: FrontStartOpt = None,
    front_critic_steps: FrontCriticStepsOpt = 0,
    front_gpi: FrontGpiOpt = "actions",
    morl_python: MorlPythonOpt = None,
    terms: TermsOpt = None,
    term_bounds: TermBoundsOpt = None,
    info_key: InfoKeyOpt = None,
    episode_steps: EpisodeStepsOpt = None,
    protocol: ProtocolOpt = None,
) -> None:
    """Train and evaluate every method on every seed; write results.json, evaluations.csv and plots. Tables
    compare the normalised terms' return; goal touches and contacts only where the env reports them (the snake)."""
    if protocol is not None:
        return protocol_command(context)
    shared = terms_env_option(env, terms, term_bounds, info_key, episode_steps)
    chosen, preferences = _scenario_methods(scenario, methods, preference, ham_hysteresis, shared, backend)
    settings = check_machine_paths(_settings_of(context, chosen, preferences, shared))
    check_jobs(n_jobs, executor)
    redone, address = _checked_options(settings, redo, resume, out, snapshot_dir, (executor, ray_address))
    prepare_out_dir(context, out, resume, force)
    results = _run_until_stopped(
        settings, out, n_jobs, resume, redone, address, snapshot_dir, allow_mixed_commits
    )
    _print_results(results, out, export_dir, snapshot_dir)


#: The settings fields the command passes on as given, each from the option of its own name.
_GIVEN_SETTINGS = (
    "worker_timesteps",
    "flat_timesteps",
    "eval_freq",
    "eval_episodes",
    "test_episodes",
    "ham_threshold",
    "ham_hysteresis",
    "bias",
    "scenario",
    "backend",
    "final_test",
    "worker_algo",
    *FRONT_SETTINGS,
)


def _settings_of(
    context: typer.Context, methods: list[str], preferences: list[str], shared: TermsEnv | None
) -> BenchmarkSettings:
    """
    The benchmark's settings from the command's options, a refusal naming the option at fault
    (:func:`~hddpg_zoo.cli.options.build_settings`).

    :param context: the command's context (its parameters: the options as given).
    :param methods: the methods the scenario runs.
    :param preferences: the transfer scenario's preferences.
    :param shared: the env with several objectives chosen by ``--env`` and its term options, if any.
    """
    params = context.params
    workers_from = params["workers_from"]
    return build_settings(
        BenchmarkSettings,
        _SETTINGS_OPTIONS,
        methods=methods,
        seeds=list(range(params["seeds"])),
        timesteps=params["timesteps"] or 0,
        preferences=preferences,
        env=_env_record(shared),
        workers_from=str(workers_from.resolve()) if workers_from is not None else None,
        **{name: params[name] for name in _GIVEN_SETTINGS},
    )


def _run_until_stopped(
    settings: BenchmarkSettings,
    out: Path,
    n_jobs: int | None,
    resume: bool,
    redo: list[str],
    address: str | None,
    snapshot_dir: Path | None,
    allow_mixed_commits: bool = False,
) -> BenchmarkResults:
    """
    Run the benchmark, printing each run's start and end. Ctrl-C or SIGTERM stops it with every finished
    run kept and every running one checkpointed: say how to continue, and exit 130.
    """
    printer = snapshotting(event_printer(settings, n_jobs, address), out, snapshot_dir, settings)
    try:
        return run_benchmark(
            settings,
            out,
            n_jobs=n_jobs,
            resume=resume,
            on_event=printer,
            ray_address=address,
            redo=redo,
            allow_mixed_commits=allow_mixed_commits,
        )
    except KeyboardInterrupt:
        raise CommandStopped(
            "Stopped: the finished runs are kept and the running ones checkpointed; the same command with "
            f"--resume continues it in {out}."
        ) from None


def _scenario_methods(
    scenario: str,
    methods: str | None,
    preference: list[str] | None,
    ham_hysteresis: float,
    shared: TermsEnv | None,
    backend: str,
) -> tuple[list[str], list[str]]:
    """
    Check the scenario and the options that depend on it.

    :return: the methods to run (the scenario's default unless ``--methods``), and the transfer preferences.
    """
    if scenario not in SCENARIOS:
        raise typer.BadParameter(
            f"unknown scenario {scenario!r}; choose from {list(SCENARIOS)}", param_hint="'--scenario'"
        )
    transfer = scenario == "transfer"
    if preference and not transfer:
        raise typer.BadParameter("applies to --scenario transfer only", param_hint="'--preference'")
    with usage_errors("'--env'"):
        chosen = _chosen_methods(methods, transfer, shared)
    if scenario == "front" and methods is None:
        chosen = list(FRONT_METHODS[:1])
    if ham_hysteresis < 0:
        raise typer.BadParameter(f"must be >= 0, got {ham_hysteresis}", param_hint="'--ham-hysteresis'")
    preferences = list(preference or DEFAULT_TRANSFER_PREFERENCES) if transfer else []
    with usage_errors("'--backend'"):  # e.g. tqc, which the sbx backend does not train
        BenchmarkSettings(
            methods=[m for m in chosen if m not in ENV_ONLY_METHODS] or ["hddpg"],
            backend=backend,
            scenario="front" if scenario == "front" else "standard",
        )
    return chosen, preferences


def _env_record(shared: TermsEnv | None) -> EnvChoice | None:
    """The benchmark settings' record of another env than the snake (``None``: the snake)."""
    if shared is None:
        return None
    return {"env_id": shared.env_id, "env_kwargs": shared.env_kwargs, "terms": list(shared.terms)}


def _checked_options(
    settings: BenchmarkSettings,
    redo: str | None,
    resume: bool,
    out: Path,
    snapshot_dir: Path | None,
    executor: tuple[str, str | None],
) -> tuple[list[str], str | None]:
    """
    Check ``--workers-from``, ``--redo``, ``--snapshot`` and the executor before the folder is touched.

    :return: the methods to redo, and the Ray cluster's address (``None``: local processes).
    """
    with usage_errors("'--workers-from'"):
        check_workers_source(settings)
    redone = [m.strip() for m in redo.split(",") if m.strip()] if redo else []
    with usage_errors("'--redo'"):
        check_redo(settings, redone, resume)
    check_snapshot_option(settings, out, snapshot_dir, resume)
    return redone, cluster_address(*executor)


def _print_results(
    results: BenchmarkResults, out: Path, export_dir: Path | None, snapshot_dir: Path | None
) -> None:
    """The result tables, the wall time and the outputs; the export and snapshot; exit 1 naming every failed run."""
    for table in console_tables(results):
        console.print(_rich_table(table))
    console.print(
        f"Wall time: {wall_time_text(results)}.  Outputs in {out}: {', '.join(output_files_in(out))}"
    )
    if export_dir is not None:
        export_run(out, export_dir)
    if snapshot_dir is not None:
        take_snapshot(out, snapshot_dir)
    if results.failures:
        for label, message in results.failures.items():
            console.print(f"[red]failed[/] {label}: {message}")
        raise typer.Exit(1)

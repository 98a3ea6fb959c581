"""``hddpg-cli train-workers``, ``grow`` and ``train-manager``: the two halves of the hierarchy (paper Algorithm 1)."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from sb3_hddpg.artifacts.limits import MAX_MANAGER_MOTION
from sb3_hddpg.artifacts.manifests import RESUME_CHANGES
from sb3_hddpg.cli.app import app, console
from sb3_hddpg.cli.errors import CommandStopped
from sb3_hddpg.cli.options import (
    ENV_HELP,
    ENV_OPTIONS,
    RUN_OPTIONS,
    SNAKE_DEFAULT,
    BackendOpt,
    ForceOpt,
    ResumeOpt,
    at_least,
    count,
    discount,
    existing_dir,
    existing_file,
    prepare_out_dir,
    run_options_of,
    takes_options,
    terms_env_of,
    usage_errors,
)
from sb3_hddpg.envs.ids import WORKER_ENV_IDS
from sb3_hddpg.envs.weighted import parse_term_weights
from sb3_hddpg.evaluation import summaries_table
from sb3_hddpg.hierarchy.hierarchy import Hierarchy
from sb3_hddpg.hierarchy.selection import parse_preferences
from sb3_hddpg.metric_labels import MANAGER_REWARD_LABEL, MetricLabel, manager_warnings
from sb3_hddpg.training.agent import ALGO_NAMES, TrainingInterrupted, TrainingOutcome
from sb3_hddpg.training.backends import check_algo, resolve_backend
from sb3_hddpg.training.grow import SUPPORT_FILE, SupportOptions, check_growable, grow
from sb3_hddpg.training.manager import train_manager
from sb3_hddpg.training.manager_setup import MANAGER_ALGOS, ManagerOptions, setup_manager
from sb3_hddpg.training.term_critic import STATE_CRITIC_OPTIONS, TermCriticOptions, fit_state_critics
from sb3_hddpg.training.workers import (
    folder_algos,
    parse_worker_algorithms,
    plan_workers,
    train_workers,
)

#: train-manager's --env: where its default comes from.
MANAGER_ENV_NOTE = " Default: the shared env recorded in the workers' manifest."
CONFIG_HELP = "Hyperparameters in RL Zoo format (default: the bundled zoo_configs/ddpg.yml)."


@contextlib.contextmanager
def training_interrupt_exits() -> Iterator[None]:
    """Training stopped by Ctrl-C or SIGTERM (its checkpoint saved): say where (exit 130, as main decides)."""
    try:
        yield
    except TrainingInterrupted as interrupted:
        raise CommandStopped(str(interrupted)) from None


def metrics_table(title: str, rows: dict[str, dict], reward: MetricLabel | None = None) -> Table:
    """
    :func:`~sb3_hddpg.evaluation.summaries_table` drawn by rich.

    :param title: the table's title.
    :param rows: agent -> its evaluation summary.
    :param reward: what ``mean_reward`` is for these agents (default: the env's own reward).
    """
    summaries = summaries_table(title, rows, reward)
    table = Table(title=summaries.title, caption=summaries.caption)
    table.add_column("agent")
    for column in summaries.columns:  # folded, not cut, where a header word is wider than 80 columns allow
        table.add_column(column, justify="right", overflow="fold")
    for row in summaries.rows:
        table.add_row(*row)
    return table


# The options of `train_workers_command`.
_WorkerNamesOpt = Annotated[
    list[str] | None,
    typer.Option(
        "--workers",
        help=f"Workers to train, one per reward term (repeat the option). Default: every term of the env "
        f"(the snake arm: {sorted(WORKER_ENV_IDS)}).",
    ),
]
_WorkersEnvOpt = Annotated[str | None, typer.Option("--env", help=ENV_HELP + SNAKE_DEFAULT)]
_TermCriticOpt = Annotated[
    bool,
    typer.Option(
        "--term-critic/--no-term-critic",
        help="Train each off-policy worker's per-term critic (one Q head per term, for GPI and grow) on the "
        "transitions it collected, after it trains: gradient steps, no env steps.",
    ),
]
_KeepTransitionsOpt = Annotated[
    bool,
    typer.Option(
        "--keep-transitions",
        help="Also write each worker's transitions with their terms (NAME.transitions.npz), which grow "
        "warm-starts a neighbouring worker with.",
    ),
]
_WorkersWeightsOpt = Annotated[
    list[str] | None,
    typer.Option(
        "--weights",
        help="A worker on a weighting of the terms, e.g. goal=0.7,avoid=0.3 (repeat the option for more): "
        "trained on the weighted sum of the normalised terms, named mix-goal70-avoid30. With --weights and "
        "no --workers only the weighted workers train.",
    ),
]
_WorkersAlgoOpt = Annotated[
    str | None,
    typer.Option(
        "--algo",
        help=f"Each worker's algorithm, e.g. goal=crossq,avoid=sac, or one for all; one of {list(ALGO_NAMES)} "
        "that acts in the worker's action space (default: the snake arm's goal=ddpg,avoid=sac; ddpg on "
        "another env).",
    ),
]
_WorkersConfigOpt = Annotated[
    Path | None,
    typer.Option(
        "--config",
        callback=existing_file,
        help="Hyperparameters in RL Zoo format (default: each worker's algorithm's bundled zoo_configs/<algo>.yml).",
    ),
]
_WorkersTimestepsOpt = Annotated[
    int | None,
    typer.Option(
        "--timesteps", callback=at_least(1), help="Steps per worker (default: the config's n_timesteps)."
    ),
]
_WorkersOutOpt = Annotated[Path, typer.Option("--out", help="Run folder; workers go to OUT/workers/.")]
_ResumeChangingOpt = Annotated[
    list[str] | None,
    typer.Option(
        "--resume-changing",
        help="With --resume: continue although the run's algo, seed or config differs from this command's "
        "(repeat for several; refused by default); the manifest then records the new value.",
    ),
]


@app.command("train-workers")
@takes_options(*ENV_OPTIONS, *RUN_OPTIONS)
def train_workers_command(
    context: typer.Context,
    workers: _WorkerNamesOpt = None,
    weights: _WorkersWeightsOpt = None,
    term_critic: _TermCriticOpt = True,
    keep_transitions: _KeepTransitionsOpt = False,
    env: _WorkersEnvOpt = None,
    algo: _WorkersAlgoOpt = None,
    config: _WorkersConfigOpt = None,
    timesteps: _WorkersTimestepsOpt = None,
    out: _WorkersOutOpt = Path("runs/workers"),
    resume: ResumeOpt = False,
    force: ForceOpt = False,
    backend: BackendOpt = None,
    resume_changing: _ResumeChangingOpt = None,
) -> None:
    """Train each worker as a plain SB3 model (its default learner unless --algo says) on its own reward (paper Algorithm 1)."""
    shared = terms_env_of(context, env)
    # Each known and given once; default: one per term of the env, none when --weights gives the workers.
    known = list(shared.terms) if shared is not None else sorted(WORKER_ENV_IDS)
    names = list(workers) if workers else ([] if weights else list(known))
    unknown = [w for w in names if w not in known]
    duplicates = sorted({w for w in names if names.count(w) > 1})
    if unknown or duplicates:
        problem = f"unknown worker {unknown[0]!r}" if unknown else f"worker {duplicates[0]!r} given twice"
        raise typer.BadParameter(f"{problem}; choose from {known}", param_hint="'--workers'")
    with usage_errors("'--weights'"):
        weightings = [parse_term_weights(text) for text in weights or []]
        # Names and weights only here; --algo and --config are checked below, each under its own option.
        all_names = [worker.name for worker in plan_workers(names, weightings, None, shared)]
    with usage_errors("'--algo'"):
        algos = parse_worker_algorithms(algo, all_names, shared) if algo is not None else {}
    if resume:  # a weighted worker joins the folder's kind (folder_algos), as train_workers will train it
        with usage_errors("'--out'"):
            algos = folder_algos(out, weightings, shared, algos)
    with usage_errors("'--config'"):  # a bad block fails now, not after the first worker has trained
        planned = plan_workers(names, weightings, config, shared, algos)
    with usage_errors("'--backend'"):  # also a config's `backend: sbx` where SBX is not installed
        for worker in planned:
            check_algo(worker.algo, resolve_backend(backend, worker.hyperparams.backend))
    unknown = [c for c in resume_changing or [] if c not in RESUME_CHANGES]
    if unknown or (resume_changing and not resume):
        problem = (
            f"expected some of {list(RESUME_CHANGES)}, got {unknown[0]!r}" if unknown else "needs --resume"
        )
        raise typer.BadParameter(problem, param_hint="'--resume-changing'")
    prepare_out_dir(context, out, resume, force)

    def done(name: str, outcome: TrainingOutcome) -> None:
        console.print(
            f"[green]✓[/] worker [bold]{name}[/]: {outcome.num_timesteps} steps"
            f"{' (stopped on plateau)' if outcome.stopped_early else ''} -> {outcome.model_path}"
        )

    with training_interrupt_exits():
        manifest = train_workers(
            out,
            workers=names,
            config=config,
            run=run_options_of(context),
            on_worker_done=done,
            env=shared,
            algos=algos,
            weights=weightings,
            term_critic=TermCriticOptions() if term_critic else None,
            keep_transitions=keep_transitions,
            resume_changes=resume_changing or (),
        ).manifest
    trained = [worker.name for worker in planned]
    rows = {name: entry["metrics"] for name, entry in manifest["workers"].items() if name in trained}
    console.print(metrics_table(f"Workers in {out / 'workers'} (best evaluation)", rows))
    console.print(
        f"Manifest: {out / 'workers' / 'manifest.json'}   TensorBoard: tensorboard --logdir {out / 'tensorboard'}"
    )


# The options of `train_manager_command`.
_ManagerWorkersDirOpt = Annotated[
    Path,
    typer.Option(
        "--workers",
        callback=existing_dir,
        help="Run folder of train-workers (holding workers/manifest.json).",
    ),
]
_ManagerWorkerNamesOpt = Annotated[
    list[str] | None,
    typer.Option(
        "--worker", help="Use only these workers, in this order (repeat; default: all in the manifest)."
    ),
]
_ManagerPreferOpt = Annotated[
    str | None, typer.Option("--prefer", help="A worker to prefer (paper Section 3.4), e.g. goal.")
]
_ManagerBiasOpt = Annotated[float, typer.Option("--bias", help="The preferred worker's extra factor, > 0.")]
_ManagerPreferenceOpt = Annotated[
    str | None,
    typer.Option(
        "--preference",
        help="Every factor explicitly, e.g. goal=1.15,avoid=1.0 (wins over --prefer). The factors scale the "
        "manager's reward too: to change only the trade-off, keep their sum at the number of workers "
        "(docs/MANAGER.md).",
    ),
]
_ManagerTrainPreferencesOpt = Annotated[
    str | None,
    typer.Option(
        "--preferences",
        help="Train one manager for every preference: 'ratio-sweep' (each worker weighted 1-4 times the "
        "others: 4:1 ... 1:4), 'ratio-sweep:MAX' (ratios doubling up to MAX, e.g. 16), 'dirichlet' or "
        "'dirichlet:ALPHA', or preferences with one sum separated by "
        "';' (goal=1.6,avoid=0.4;goal=0.4,avoid=1.6). The manager observes the preference; choose it at "
        "run time with --preference of evaluate, record and plot-selection.",
    ),
]
_ManagerRelabelFractionOpt = Annotated[
    float | None,
    typer.Option(
        "--relabel-fraction",
        help="With --preferences: the share of replayed steps paid at another preference (default 0.5).",
    ),
]
_ManagerInitFromHamOpt = Annotated[
    float | None,
    typer.Option(
        "--init-from-ham",
        metavar="THRESHOLD",
        help="Start from the hand-written rule: before RL the manager imitates HAM with this threshold "
        "(its replay buffer filled with HAM's choices), so RL starts at HAM's level.",
    ),
]
_ManagerInitFromGpiOpt = Annotated[
    bool,
    typer.Option(
        "--init-from-gpi",
        help="Start from GPI over the workers' per-term critics (see fit-critics): before RL the manager "
        "imitates GPI's choice at each episode's preference, so RL starts at GPI's level.",
    ),
]
_ManagerSelectionOpt = Annotated[
    str | None,
    typer.Option(
        "--selection",
        help="sample (the paper's), argmax, mix, or another registered mode (default: the config's).",
    ),
]
_ManagerOptionStepsOpt = Annotated[
    int | None,
    typer.Option(
        "--option-steps",
        callback=count("option_steps"),
        help="Env steps per manager decision (default: the config's).",
    ),
]
_ManagerOptionEndOpt = Annotated[
    str | None,
    typer.Option(
        "--option-end",
        help="Options that also end by state: distance=0.5 (an obstacle comes within half the sensor range, or "
        "leaves it; several edges: distance=0.25/0.5), touch (the goal is touched or lost), or both "
        "(distance=0.5,touch); --option-steps stays the longest option.",
    ),
]
_ManagerMotionOpt = Annotated[
    float | None,
    typer.Option(
        "--manager-motion",
        min=0.0,
        max=MAX_MANAGER_MOTION,
        help="The manager also sees how its state moved over the last env step, scaled by this factor and "
        "clipped to [-1, 1] (e.g. 20 for the snake arm); 0: the state only.",
    ),
]
_ManagerGammaOpt = Annotated[
    float | None,
    typer.Option(
        "--gamma",
        callback=discount,
        help="The manager's discount per decision (default: the config block's, which fits its options' "
        "length: with shorter --option-steps, a discount closer to 1 keeps the horizon in env steps).",
    ),
]
_ManagerAlgoOpt = Annotated[
    str,
    typer.Option(
        "--algo",
        help=f"The manager's algorithm, one of {list(MANAGER_ALGOS)}: DDPG is the paper's; the others that act "
        "in Box spaces take the same action, DQN and QR-DQN pick a worker's index (selection 'discrete') "
        "(default config: the bundled zoo_configs/<algo>.yml).",
    ),
]
_ManagerConfigOpt = Annotated[
    Path | None,
    typer.Option("--config", callback=existing_file, help=CONFIG_HELP + " Its 'manager' block is used."),
]
_ManagerTimestepsOpt = Annotated[
    int | None,
    typer.Option(
        "--timesteps",
        callback=at_least(1),
        help="The manager's budget in decisions (SB3 steps of the manager; each runs --option-steps env "
        "steps; default: the config's n_timesteps).",
    ),
]
_ManagerOutOpt = Annotated[
    Path, typer.Option("--out", help="Run folder; the bundle goes to OUT/hierarchy.zip.")
]
_ManagerTrustOpt = Annotated[
    bool, typer.Option("--trust", help="Load the workers with SB3's full loader (runs code in the files).")
]
_ManagerEnvOpt = Annotated[str | None, typer.Option("--env", help=ENV_HELP + MANAGER_ENV_NOTE)]


@app.command("train-manager")
@takes_options(*RUN_OPTIONS, *ENV_OPTIONS)
def train_manager_command(
    context: typer.Context,
    workers_dir: _ManagerWorkersDirOpt = Path("runs/workers"),
    names: _ManagerWorkerNamesOpt = None,
    prefer: _ManagerPreferOpt = None,
    bias: _ManagerBiasOpt = 0.15,
    preference: _ManagerPreferenceOpt = None,
    train_preferences: _ManagerTrainPreferencesOpt = None,
    relabel_fraction: _ManagerRelabelFractionOpt = None,
    init_from_ham: _ManagerInitFromHamOpt = None,
    init_from_gpi: _ManagerInitFromGpiOpt = False,
    selection: _ManagerSelectionOpt = None,
    option_steps: _ManagerOptionStepsOpt = None,
    option_end: _ManagerOptionEndOpt = None,
    manager_motion: _ManagerMotionOpt = None,
    gamma: _ManagerGammaOpt = None,
    algo: _ManagerAlgoOpt = "ddpg",
    config: _ManagerConfigOpt = None,
    timesteps: _ManagerTimestepsOpt = None,
    out: _ManagerOutOpt = Path("runs/manager"),
    resume: ResumeOpt = False,
    force: ForceOpt = False,
    trust: _ManagerTrustOpt = False,
    backend: BackendOpt = None,
    env: _ManagerEnvOpt = None,
) -> None:
    """
    Train the manager: a plain SB3 DDPG (or TD3, SAC) whose action selects a worker (paper Algorithm 1). Its
    budget and progress bar count decisions; its table reports the env's reward terms and the return of the
    normalised terms, and goal touches and contacts only where the env reports them (the snake arm).
    """
    algo = algo.lower()
    if algo not in MANAGER_ALGOS:
        raise typer.BadParameter(f"must be one of {list(MANAGER_ALGOS)}, got {algo!r}", param_hint="'--algo'")
    with usage_errors("'--preference'"):
        preferences = parse_preferences(preference) if preference is not None else None
    if relabel_fraction is not None and train_preferences is None:
        raise typer.BadParameter("applies with --preferences only", param_hint="'--relabel-fraction'")
    shared = terms_env_of(context, env)
    options = ManagerOptions(
        worker_names=names or None,
        prefer=prefer,
        bias=bias,
        preferences=preferences,
        selection=selection,
        option_steps=option_steps,
        config=config,
        trusted=trust,
        env_id=shared.env_id if shared is not None else None,
        env_kwargs=shared.env_kwargs if shared is not None else None,
        algo=algo,
        manager_preferences=train_preferences,
        relabel_fraction=0.5 if relabel_fraction is None else relabel_fraction,
        init_from_ham=init_from_ham,
        init_from_gpi=init_from_gpi or None,
        option_end=option_end,
        manager_motion=manager_motion,
        gamma=gamma,
    )
    # Checked before the output folder is touched: the library checks the set-up, here its backend.
    with usage_errors():
        setup = setup_manager(workers_dir, options)
    with usage_errors("'--backend'"):
        resolved = resolve_backend(backend, setup.hyperparams.backend)
        check_algo(options.algo, resolved)
        if setup.start is not None and resolved != "sb3":
            raise ValueError(
                "a start from HAM or GPI (--init-from-ham, --init-from-gpi) fits SB3 (torch) managers: "
                "use --backend sb3"
            )
    prepare_out_dir(context, out, resume, force)
    with training_interrupt_exits():
        result = train_manager(setup, out, run=run_options_of(context))
    _print_manager(result.hierarchy, result.outcome, out)


def _print_manager(hierarchy: Hierarchy, outcome: TrainingOutcome, out: Path) -> None:
    """The trained manager's evaluation, its worker choices, its budget and bundle, and how it started."""
    console.print(
        metrics_table(
            f"Manager over {hierarchy.names} (best evaluation)",
            {"manager": outcome.metrics},
            reward=MANAGER_REWARD_LABEL,
        )
    )
    rates = outcome.metrics.get("selection_rate", {})
    if rates:
        console.print(
            "Worker choices (% of steps): " + ", ".join(f"{n} {100 * r:.0f}" for n, r in rates.items())
        )
    for warning in manager_warnings(outcome.metrics):
        console.print(f"[yellow]Note:[/] {warning}")
    option_steps = hierarchy.config.option_steps
    console.print(
        f"Trained {outcome.num_timesteps:,} decisions"
        + (f" of up to {option_steps} env steps each" if option_steps > 1 else " (one env step each)")
        + f". Preferences: {hierarchy.config.preferences}   Bundle: {out / 'hierarchy.zip'}"
    )
    for key, teacher in (("init_from_ham", "HAM"), ("init_from_gpi", "GPI")):
        start = hierarchy.metadata.get(key)
        if start:
            rule = f" (threshold {start['threshold']:g})" if "threshold" in start else ""
            console.print(
                f"Before RL the manager imitated {teacher}{rule} on {start['decisions']:,} decisions: it "
                f"agrees with {teacher} on {start['agreement']:.0%} of them"
            )
    if hierarchy.preference_space is not None:
        console.print(f"Conditioned on {hierarchy.preference_space.describe()}")


@app.command("grow")
@takes_options("seed", "n_envs", "eval_freq", "eval_episodes", "checkpoint_freq", "threads", "progress_bar")
def grow_command(
    context: typer.Context,
    workers: Path = typer.Option(
        Path("runs/workers"),
        "--workers",
        help="Run folder of train-workers holding a per-term worker with its critic for every term; the new "
        "workers are added to it.",
    ),
    support: int = typer.Option(
        4, "--support", help="The most workers the support holds, per-term ones included."
    ),
    budget: int = typer.Option(150_000, "--budget", help="Env steps all new workers may train together."),
    tolerance: float = typer.Option(
        0.01,
        "--tolerance",
        help="Stop when the largest optimistic gain is below this fraction of the front's value.",
    ),
    start_states: int = typer.Option(
        32, "--start-states", help="Development episodes whose start states value each worker."
    ),
    config: Path | None = typer.Option(
        None,
        "--config",
        help="Hyperparameters in RL Zoo format for the new workers (block <env>/mix, else the env's).",
    ),
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
    with usage_errors("'--workers'"):  # before anything trains; a failure while training is no usage error
        check_growable(root, resume)
    with training_interrupt_exits():
        record = grow(root, options, run=run_options_of(context), config=config)
    table = Table(title=f"Support in {root / 'workers'}")
    for column in ("worker", "weights", "gain", "env steps", "warm start"):
        table.add_column(column)
    for step in record.added:
        weights = ", ".join(f"{t}={w:.3g}" for t, w in step.weights.items())
        table.add_row(step.name, weights, f"{step.gain:.4g}", str(step.steps), step.warm_start or "-")
    console.print(table)
    console.print(f"Stopped: {record.stopped}.  Record: {root / 'workers' / SUPPORT_FILE}")


@app.command("fit-critics")
@takes_options("seed")
def fit_critics_command(
    context: typer.Context,
    workers: Path = typer.Option(
        Path("runs/workers"), "--workers", help="Run folder of train-workers whose workers get the critics."
    ),
    names: list[str] | None = typer.Option(None, "--worker", help="A worker to fit (repeat; default: all)."),
    rollout_steps: int = typer.Option(
        STATE_CRITIC_OPTIONS.rollout_steps,
        "--rollout-steps",
        help="Env steps each worker is rolled out for, with exploration noise, to fit its critic on.",
    ),
    steps: int = typer.Option(
        STATE_CRITIC_OPTIONS.steps or 1, "--steps", help="Gradient steps of each critic's TD fitting."
    ),
) -> None:
    """Give each worker a per-term critic fitted on rollouts of its policy, what GPI (Hierarchy.gpi, --init-from-gpi) acts with: a state value over the full shared state, or a discrete worker's Q over its actions."""
    if not (workers / "workers" / "manifest.json").is_file() and not (workers / "manifest.json").is_file():
        raise typer.BadParameter(
            f"no workers manifest in {str(workers)!r}; run train-workers first", param_hint="'--workers'"
        )
    with usage_errors("'--rollout-steps'"):
        options = replace(STATE_CRITIC_OPTIONS, rollout_steps=rollout_steps, steps=steps)
    run = run_options_of(context)
    with usage_errors("'--workers'"):
        facts = fit_state_critics(workers, names or None, options, seed=run.seed)
    table = Table(title=f"Critics fitted on rollouts in {workers}")
    for column in ("worker", "kind", "env steps", "TD steps", "last TD loss"):
        table.add_column(column)
    for name, fact in facts.items():
        table.add_row(
            name, str(fact["kind"]), f"{fact['env_steps']:,}", f"{fact['steps']:,}", f"{fact['td_loss']:.4g}"
        )
    console.print(table)

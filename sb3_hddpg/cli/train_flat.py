"""``hddpg-cli train-flat``: the single-agent baselines (DDPG, TD3, SAC, TQC) on the combined reward."""

from __future__ import annotations

from pathlib import Path

import typer

from sb3_hddpg.cli.app import app, console
from sb3_hddpg.cli.options import (
    ENV_HELP,
    ENV_OPTIONS,
    RUN_OPTIONS,
    SNAKE_DEFAULT,
    BackendOpt,
    ForceOpt,
    ResumeOpt,
    at_least,
    existing_file,
    prepare_out_dir,
    run_options_of,
    takes_options,
    terms_env_of,
    usage_errors,
)
from sb3_hddpg.cli.train import metrics_table, training_interrupt_exits
from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID
from sb3_hddpg.hierarchy.preference import make_preference_env
from sb3_hddpg.hierarchy.selection import parse_preferences
from sb3_hddpg.training.agent import ALGO_NAMES
from sb3_hddpg.training.backends import algo_class, check_algo, resolve_backend
from sb3_hddpg.training.config import default_config, load_hyperparams
from sb3_hddpg.training.flat import check_flat_env, train_flat


@app.command("train-flat")
@takes_options(*ENV_OPTIONS, *(name for name in RUN_OPTIONS if name != "checkpoint_freq"))
def train_flat_command(
    context: typer.Context,
    algo: str = typer.Option("ddpg", "--algo", help=f"Algorithm, one of {list(ALGO_NAMES)}."),
    config: Path | None = typer.Option(
        None,
        "--config",
        callback=existing_file,
        help="Hyperparameters in RL Zoo format (default: the bundled zoo_configs/<algo>.yml).",
    ),
    timesteps: int | None = typer.Option(
        None, "--timesteps", callback=at_least(1), help="Training steps (default: the config's n_timesteps)."
    ),
    out: Path = typer.Option(
        Path("runs/flat"), "--out", help="Run folder; the model goes to OUT/flat/<algo>.zip."
    ),
    resume: ResumeOpt = False,
    force: ForceOpt = False,
    backend: BackendOpt = None,
    preference: str | None = typer.Option(
        None,
        "--preference",
        help="Learn the preference-weighted sum of the normalised terms, e.g. time=1,fuel=2 (terms not named "
        "get 1); default: the env's own reward (the normalised sum).",
    ),
    env: str | None = typer.Option(None, "--env", help=ENV_HELP + SNAKE_DEFAULT),
) -> None:
    """Train one SB3 agent on both objectives at once (the paper's single-DDPG baseline)."""
    shared = terms_env_of(context, env)
    env_id, env_kwargs = (shared.env_id, shared.env_kwargs) if shared else (SNAKE_REACH_ENV_ID, None)
    with usage_errors("'--preference'"):
        preferences = parse_preferences(preference) if preference is not None else None
        if preferences is not None:
            make_preference_env(env_id, env_kwargs or {}, preferences).close()
    algo = algo.lower()
    if algo not in ALGO_NAMES:
        raise typer.BadParameter(f"must be one of {list(ALGO_NAMES)}, got {algo!r}", param_hint="'--algo'")
    with usage_errors("'--config'"):  # a bad block fails now, as a usage error, not after start-up
        hyperparams = load_hyperparams(
            shared.config_key if shared is not None else env_id,
            algo_class(algo),
            config if config is not None else default_config(algo),
        )
    with usage_errors("'--algo'"):
        check_flat_env(algo, env_id, env_kwargs)
    with usage_errors("'--backend'"):
        check_algo(algo, resolve_backend(backend, hyperparams.backend))
    prepare_out_dir(context, out, resume, force)
    with training_interrupt_exits():
        result = train_flat(
            out,
            algo=algo,
            config=config,
            run=run_options_of(context),
            env_id=env_id,
            env_kwargs=env_kwargs,
            preferences=preferences,
        )
    entry = result.manifest["models"][algo]
    if result.outcome is None:
        console.print(f"{algo} was already trained for {entry['timesteps_requested']} steps; kept it.")
    console.print(metrics_table(f"Flat {algo} on {env_id} (best evaluation)", {algo: entry["metrics"]}))
    console.print(f"Model: {out / 'flat' / entry['file']}   Manifest: {out / 'flat' / 'manifest.json'}")

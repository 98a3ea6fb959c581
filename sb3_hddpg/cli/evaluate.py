"""``hddpg-cli evaluate PATH``: the env's metrics for any policy, on fixed evaluation seeds."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from sb3_hddpg.cli.app import app, console
from sb3_hddpg.cli.options import at_least, seed_range, usage_errors, writable_file

#: The first evaluation seed (``sb3_hddpg.evaluation.EVAL_SEED_BASE``, repeated here so that ``--help``
#: and usage errors need not import the library).
EVAL_SEED_BASE = 10_000


@app.command("evaluate")
def evaluate_command(
    path: str = typer.Argument(
        ..., help="A worker or flat zip, a hierarchy.zip, a ham.json, or 'random' / 'scripted'."
    ),
    env_id: str | None = typer.Option(
        None, "--env", help="Env id to evaluate on (default: the one it was trained on)."
    ),
    episodes: int = typer.Option(20, "--episodes", callback=at_least(1), help="Evaluation episodes."),
    seed: int = typer.Option(
        EVAL_SEED_BASE,
        "--seed",
        callback=seed_range,
        help="Seed of the first episode (episode k uses seed + k).",
    ),
    deterministic: bool = typer.Option(True, "--deterministic/--stochastic", help="Deterministic actions."),
    json_path: Path | None = typer.Option(
        None, "--json", callback=writable_file, help="Also write the metrics (and every episode) as JSON."
    ),
    trust: bool = typer.Option(
        False,
        "--trust",
        help="Allow SB3's full loader, which runs code stored in the file: only for files you trust.",
    ),
    algo: str | None = typer.Option(
        None, "--algo", help="Algorithm of a zip without manifest (with --trust)."
    ),
) -> None:
    """Evaluate a policy: mean reward, goal-touch rate, collisions, success, clearance (and worker choices)."""
    from sb3_hddpg.evaluation import evaluate
    from sb3_hddpg.io import atomic_write_json
    from sb3_hddpg.loading import load_policy

    # Everything that depends only on the arguments (the file, its hashes and spaces, the env id) is
    # checked here, as a usage error; what fails during the episodes is not.
    with usage_errors("'PATH'"):
        loaded = load_policy(path, env_id=env_id, trusted=trust, algo=algo)
    with usage_errors("'--env'"):
        env = loaded.make_env(env_id)
    result = evaluate(loaded.policy, env, n_episodes=episodes, seed=seed, deterministic=deterministic)
    summary = result.summary()
    table = Table(
        title=f"{loaded.kind} {loaded.name!r} on {env_id or loaded.env_id}: {episodes} episodes from seed {seed}"
    )
    table.add_column("metric")
    table.add_column("value", justify="right")
    for key, value in summary.items():
        if isinstance(value, dict):
            for name, rate in value.items():
                table.add_row(f"{key}: {name}", f"{rate:.1%}")
        elif isinstance(value, float):
            table.add_row(key, f"{value:.3f}")
        else:
            table.add_row(key, str(value))
    console.print(table)
    if json_path is not None:
        payload = {
            "path": str(path),
            "kind": loaded.kind,
            "env_id": env_id or loaded.env_id,
            **result.to_dict(),
        }
        atomic_write_json(json_path, payload)
        console.print(f"Metrics written to {json_path}")

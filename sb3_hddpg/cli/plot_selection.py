"""``hddpg-cli plot-selection PATH --out FILE.png``: when the manager picks which worker, and why."""

from __future__ import annotations

from pathlib import Path

import typer

from sb3_hddpg.cli.app import app, console
from sb3_hddpg.cli.options import at_least, seed_range, usage_errors
from sb3_hddpg.cli.record import TRUST_HELP
from sb3_hddpg.evaluation import EVAL_SEED_BASE
from sb3_hddpg.hierarchy.loading import load_policy
from sb3_hddpg.media.figures import plot_selection_timeline
from sb3_hddpg.media.trace import selected_names, trace_episodes


@app.command("plot-selection")
def plot_selection_command(
    path: str = typer.Argument(..., help="A hierarchy.zip (or its folder) or a ham.json."),
    out: Path = typer.Option(Path("selection.png"), "--out", help="The PNG to write."),
    episodes: int = typer.Option(1, "--episodes", callback=at_least(1), help="Episodes, one after another."),
    seed: int = typer.Option(
        EVAL_SEED_BASE,
        "--seed",
        callback=seed_range,
        help="Seed of the first episode (episode k uses seed + k).",
    ),
    env_id: str | None = typer.Option(
        None, "--env", help="Env id to act in (default: the one it was trained on)."
    ),
    max_steps: int | None = typer.Option(
        None,
        "--max-steps",
        callback=at_least(1),
        help="Cut every episode to this many steps (default: full).",
    ),
    trust: bool = typer.Option(False, "--trust", help=TRUST_HELP),
) -> None:
    """Per step: the worker chosen and the manager's probabilities, beside obstacle clearance and goal distance."""

    if out.suffix.lower() != ".png":
        raise typer.BadParameter(f"expected a .png file, got {str(out)!r}", param_hint="'--out'")
    with usage_errors("'PATH'"):  # the model named on the command line is unusable
        loaded = load_policy(path, env_id=env_id, trusted=trust)
    names = selected_names(loaded.policy)
    if not names:
        raise typer.BadParameter(
            f"{path!r} is a {loaded.kind}, which selects no worker; give a hierarchy bundle or a HAM switch",
            param_hint="'PATH'",
        )
    env = loaded.make_env(env_id, **({"max_episode_steps": max_steps} if max_steps else {}))
    records, result = trace_episodes(loaded.policy, env, n_episodes=episodes, seed=seed)
    base = env.unwrapped
    written = plot_selection_timeline(
        records,
        out,
        names=names,
        title=f"{loaded.kind} {loaded.name!r} on {env_id or loaded.env_id}, seeds {seed}..{seed + episodes - 1}",
        sensor_range=getattr(base, "sensor_range", None),
        touch_radius=getattr(base, "touch_radius", None),
    )
    env.close()
    rates = result.summary().get("selection_rate", {})
    console.print(
        f"[green]✓[/] {len(records)} steps -> [bold]{written}[/]   "
        + ", ".join(f"{n} acted {r:.0%}" for n, r in rates.items())
    )

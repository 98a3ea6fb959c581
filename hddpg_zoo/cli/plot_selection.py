"""``hddpg-cli plot-selection PATH --out FILE.png``: when the manager picks which worker, and why."""

from __future__ import annotations

from pathlib import Path

import typer

from hddpg_zoo.cli.record import ActInEnvOpt, EpisodeSeedOpt, MaxStepsOpt, TrustOpt, watched_policy
from hddpg_zoo.media.figures import plot_selection_timeline
from sb3_hddpg.cli.app import app, console
from sb3_hddpg.cli.options import (
    EpisodeStepsOpt,
    InfoKeyOpt,
    ReplaceFileOpt,
    RunPreferenceOpt,
    TermBoundsOpt,
    TermsOpt,
    count,
    output_file,
    usage_errors,
)
from sb3_hddpg.envs.contract import proximity_of
from sb3_hddpg.evaluation import EVAL_SEED_BASE
from sb3_hddpg.media.trace import selected_names, trace_episodes


@app.command("plot-selection")
def plot_selection_command(
    path: str = typer.Argument(..., help="A hierarchy.zip (or its folder) or a ham.json."),
    out: Path = typer.Option(Path("selection.png"), "--out", help="The PNG to write."),
    episodes: int = typer.Option(
        1, "--episodes", callback=count("episodes"), help="Episodes, one after another."
    ),
    seed: EpisodeSeedOpt = EVAL_SEED_BASE,
    env_id: ActInEnvOpt = None,
    terms: TermsOpt = None,
    term_bounds: TermBoundsOpt = None,
    info_key: InfoKeyOpt = None,
    episode_steps: EpisodeStepsOpt = None,
    max_steps: MaxStepsOpt = None,
    trust: TrustOpt = False,
    force: ReplaceFileOpt = False,
    preference: RunPreferenceOpt = None,
) -> None:
    """
    Per step: the worker chosen and the manager's probabilities, beside obstacle clearance and goal distance
    (an env without them, i.e. without the proximity capability: its reward terms).
    """

    if out.suffix.lower() != ".png":
        raise typer.BadParameter(f"expected a .png file, got {str(out)!r}", param_hint="'--out'")
    output_file(out, force, "'--out'")
    watched = watched_policy(
        path, env_id, terms, term_bounds, info_key, episode_steps, max_steps, trust, preference
    )
    loaded = watched.loaded
    names = selected_names(loaded.policy)
    if not names:
        raise typer.BadParameter(
            f"{path!r} is a {loaded.kind}, which selects no worker; give a hierarchy bundle or a HAM switch",
            param_hint="'PATH'",
        )
    with usage_errors(watched.env_option):
        env = loaded.make_env(watched.env_id, **watched.env_kwargs)
    records, result = trace_episodes(loaded.policy, env, n_episodes=episodes, seed=seed)
    # The clearance and goal panels' reference lines come from the env's declared proximity; an env
    # without it gets its reward terms in those panels instead.
    proximity = proximity_of(env)
    written = plot_selection_timeline(
        records,
        out,
        names=names,
        title=f"{loaded.kind} {loaded.name!r} on {env_id or loaded.env_id}, seeds {seed}..{seed + episodes - 1}",
        sensor_range=proximity.sensor_range if proximity else None,
        touch_radius=proximity.touch_radius if proximity else None,
    )
    env.close()
    rates = result.summary().get("selection_rate", {})
    console.print(
        f"[green]✓[/] {len(records)} steps -> [bold]{written}[/]   "
        + ", ".join(f"{n} acted {r:.0%}" for n, r in rates.items())
    )
    if proximity is None:
        console.print(
            f"Obstacle clearance and goal distance: not available for {watched.env_id or loaded.env_id} "
            "(it declares no proximity); its reward terms are plotted instead."
        )

"""``hddpg-cli package PATH --out DIR``: a huggingface_sb3-style folder, made offline."""

from __future__ import annotations

from pathlib import Path

import typer

from hddpg_zoo.cli.record import TrustOpt
from hddpg_zoo.packaging import check_package_folder, package_policy
from sb3_hddpg.cli.app import app, console
from sb3_hddpg.cli.options import count, seed_range, usage_errors
from sb3_hddpg.evaluation import EVAL_SEED_BASE
from sb3_hddpg.hierarchy.loading import load_policy


@app.command("package")
def package_command(
    path: str = typer.Argument(..., help="A worker or flat zip, or a hierarchy.zip (or its folder)."),
    out: Path = typer.Option(..., "--out", help="The package folder to create."),
    episodes: int = typer.Option(10, "--episodes", callback=count("episodes"), help="Evaluation episodes."),
    seed: int = typer.Option(
        EVAL_SEED_BASE, "--seed", callback=seed_range, help="Seed of the first evaluation episode."
    ),
    video_steps: int | None = typer.Option(
        None,
        "--video-steps",
        callback=count("video_steps"),
        help="Length of replay.mp4 in steps (default: one episode).",
    ),
    force: bool = typer.Option(False, "--force", help="Replace a folder that is not empty."),
    trust: TrustOpt = False,
) -> None:
    """Model zip (or bundle + manifest), model card, config.json, results.json and replay.mp4 in one folder."""

    with usage_errors("'--out'"):  # refused before the model is even loaded
        check_package_folder(out, force)
    with usage_errors("'PATH'"):  # the model named on the command line is unusable
        loaded = load_policy(path, trusted=trust)
    with console.status(f"Evaluating and recording {loaded.kind} {loaded.name!r}…"):
        result = package_policy(
            loaded, path, out, n_eval_episodes=episodes, seed=seed, video_steps=video_steps, force=force
        )
    console.print(
        f"[green]✓[/] {result.folder}: mean reward {result.results['mean_reward']:.2f} ± "
        f"{result.results['std_reward']:.2f} over {episodes} episodes"
    )
    for item in sorted(result.folder.iterdir()):
        console.print(f"  {item.name}{'/' if item.is_dir() else ''}")

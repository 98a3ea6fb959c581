"""``hddpg-cli record PATH --out FILE.gif|FILE.mp4``: watch any policy, with the manager's choices drawn."""

from __future__ import annotations

from pathlib import Path

import typer

from sb3_hddpg.cli.app import app, console
from sb3_hddpg.cli.options import at_least, seed_range, usage_errors
from sb3_hddpg.evaluation import EVAL_SEED_BASE
from sb3_hddpg.hierarchy.loading import load_policy
from sb3_hddpg.media.video import check_video_path, record_video

POLICY_HELP = "A worker or flat zip, a hierarchy.zip (or its folder), a ham.json, or 'random' / 'scripted' (Jacobian-transpose) / 'ik' (damped-least-squares IK)."
TRUST_HELP = "Allow SB3's full loader, which runs code stored in the file: only for files you trust."


@app.command("record")
def record_command(
    path: str = typer.Argument(..., help=POLICY_HELP),
    out: Path = typer.Option(..., "--out", help="The video to write: FILE.gif or FILE.mp4."),
    episodes: int = typer.Option(1, "--episodes", callback=at_least(1), help="Episodes to record."),
    seed: int = typer.Option(
        EVAL_SEED_BASE,
        "--seed",
        callback=seed_range,
        help="Seed of the first episode (episode k uses seed + k).",
    ),
    fps: int = typer.Option(
        10, "--fps", callback=at_least(1), help="Frames per second (the env runs at 10)."
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
    deterministic: bool = typer.Option(True, "--deterministic/--stochastic", help="Deterministic actions."),
    trust: bool = typer.Option(False, "--trust", help=TRUST_HELP),
    algo: str | None = typer.Option(
        None, "--algo", help="Algorithm of a zip without manifest (with --trust)."
    ),
) -> None:
    """Render a policy to a GIF or MP4; for a hierarchy or HAM each frame shows the acting worker and the odds."""

    try:
        check_video_path(out)
    except ValueError as error:
        raise typer.BadParameter(str(error), param_hint="'--out'") from None
    with usage_errors("'PATH'"):  # the model named on the command line is unusable
        loaded = load_policy(path, env_id=env_id, trusted=trust, algo=algo)
    limit = {"max_episode_steps": max_steps} if max_steps else {}
    env = loaded.make_env(env_id, render_mode="rgb_array", **limit)
    with console.status(f"Recording {episodes} episode(s) of {loaded.kind} {loaded.name!r}…"):
        result = record_video(
            loaded.policy,
            env,
            out,
            episodes=episodes,
            seed=seed,
            fps=fps,
            deterministic=deterministic,
            title=loaded.name if loaded.name == loaded.kind else f"{loaded.kind}: {loaded.name}",
        )
    env.close()
    summary = result.evaluation.summary()
    console.print(
        f"[green]✓[/] {result.frames} frames ({result.size[0]}×{result.size[1]}, {fps} fps) -> [bold]{result.path}[/]"
        f"   mean reward {summary['mean_reward']:.1f}, goal touch {summary['goal_touch_rate']:.1%}, "
        f"collisions/ep {summary['collisions_per_episode']:.1f}"
    )

"""``hddpg-cli rollout``: look at the environment with a scripted or random policy, no training."""

from __future__ import annotations

import io
from pathlib import Path

import gymnasium as gym
import numpy as np
import typer
from rich.table import Table

from sb3_hddpg.artifacts.io import atomic_write_bytes
from sb3_hddpg.baselines import JacobianReacher
from sb3_hddpg.baselines.random import RandomPolicy
from sb3_hddpg.cli.app import app, console
from sb3_hddpg.cli.options import ReplaceFileOpt, count, output_file, usage_errors, writable_file
from sb3_hddpg.envs.contract import state_layout_of
from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID
from sb3_hddpg.evaluation import evaluate
from sb3_hddpg.extras import Image
from sb3_hddpg.policy import Policy


@app.command()
def rollout(
    env_id: str = typer.Option(SNAKE_REACH_ENV_ID, "--env", help="Registered environment id."),
    episodes: int = typer.Option(5, callback=count("episodes"), help="Episodes per policy."),
    seed: int = typer.Option(0, min=0, help="Seed of the first episode (episode k uses seed + k)."),
    png: Path = typer.Option(
        Path("runs/rollout.png"), callback=writable_file, help="Where to save a rendered frame."
    ),
    force: ReplaceFileOpt = False,
) -> None:
    """Roll out a random and a scripted (Jacobian-transpose) policy and print the env's metrics."""
    output_file(png, force, "'--png'")
    with usage_errors("'--env'"):
        env = gym.make(env_id, render_mode="rgb_array")
    policies: dict[str, Policy] = {
        "random": RandomPolicy(env.action_space, seed=seed),
        "scripted reacher": JacobianReacher(state_layout_of(env)),
    }
    table = Table(title=f"{env_id}: {episodes} episodes, seeds {seed}..{seed + episodes - 1}")
    for column in ("policy", "reward", "goal touch rate", "contact steps/ep", "success", "min clearance"):
        table.add_column(column, justify="right" if column != "policy" else "left")
    for name, policy in policies.items():
        s = evaluate(policy, env, n_episodes=episodes, seed=seed).summary()
        table.add_row(
            name,
            f"{s['mean_reward']:.1f} ± {s['std_reward']:.1f}",
            f"{s['goal_touch_rate']:.1%}",
            f"{s['collisions_per_episode']:.1f}",
            f"{s['success_rate']:.0%}",
            f"{s['min_clearance']:.3f}",
        )
    console.print(table)
    buffer = io.BytesIO()
    frame = env.render()
    # gymnasium types render() for every render mode; rgb_array (asked for above) returns one array.
    assert isinstance(frame, np.ndarray), type(frame)
    Image.fromarray(frame).save(buffer, format="PNG")
    atomic_write_bytes(png, buffer.getvalue())
    console.print(f"Saved the last frame of the scripted reacher to [bold]{png}[/]")

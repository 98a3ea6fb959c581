"""``hddpg-cli record PATH --out FILE.gif|FILE.mp4``: watch any policy, with the manager's choices drawn."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import typer

from hddpg_zoo.media.video import check_video_path, make_recording_env, record_video
from sb3_hddpg.cli.app import app, console
from sb3_hddpg.cli.evaluate import load_cli_policy
from sb3_hddpg.cli.options import (
    ENV_HELP,
    EpisodeStepsOpt,
    InfoKeyOpt,
    ReplaceFileOpt,
    RunPreferenceOpt,
    TermBoundsOpt,
    TermsOpt,
    at_least,
    count,
    output_file,
    seed_range,
    terms_env_option,
    usage_errors,
)
from sb3_hddpg.evaluation import EVAL_SEED_BASE
from sb3_hddpg.hierarchy.loading import LoadedPolicy

POLICY_HELP = "A worker or flat zip, a hierarchy.zip (or its folder), a ham.json, or 'random' / 'scripted' (Jacobian-transpose) / 'ik' (damped-least-squares IK) / 'field' (potential-field avoider)."
TRUST_HELP = "Allow SB3's full loader, which runs code stored in the file: only for files you trust."

# The options of the commands that run a policy for a few episodes (record, plot-selection), spelled once.
EpisodeSeedOpt = Annotated[
    int,
    typer.Option("--seed", callback=seed_range, help="Seed of the first episode (episode k uses seed + k)."),
]
ActInEnvOpt = Annotated[
    str | None,
    typer.Option("--env", help=ENV_HELP + " Default: the env it was trained on."),
]
MaxStepsOpt = Annotated[
    int | None,
    typer.Option(
        "--max-steps",
        callback=count("episode_steps"),
        help="Cut every episode to this many steps (default: full).",
    ),
]
TrustOpt = Annotated[bool, typer.Option("--trust", help=TRUST_HELP)]


@dataclass(frozen=True)
class WatchedPolicy:
    """
    A policy named on the command line, loaded for the env it acts in.

    :param loaded: the policy and what it was trained on.
    :param env_id: the env given with ``--env`` (``None``: the one it was trained on).
    :param env_kwargs: the env's keyword arguments, ``--max-steps`` included.
    """

    loaded: LoadedPolicy
    env_id: str | None
    env_kwargs: dict[str, Any]

    @property
    def env_option(self) -> str:
        """The option a bad env is blamed on: ``--env`` if given, else the policy's path."""
        return "'--env'" if self.env_id else "'PATH'"


def watched_policy(
    path: str,
    env_id: str | None,
    terms: str | None,
    term_bounds: str | None,
    info_key: str | None,
    episode_steps: int | None,
    max_steps: int | None,
    trust: bool,
    preference: str | None,
    algo: str | None = None,
) -> WatchedPolicy:
    """
    Load the policy at ``path`` as ``record`` and ``plot-selection`` run it: another env with several
    objectives resolves to the adapter it needs (as in ``evaluate``), and naming it opts in to it (as
    ``allowed_env_ids`` does in the library); the run-time preference is applied.

    :param path: the policy (``PATH``).
    :param env_id: ``--env`` (``None``: the env the policy was trained on).
    :param terms: ``--terms`` of that env.
    :param term_bounds: ``--term-bounds`` of that env.
    :param info_key: ``--info-key`` of that env.
    :param episode_steps: ``--episode-steps`` of that env.
    :param max_steps: ``--max-steps``: the time limit of each episode (``None``: the env's).
    :param trust: ``--trust``: allow SB3's full loader.
    :param preference: ``--preference``: the run-time preference (``None``: the policy's own).
    :param algo: ``--algo``: the algorithm of a zip without manifest.
    """
    shared = terms_env_option(env_id, terms, term_bounds, info_key, episode_steps)
    loaded = load_cli_policy(path, shared, trust, algo, preference)
    kwargs = {**(shared.env_kwargs if shared else {})}
    if max_steps:
        kwargs["max_episode_steps"] = max_steps
    return WatchedPolicy(loaded, shared.env_id if shared else None, kwargs)


@app.command("record")
def record_command(
    path: str = typer.Argument(..., help=POLICY_HELP),
    out: Path = typer.Option(..., "--out", help="The video to write: FILE.gif or FILE.mp4."),
    episodes: int = typer.Option(1, "--episodes", callback=count("episodes"), help="Episodes to record."),
    seed: EpisodeSeedOpt = EVAL_SEED_BASE,
    fps: int = typer.Option(
        10, "--fps", callback=at_least(1), help="Frames per second (the env runs at 10)."
    ),
    env_id: ActInEnvOpt = None,
    terms: TermsOpt = None,
    term_bounds: TermBoundsOpt = None,
    info_key: InfoKeyOpt = None,
    episode_steps: EpisodeStepsOpt = None,
    max_steps: MaxStepsOpt = None,
    deterministic: bool = typer.Option(True, "--deterministic/--stochastic", help="Deterministic actions."),
    trust: TrustOpt = False,
    preference: RunPreferenceOpt = None,
    algo: str | None = typer.Option(
        None, "--algo", help="Algorithm of a zip without manifest (with --trust)."
    ),
    force: ReplaceFileOpt = False,
) -> None:
    """Render a policy to a GIF or MP4; for a hierarchy or HAM each frame shows the acting worker and the odds."""

    try:
        check_video_path(out)
    except ValueError as error:
        raise typer.BadParameter(str(error), param_hint="'--out'") from None
    output_file(out, force, "'--out'")
    watched = watched_policy(
        path, env_id, terms, term_bounds, info_key, episode_steps, max_steps, trust, preference, algo
    )
    loaded = watched.loaded
    make = functools.partial(loaded.make_env, watched.env_id, **watched.env_kwargs)
    # The env the policy acts in must render frames; one that cannot is named in one line.
    with usage_errors(watched.env_option):
        env = make_recording_env(make, watched.env_id or loaded.env_id)
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
    if "goal_touch_rate" in summary:  # the snake arm's own metrics
        details = (
            f"goal touch {summary['goal_touch_rate']:.1%}, "
            f"contact steps {summary['collisions_per_episode']:.1f} per episode"
        )
    else:  # any env of the contract: its reward terms summed per episode
        details = ", ".join(
            f"{key[len('mean_') : -len('_reward')]} {value:.1f}"
            for key, value in summary.items()
            if key.startswith("mean_")
            and key.endswith("_reward")
            and key not in ("mean_reward", "mean_reach_reward")
        )
    console.print(
        f"[green]✓[/] {result.frames} frames ({result.size[0]}×{result.size[1]}, {fps} fps) -> [bold]{result.path}[/]"
        f"   mean reward {summary['mean_reward']:.1f}{', ' + details if details else ''}"
    )

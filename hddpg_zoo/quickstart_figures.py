"""
The quickstart's demo of its main hierarchy: which of the table's episodes the GIF and the selection timeline
show (:func:`shown_episode`), and the GIF itself (:func:`record_hierarchy`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hddpg_zoo.media.video import RecordingResult, record_video
from hddpg_zoo.quickstart_jobs import QuickstartObserver
from sb3_hddpg.envs import MAX_EPISODE_STEPS
from sb3_hddpg.envs.contract import Proximity, proximity_of
from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID
from sb3_hddpg.evaluation import EVAL_SEED_BASE
from sb3_hddpg.hierarchy.loading import LoadedPolicy


def shown_episode(main: dict[str, Any], env_id: str) -> tuple[int, str]:
    """
    The episode the GIF and the selection timeline show, and its title: the first of the table's episodes in
    which the main hierarchy called more than one worker (the first episode when it never did), so that the
    demo shows its choices; the title says how it was picked and how many episodes had a switch.

    :param main: the main hierarchy's facts (``switching_episodes``, ``episodes``); the seed shown is added.
    :param env_id: the env it was evaluated on.
    """
    switching, episodes = main.get("switching_episodes", []), len(main["episodes"])
    seed = switching[0] if switching else EVAL_SEED_BASE
    main["shown_episode_seed"] = seed
    picked = (
        f"the first of the table's episodes with a switch ({len(switching)} of {episodes} have one)"
        if switching
        else f"the first of the table's episodes (none of {episodes} has a switch)"
    )
    return seed, f"The hierarchy on {env_id}, seed {seed}, {picked}: which worker acts, and why"


def record_hierarchy(
    hierarchy: LoadedPolicy,
    run_dir: Path,
    episodes: tuple[int, int, int | None],
    observer: QuickstartObserver,
    files: dict[str, Path],
) -> tuple[RecordingResult, Proximity | None]:
    """
    The hierarchy at work: a GIF (``files["gif"]``), whose records the selection timeline plots.

    :param episodes: the seed of the first episode shown, how many, and the steps each is cut to (``None``: whole).
    :return: the recording, and the snake's sensor range and touch radius as the contract declares them.
    """
    seed, count, max_steps = episodes
    limit = {"max_episode_steps": max_steps} if max_steps else {}
    gif_env = hierarchy.make_env(SNAKE_REACH_ENV_ID, render_mode="rgb_array", **limit)
    gif_steps = count * (max_steps or MAX_EPISODE_STEPS)
    try:
        recording = record_video(
            hierarchy.policy,
            gif_env,
            run_dir / "hierarchy.gif",
            episodes=count,
            seed=seed,
            fps=10,
            title=f"hierarchy, seed {seed}",
        )
        observer.on_task("GIF", gif_steps, gif_steps)
        files["gif"] = recording.path
        return recording, proximity_of(gif_env)
    finally:
        gif_env.close()


__all__ = ["record_hierarchy", "shown_episode"]

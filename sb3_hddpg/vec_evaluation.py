"""
:func:`~sb3_hddpg.evaluation.evaluate` on a VecEnv, in-process (``DummyVecEnv``) or not (``SubprocVecEnv``):
``num_envs`` episodes a round, the policy given the batch with its ``state`` and ``episode_start``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, cast

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv

from sb3_hddpg.envs.contract import Proximity, TermNormaliser
from sb3_hddpg.evaluation import (
    EpisodeMetrics,
    EpisodeTally,
    EvaluationResult,
    bands_of,
    finite_episode,
)
from sb3_hddpg.policy import Policy


def evaluate_vec_env(
    policy: Policy,
    vec_env: VecEnv,
    n_episodes: int,
    seed: int,
    deterministic: bool,
    on_step: Callable[[gym.Env, dict[str, Any]], None] | None,
    near_clearance: float | None,
    clear_clearance: float | None,
) -> EvaluationResult:
    """:func:`~sb3_hddpg.evaluation.evaluate` on a VecEnv: episode ``k`` with seed ``seed + k``."""
    envs = _in_process_envs(vec_env)
    if on_step is not None and envs is None:
        raise ValueError(
            f"evaluate(): `on_step` is given the env that stepped, which a {type(vec_env.unwrapped).__name__} runs in "
            "another process; use a DummyVecEnv to record"
        )
    normaliser, proximity, name = _declared_terms(vec_env)
    near_clearance, clear_clearance = bands_of(proximity, name, near_clearance, clear_clearance)
    names = getattr(policy, "names", None)
    if names is None:  # a manager's env (a WorkerSelectionWrapper) names the workers it chooses among
        names = vec_env.get_attr("worker_names", [0])[0] if vec_env.has_attr("worker_names") else []
    n_envs = vec_env.num_envs
    episodes: list[EpisodeMetrics] = []
    state: Any = None
    for first in range(0, n_episodes, n_envs):
        vec_env.seed(seed + first)  # env i's next reset: seed + first + i
        # The env contract's observations are arrays (a Box); SB3 types a VecEnv's more widely.
        obs = cast(np.ndarray, vec_env.reset())
        tallies = [
            EpisodeTally(normaliser, list(names), near_clearance, clear_clearance, vec_env.reset_infos[i])
            for i in range(min(n_envs, n_episodes - first))
        ]
        # Envs past this round's last episode step along (a VecEnv steps all) but are not counted.
        running = np.arange(n_envs) < len(tallies)
        starts = np.ones(n_envs, dtype=bool)
        while running.any():
            action, state = policy.predict(
                obs, state=state, episode_start=starts, deterministic=deterministic
            )
            selections = getattr(policy, "last_selections", None) or [None] * n_envs
            decisions = getattr(policy, "last_manager_actions", None)
            step_obs, rewards, dones, infos = vec_env.step(action)
            obs = cast(np.ndarray, step_obs)
            for i in np.flatnonzero(running):
                tallies[i].add_decision(np.asarray(action[i] if decisions is None else decisions[i]))
                tallies[i].add_env_step(float(rewards[i]), infos[i], selections[i])
                if on_step is not None and envs is not None:
                    on_step(envs[i], infos[i])
            running &= ~dones
            starts = dones
        episodes += [finite_episode(t.metrics(seed + first + i)) for i, t in enumerate(tallies)]
    return EvaluationResult(episodes, near_clearance, clear_clearance)


def _declared_terms(vec_env: VecEnv) -> tuple[TermNormaliser, Proximity | None, str]:
    """
    What the first env of ``vec_env`` declares of the env contract (:mod:`sb3_hddpg.envs.contract`): its
    reward terms' normaliser, its proximity (``None``: none) and its name. Asked through ``get_attr``, which
    reaches envs in other processes too, so that only these picklable values cross.

    :raises ValueError: one line, when the envs do not declare their reward terms.
    """
    spec = vec_env.get_attr("spec", [0])[0]
    name = repr(spec.id) if spec is not None else "the VecEnv's first env"
    if not (vec_env.has_attr("reward_bounds") and vec_env.has_attr("normalise_terms")):
        raise ValueError(
            f"Expected envs that declare their reward terms (`reward_bounds` and `normalise_terms`, see "
            f"sb3_hddpg.envs.contract), actually: {name}; wrap them with sb3_hddpg.envs.adapters"
        )
    proximity = vec_env.get_attr("proximity", [0])[0] if vec_env.has_attr("proximity") else None
    normaliser = TermNormaliser(vec_env.get_attr("reward_bounds", [0])[0])
    return normaliser, proximity if isinstance(proximity, Proximity) else None, name


def _in_process_envs(vec_env: VecEnv) -> list[gym.Env] | None:
    """The envs of a ``DummyVecEnv`` (under any VecEnv wrappers); ``None`` for envs in other processes."""
    inner = vec_env.unwrapped
    return list(inner.envs) if isinstance(inner, DummyVecEnv) else None

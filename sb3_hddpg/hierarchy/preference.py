"""``PreferenceReward``: the shared env's reward re-weighted by preference factors (a flat agent's view of a preference)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np

from sb3_hddpg.envs.contract import env_contract
from sb3_hddpg.hierarchy.selection import check_preferences


class PreferenceReward(gym.Wrapper[np.ndarray, np.ndarray, np.ndarray, np.ndarray]):
    """
    Replace the env's reward by ``sum_t preference[t] * normalised(term_t)``, the reward a manager with one
    worker per term is paid at these factors, so that a flat agent learns the same scalarised objective from
    scratch (with every factor 1 on ``hddpg/SnakeReach-v0``: that env's own reward).

    :param env: the shared env, which meets the env contract (:mod:`sb3_hddpg.envs.contract`).
    :param preferences: term name -> factor (finite, > 0); terms not named get 1.
    """

    def __init__(self, env: gym.Env, preferences: Mapping[str, float]) -> None:
        super().__init__(env)
        self.contract = env_contract(env)
        terms = list(self.contract.reward_bounds)
        unknown = sorted(set(preferences) - set(terms))
        if unknown:
            raise ValueError(f"Unknown reward terms {unknown} in the preferences; the env's terms: {terms}")
        # The manager's own rule for preference factors (finite, > 0, missing ones 1): one check for both.
        self.preferences: dict[str, float] = check_preferences(dict(preferences), list(terms))

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        obs, _, terminated, truncated, info = self.env.step(action)
        normalised = self.contract.normalise_terms(info["reward_terms"])
        reward = sum(factor * normalised[term] for term, factor in self.preferences.items())
        return obs, float(reward), terminated, truncated, info


def make_preference_env(
    env_id: str, env_kwargs: dict[str, Any] | None, preferences: Mapping[str, float]
) -> gym.Env:
    """``gym.make(env_id, **env_kwargs)`` wrapped in :class:`PreferenceReward` (module-level: picklable)."""
    return PreferenceReward(gym.make(env_id, **(env_kwargs or {})), preferences)

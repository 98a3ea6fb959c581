"""``hddpg/SnakeMO-v0``: the snake arm speaking MO-Gymnasium's API (a vector reward and ``reward_space``)."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces

from sb3_hddpg.envs.snake import REWARD_TERMS, SnakeArmEnv


class SnakeMOEnv(SnakeArmEnv):
    """
    :class:`~sb3_hddpg.envs.snake.SnakeArmEnv` whose step reward is the vector of its raw terms
    ``[goal, avoid]``, with ``reward_space`` declaring their bounds, so that MORL libraries can train on it.

    :param kwargs: as :class:`~sb3_hddpg.envs.snake.SnakeArmEnv`, except ``reward`` (the vector is the reward).
    """

    def __init__(self, **kwargs: Any) -> None:
        if "reward" in kwargs:
            raise ValueError(
                "hddpg/SnakeMO-v0 returns every term as its reward vector: `reward` is not an argument"
            )
        super().__init__(reward="reach", **kwargs)
        low = np.array([self.reward_bounds[t][0] for t in REWARD_TERMS], dtype=np.float32)
        high = np.array([self.reward_bounds[t][1] for t in REWARD_TERMS], dtype=np.float32)
        self.reward_space = spaces.Box(low, high, dtype=np.float32)
        self.reward_dim = len(REWARD_TERMS)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool, bool, dict[str, Any]]:  # type: ignore[override]
        obs, _, terminated, truncated, info = super().step(action)
        terms = info["reward_terms"]
        vector = np.array([terms[t] for t in REWARD_TERMS], dtype=np.float32)
        return obs, vector, terminated, truncated, info

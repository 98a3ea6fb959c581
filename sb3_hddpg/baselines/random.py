"""The floor every learned policy must beat: uniform random actions."""

from __future__ import annotations

import gymnasium as gym
import numpy as np


class RandomPolicy:
    """
    Uniform random actions.

    :param action_space: the space to sample from: a ``Box``.
    :param seed: seed of the sampler.
    """

    def __init__(self, action_space: gym.spaces.Space[np.ndarray], seed: int | None = None) -> None:
        if not isinstance(action_space, gym.spaces.Box):
            raise TypeError(f"RandomPolicy samples Box action spaces, got {action_space}")
        self.action_space = action_space
        self.rng = np.random.default_rng(seed)

    def predict(
        self,
        observation: np.ndarray,
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, None]:
        batch = observation.shape[:-1]
        low, high = self.action_space.low, self.action_space.high
        action = self.rng.uniform(low, high, size=(*batch, *self.action_space.shape)).astype(np.float32)
        return action, None

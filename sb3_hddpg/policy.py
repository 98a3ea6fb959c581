"""The worker protocol: anything that acts like an SB3 model's ``predict``."""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import gymnasium as gym
import numpy as np

#: Worker name -> the registered env id whose reward it learns (here, not in ``training``, so that the CLI
#: can list the names without importing torch).
WORKER_ENV_IDS = {"goal": "hddpg/SnakeGoal-v0", "avoid": "hddpg/SnakeAvoid-v0"}


@runtime_checkable
class Policy(Protocol):
    """
    What every policy in sb3-hddpg is: an SB3 model, a :class:`~sb3_hddpg.hierarchy.hierarchy.Hierarchy`, the HAM
    switch, or any object with SB3's ``predict`` signature. Any policy can be a worker of a manager.
    """

    def predict(
        self,
        observation: np.ndarray,
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]: ...


class RandomPolicy:
    """
    Uniform random actions: the floor every learned policy must beat.

    :param action_space: the space to sample from: a ``Box``.
    :param seed: seed of the sampler.
    """

    def __init__(self, action_space: gym.spaces.Space[Any], seed: int | None = None) -> None:
        if not isinstance(action_space, gym.spaces.Box):
            raise TypeError(f"RandomPolicy samples Box action spaces, got {action_space}")
        self.action_space = action_space
        self.rng = np.random.default_rng(seed)

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, None]:
        batch = observation.shape[:-1]
        low, high = self.action_space.low, self.action_space.high
        action = self.rng.uniform(low, high, size=(*batch, *self.action_space.shape)).astype(np.float32)
        return action, None

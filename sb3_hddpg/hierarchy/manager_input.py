"""
What the manager observes: its slice of the shared state, optionally how that slice moved over the last env
step, and a conditioned manager's preference weights. One owner for the training wrapper and the loaded
hierarchy, so that a manager acts on the input it was trained on.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_hddpg.artifacts.limits import MAX_MANAGER_MOTION


def subset_space(space: gym.Space[Any], indices: np.ndarray | None) -> gym.Space[Any]:
    """The observation space restricted to ``indices`` (``None``: all of it)."""
    if indices is None:
        return space
    if not isinstance(space, spaces.Box):
        raise ValueError(f"Selecting state components needs a Box observation space, got {space}")
    return spaces.Box(space.low[indices], space.high[indices], dtype=space.dtype.type)


def with_preference_space(space: gym.Space, n_workers: int) -> spaces.Box:
    """
    A conditioned manager's observation space: ``space`` flattened (a matrix such as highway-env's
    Kinematics observation row by row), followed by ``n_workers`` weights in [0, 1].
    """
    if not isinstance(space, spaces.Box):
        raise ValueError(f"A preference-conditioned manager needs a Box observation, got {space}")
    low = np.concatenate([space.low.ravel(), np.zeros(n_workers)]).astype(space.dtype)
    high = np.concatenate([space.high.ravel(), np.ones(n_workers)]).astype(space.dtype)
    return spaces.Box(low, high, dtype=space.dtype.type)


def with_motion_space(space: gym.Space) -> spaces.Box:
    """
    The observation space of a manager that also sees motion: ``space`` flattened, followed by one value in
    [-1, 1] per entry (its scaled change over the last env step).
    """
    if not isinstance(space, spaces.Box):
        raise ValueError(f"A manager that observes motion needs a Box observation, got {space}")
    size = int(np.prod(space.shape))
    low = np.concatenate([space.low.ravel(), -np.ones(size)]).astype(space.dtype)
    high = np.concatenate([space.high.ravel(), np.ones(size)]).astype(space.dtype)
    return spaces.Box(low, high, dtype=space.dtype.type)


class ManagerInput:
    """
    Build the manager's observation from the shared state: ``[state, motion, preference weights]``.

    - *state*: the components of ``indices`` (``None``: the whole observation);
    - *motion* (``motion > 0``): ``clip(motion * (state - previous state), -1, 1)``, the state one env step
      earlier; at an episode's first step the previous state is the state itself (no motion). Most of the
      shared state moves little per step (the snake arm's obstacles by at most 0.0075 of their range), so
      ``motion`` scales the change to where a network sees it;
    - *preference weights*: a conditioned manager's normalised weights, the last ``n_workers`` entries.

    With neither motion nor weights the state keeps its own shape; otherwise every part is flattened.

    :param observation_space: the shared env's observation space.
    :param indices: the state entries the manager sees (``None``: all).
    :param motion: the scale of the observed change (0: the manager sees no motion).
    :param n_preferences: the number of preference weights a conditioned manager observes (0: none).
    """

    def __init__(
        self,
        observation_space: gym.Space,
        indices: np.ndarray | None = None,
        motion: float = 0.0,
        n_preferences: int = 0,
    ) -> None:
        if not (np.isfinite(motion) and 0 <= motion <= MAX_MANAGER_MOTION):
            raise ValueError(
                f"Expected manager_motion to be a finite number in [0, {MAX_MANAGER_MOTION:g}], actually: {motion!r}"
            )
        self.indices = indices
        self.motion = float(motion)
        self.n_preferences = int(n_preferences)
        state_space = subset_space(observation_space, indices)
        self._single_ndim = len(state_space.shape or ())
        space = with_motion_space(state_space) if self.motion else state_space
        if self.n_preferences:
            space = with_preference_space(space, self.n_preferences)
        self.observation_space: gym.Space = space
        self._dtype = np.dtype(getattr(space, "dtype", np.float32) or np.float32)

    def state(self, obs: np.ndarray) -> np.ndarray:
        """The manager's slice of one observation or of a batch (the leading axes)."""
        return obs if self.indices is None else obs[..., self.indices]

    def __call__(
        self, obs: np.ndarray, previous: np.ndarray | None = None, weights: np.ndarray | None = None
    ) -> np.ndarray:
        """
        The manager's observation.

        :param obs: the shared state, one observation or a batch of them.
        :param previous: the shared state one env step earlier, of ``obs``'s shape (``None``: no motion, as
            at an episode's first step).
        :param weights: a conditioned manager's preference weights (required when it observes them).
        :return: the manager's observation (a batch for a batch).
        """
        state = self.state(obs)
        if not self.motion and not self.n_preferences:
            return state
        batch = state.shape[: state.ndim - self._single_ndim]
        parts = [state.reshape(*batch, -1)]
        if self.motion:
            change = np.zeros_like(state) if previous is None else state - self.state(previous)
            parts.append(np.clip(self.motion * change, -1.0, 1.0).reshape(*batch, -1))
        if self.n_preferences:
            if weights is None:
                raise ValueError("A conditioned manager's observation needs the preference weights")
            parts.append(np.broadcast_to(weights, (*batch, self.n_preferences)))
        return np.concatenate(parts, axis=-1).astype(self._dtype, copy=False)

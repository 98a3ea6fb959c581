"""
What the manager observes: its slice of the shared state, optionally how that slice moved over the last env
step, and a conditioned manager's preference weights; one owner for training and acting.
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
    """A conditioned manager's observation space: ``space`` flattened, then ``n_workers`` weights in [0, 1]."""
    return _appended(space, 0.0, n_workers, "A preference-conditioned manager")


def _appended(space: gym.Space, low: float, size: int, who: str) -> spaces.Box:
    """``space`` flattened (a matrix row by row), followed by ``size`` entries in ``[low, 1]``."""
    if not isinstance(space, spaces.Box):
        raise ValueError(f"{who} needs a Box observation, got {space}")
    low_bounds = np.concatenate([space.low.ravel(), np.full(size, low)]).astype(space.dtype)
    high_bounds = np.concatenate([space.high.ravel(), np.ones(size)]).astype(space.dtype)
    return spaces.Box(low_bounds, high_bounds, dtype=space.dtype.type)


class ManagerInput:
    """
    Build the manager's observation from the shared state: ``[state, motion, preference weights]``.

    - *state*: the components of ``indices`` (``None``: the whole observation);
    - *motion* (``motion > 0``): ``clip(motion * (state - previous state), -1, 1)``, 0 at an episode's first
      step; the scale brings the small change per step (the snake's obstacles: 0.0075 of their range at
      most) to where a network sees it;
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
        size = int(np.prod(state_space.shape or ()))
        space = (
            _appended(state_space, -1.0, size, "A manager that observes motion")
            if self.motion
            else state_space
        )
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
        The manager's observation (a batch for a batch).

        :param obs: the shared state, one observation or a batch of them.
        :param previous: the shared state one env step earlier (``None``: no motion, as at an episode's start).
        :param weights: a conditioned manager's preference weights (required when it observes them).
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

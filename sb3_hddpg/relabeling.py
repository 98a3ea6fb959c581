"""
Replay buffers that rewrite a share of their samples when they are drawn (the stored data never change): the
one sampling path of the goal worker's hindsight goals and the conditioned manager's preferences.
"""

from __future__ import annotations

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.type_aliases import ReplayBufferSamples
from stable_baselines3.common.vec_env import VecNormalize


class RelabelingReplayBuffer(ReplayBuffer):
    """
    SB3's ``ReplayBuffer`` whose sampled batches a subclass rewrites in :meth:`relabel_batch`.

    :param buffer_size: as SB3's; so are ``observation_space``, ``action_space``, ``device``, ``n_envs`` and
        ``handle_timeout_termination``.
    :param optimize_memory_usage: not supported (next observations are needed as stored).
    :param relabel_fraction: the share of sampled transitions rewritten.
    """

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        relabel_fraction: float = 0.5,
    ) -> None:
        if optimize_memory_usage:
            raise ValueError(f"{type(self).__name__} does not support optimize_memory_usage=True")
        if not 0.0 <= relabel_fraction <= 1.0:
            raise ValueError(f"Expected `relabel_fraction` in [0, 1], actually: {relabel_fraction!r:.50}")
        super().__init__(
            buffer_size,
            observation_space,
            action_space,
            device=device,
            n_envs=n_envs,
            optimize_memory_usage=False,
            handle_timeout_termination=handle_timeout_termination,
        )
        self.relabel_fraction = float(relabel_fraction)

    def relabel_batch(
        self,
        obs: np.ndarray,
        next_obs: np.ndarray,
        rewards: np.ndarray,
        batch_inds: np.ndarray,
        env_indices: np.ndarray,
    ) -> None:
        """
        Rewrite a drawn batch in place: its observations, next observations and rewards (shape ``(n,)``).

        :param batch_inds: the buffer positions drawn.
        :param env_indices: their env indices.
        """
        raise NotImplementedError

    def _get_samples(self, batch_inds: np.ndarray, env: VecNormalize | None = None) -> ReplayBufferSamples:
        env_indices = np.random.randint(0, high=self.n_envs, size=(len(batch_inds),))
        obs = self.observations[batch_inds, env_indices, :].copy()
        next_obs = self.next_observations[batch_inds, env_indices, :].copy()
        rewards = self.rewards[batch_inds, env_indices].copy()
        self.relabel_batch(obs, next_obs, rewards, batch_inds, env_indices)
        dones = self.dones[batch_inds, env_indices] * (1 - self.timeouts[batch_inds, env_indices])
        data = (
            self._normalize_obs(obs, env),
            self.actions[batch_inds, env_indices, :],
            self._normalize_obs(next_obs, env),
            dones.reshape(-1, 1),
            self._normalize_reward(rewards.reshape(-1, 1), env),
        )
        return ReplayBufferSamples(*tuple(map(self.to_torch, data)))  # type: ignore[arg-type]

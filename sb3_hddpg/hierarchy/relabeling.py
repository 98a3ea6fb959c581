"""
Preference relabelling for a preference-conditioned manager: a stored step replayed for another preference.

A conditioned manager's reward ``sum_w factor_w * reward_w`` is linear in each worker's option reward, which
the wrapper puts in ``info["worker_rewards"]``; the dynamics do not depend on the preference. So a stored
step replays as a real one for any preference: its observed weights (the last ``n_workers`` entries) are
rewritten and its reward recomputed, as hindsight relabelling rewrites a goal.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces

from sb3_hddpg.hierarchy.conditioning import PreferenceSpace
from sb3_hddpg.relabeling import RelabelingReplayBuffer


class PreferenceRelabelingReplayBuffer(RelabelingReplayBuffer):
    """
    SB3's ``ReplayBuffer`` that replays a share of its samples at a freshly drawn preference (the stored data
    never change); ``train_manager(..., manager_preferences="ratio-sweep")`` sets it up.

    :param buffer_size: as SB3's; so are ``observation_space``, ``action_space``, ``device``, ``n_envs`` and
        ``handle_timeout_termination``.
    :param optimize_memory_usage: not supported (next observations are needed as stored).
    :param names: the workers, in the manager's action order.
    :param space: the trained-over preferences (:meth:`PreferenceSpace.to_json`).
    :param relabel_fraction: the share of sampled transitions given another preference.
    :param seed: the seed of the generator that draws the preferences.
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
        names: list[str] | None = None,
        space: dict[str, Any] | None = None,
        relabel_fraction: float = 0.5,
        seed: int | None = None,
    ) -> None:
        if names is None or space is None:
            raise ValueError(
                "PreferenceRelabelingReplayBuffer needs the worker `names` and the preference `space`"
            )
        super().__init__(
            buffer_size,
            observation_space,
            action_space,
            device=device,
            n_envs=n_envs,
            optimize_memory_usage=optimize_memory_usage,
            handle_timeout_termination=handle_timeout_termination,
            relabel_fraction=relabel_fraction,
        )
        self.space = PreferenceSpace.from_json(space, names)
        self.n_workers = len(names)
        obs_size = int(np.prod(observation_space.shape or (0,)))
        if obs_size <= self.n_workers:
            raise ValueError(
                f"The observation has {obs_size} values: too few to end with {self.n_workers} preference weights"
            )
        self.total = self.space.total
        # Per stored step: each worker's own discounted option reward.
        self.worker_rewards = np.zeros((self.buffer_size, self.n_envs, self.n_workers), dtype=np.float32)
        self._rng = np.random.default_rng(seed)

    def add(
        self,
        obs: np.ndarray,
        next_obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        for env_index, info in enumerate(infos):
            if "worker_rewards" not in info:
                raise ValueError(
                    "A step without info['worker_rewards']: the manager's env is not a conditioned "
                    "WorkerSelectionWrapper (give it manager_preferences)"
                )
            self.worker_rewards[self.pos, env_index] = info["worker_rewards"]
        super().add(obs, next_obs, action, reward, done, infos)

    def relabel_batch(
        self,
        obs: np.ndarray,
        next_obs: np.ndarray,
        rewards: np.ndarray,
        batch_inds: np.ndarray,
        env_indices: np.ndarray,
    ) -> None:
        relabel = self._rng.random(len(batch_inds)) < self.relabel_fraction
        if np.any(relabel):
            weights = self.space.sample_weights(self._rng, int(relabel.sum())).astype(obs.dtype)
            n = self.n_workers
            obs[relabel, -n:] = weights
            next_obs[relabel, -n:] = weights
            terms = self.worker_rewards[batch_inds[relabel], env_indices[relabel]]
            rewards[relabel] = self.total * np.sum(weights * terms, axis=1)

"""
Hindsight goal relabelling for the snake arm's goal worker, on flat observations (HER's "future" strategy).

The goal term depends only on the tip and the goal (``-d + 1[d <= touch_radius]``), and the observation holds
both: the tip is the last point of ``joint_positions`` and the goal is ``tip + 2 * ee_to_goal``. So a stored
transition can be replayed as if the goal had been somewhere else, here where the tip itself got to later in
the same episode (Andrychowicz et al., 2017): the observation's ``ee_to_goal`` and ``goal_touched`` and the
reward are recomputed for that goal. Early in training almost no transition touches the real goal, but every
relabelled one near its new goal does: the critic learns what reaching looks like long before the actor
reaches anything. The model stays a plain SB3 model on flat observations (SB3's own ``HerReplayBuffer``
needs a ``Dict`` goal-env interface that the shared state of the hierarchy does not have).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces

from sb3_hddpg.envs.layout import StateLayout, build_state_layout
from sb3_hddpg.envs.snake.rewards import GoalTerm
from sb3_hddpg.relabeling import RelabelingReplayBuffer

#: The components relabelling needs in the observation.
REQUIRED_COMPONENTS = ("joint_positions", "ee_to_goal", "goal_touched")


class GoalRelabelingReplayBuffer(RelabelingReplayBuffer):
    """
    SB3's ``ReplayBuffer`` that replays a share of its samples with a hindsight goal (see the module's note).

    Use it for the goal worker: ``DDPG(..., replay_buffer_class=GoalRelabelingReplayBuffer,
    replay_buffer_kwargs={"n_joints": 6, "observe": [...]})``, or the config's ``goal_relabeling`` key. The
    stored data are never changed: a sample is relabelled when drawn, so the same transition serves with
    its real goal and with others.

    :param buffer_size: as SB3's.
    :param observation_space: as SB3's: the goal env's observation (the full state or an ``observe`` subset).
    :param action_space: as SB3's.
    :param device: as SB3's.
    :param n_envs: as SB3's.
    :param optimize_memory_usage: not supported (next observations are needed as stored).
    :param handle_timeout_termination: as SB3's.
    :param n_joints: the arm's joints (the env's ``n_joints``).
    :param observe: the state components the observation holds, in order (the env's ``observe``; default all).
    :param touch_radius: the env's ``touch_radius``.
    :param goal_low: the lower bound of the goal term (the env's ``reward_bounds["goal"][0]``).
    :param relabel_fraction: the share of sampled transitions given a hindsight goal (HER's 0.8 for k = 4).
    :param goal_scale: ``None``: the reward is the goal term (the goal worker's). A number: the reward is a sum
        in which the goal term enters as ``goal_scale * (term - goal_low)`` (the reach reward, where it is
        min-max normalised: ``1 / (high - low)``); a relabelled reward then changes by the normalised change
        of the goal term and keeps every other term (they do not depend on the goal).
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
        n_joints: int = 6,
        observe: Sequence[str] | None = None,
        touch_radius: float = 0.1,
        goal_low: float = -1.9,
        relabel_fraction: float = 0.8,
        goal_scale: float | None = None,
    ) -> None:
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
        full = build_state_layout(n_joints)
        names = list(observe) if observe is not None else list(full)
        missing = [c for c in REQUIRED_COMPONENTS if c not in names]
        if missing:
            raise ValueError(f"Goal relabelling needs the state components {missing} in the observation")
        layout = StateLayout([(name, full[name].stop - full[name].start) for name in names])
        if layout.size != int(np.prod(observation_space.shape or (0,))):
            raise ValueError(
                f"The observation has {observation_space.shape} values, but {names} of a {n_joints}-joint arm "
                f"make {layout.size}: give the env's n_joints and observe"
            )
        positions = layout["joint_positions"]
        self._tip = slice(positions.stop - 2, positions.stop)
        self._to_goal = layout["ee_to_goal"]
        self._touched = layout["goal_touched"].start
        self.touch_radius = float(touch_radius)
        self.goal_low = float(goal_low)
        # The env's own goal term: a relabelled reward is what the env would have paid for that goal.
        self._goal_term = GoalTerm(self.touch_radius, self.goal_low)
        self.goal_scale = None if goal_scale is None else float(goal_scale)
        # Per stored step: its episode's number (to tell a step overwritten by a later episode) and, once
        # that episode has ended, the position of its last step; -1 while it runs. Arrays, so that drawing
        # a "future" step for a whole batch is a few numpy operations.
        self._episode = np.full((self.buffer_size, self.n_envs), -1, dtype=np.int64)
        self._episode_last = np.full((self.buffer_size, self.n_envs), -1, dtype=np.int64)
        self._episode_counter = np.zeros(self.n_envs, dtype=np.int64)
        self._episode_start = np.zeros(self.n_envs, dtype=np.int64)

    @staticmethod
    def env_kwargs(env: Any) -> dict[str, Any]:
        """
        The env-dependent arguments of this buffer, read from a snake env (or a wrapper of one).

        :param env: the goal worker's training env.
        :return: ``n_joints``, ``observe``, ``touch_radius``, ``goal_low`` and ``goal_scale`` (set where the
            env's reward is the reach reward, the normalised sum of the terms).
        :raises ValueError: an env whose reward does not hold the goal term (the avoid reward).
        """
        base = env.unwrapped
        observed = getattr(base, "observed_components", None)
        low, high = base.reward_bounds["goal"]
        reward = getattr(base, "reward_name", "goal")
        if reward not in ("goal", "reach"):
            raise ValueError(
                f"Goal relabelling needs a reward that holds the goal term, actually: {reward!r}"
            )
        return {
            "n_joints": base.n_joints,
            "observe": list(observed) if observed is not None else None,
            "touch_radius": base.touch_radius,
            "goal_low": low,
            "goal_scale": 1.0 / (high - low) if reward == "reach" else None,
        }

    def add(
        self,
        obs: np.ndarray,
        next_obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        position = self.pos
        self._episode[position] = self._episode_counter
        self._episode_last[position] = -1
        super().add(obs, next_obs, action, reward, done, infos)
        for env in np.flatnonzero(np.asarray(done).reshape(-1)):
            start = int(self._episode_start[env])
            length = (position - start) % self.buffer_size + 1
            steps = (start + np.arange(length)) % self.buffer_size
            self._episode_last[steps, env] = position
            self._episode_start[env] = (position + 1) % self.buffer_size
            self._episode_counter[env] += 1

    def future_indices(self, indices: np.ndarray, envs: np.ndarray) -> np.ndarray:
        """
        For each stored step, a step of the same episode at or after it, uniformly (HER's "future").

        :param indices: buffer positions.
        :param envs: their env indices.
        :return: positions; a step whose episode was partly overwritten gets itself.
        """
        last = self._episode_last[indices, envs]
        running = last < 0  # the episode is still being played: its last stored step is the newest one
        last = np.where(running, (self.pos - 1) % self.buffer_size, last)
        span = (last - indices) % self.buffer_size
        future = (indices + (np.random.random(len(indices)) * (span + 1)).astype(np.int64)) % self.buffer_size
        same = self._episode[future, envs] == self._episode[indices, envs]
        return np.where(same, future, indices)

    def relabel_batch(
        self,
        obs: np.ndarray,
        next_obs: np.ndarray,
        rewards: np.ndarray,
        batch_inds: np.ndarray,
        env_indices: np.ndarray,
    ) -> None:
        relabel = np.flatnonzero(np.random.random(len(batch_inds)) < self.relabel_fraction)
        if len(relabel):
            futures = self.future_indices(batch_inds[relabel], env_indices[relabel])
            goals = self.next_observations[futures, env_indices[relabel], self._tip]
            self.relabel(obs, next_obs, rewards, relabel, goals)

    def relabel(
        self, obs: np.ndarray, next_obs: np.ndarray, rewards: np.ndarray, rows: np.ndarray, goals: np.ndarray
    ) -> None:
        """
        Give ``rows`` of a batch the goal positions ``goals`` (shape ``(len(rows), 2)``), in place: the
        observations' goal vector and touch flag, and the goal term as the env computes it.
        """
        if self.goal_scale is not None:  # the stored goal term, read before the goal is replaced
            stored = np.sqrt(((2.0 * next_obs[rows, self._to_goal]) ** 2).sum(axis=1))
            old_goal = self._goal_term.of(stored, next_obs[rows, self._touched])
        for batch, is_next in ((obs, False), (next_obs, True)):
            tips = batch[rows, self._tip]
            offset = goals - tips
            distance = np.sqrt((offset**2).sum(axis=1))
            new_goal, touched = self._goal_term.batch(distance)
            batch[rows, self._to_goal] = offset / 2.0
            batch[rows, self._touched] = touched
            if is_next:
                if self.goal_scale is None:
                    rewards[rows] = new_goal
                else:
                    rewards[rows] += self.goal_scale * (new_goal - old_goal)

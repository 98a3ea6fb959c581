"""A scripted reacher: Jacobian-transpose control of the snake arm toward the goal, blind to obstacles."""

from __future__ import annotations

from typing import Any

import numpy as np

from sb3_hddpg.envs.layout import StateLayout


class JacobianReacher:
    """
    Moves the tip toward the goal by Jacobian-transpose control, using only the observation: for a planar
    chain the tip velocity from joint ``i`` is ``w_i x (tip - p_i)``, so joint ``i`` turns by the 2-D cross
    product of ``tip - p_i`` with the tip-to-goal vector. It ignores obstacles, so it shows what pure
    reaching scores, and sanity-checks that the goal is reachable.

    :param layout: the env's ``state_layout``.
    :param gain: command per unit of the Jacobian-transpose signal (clipped to [-1, 1]).
    """

    def __init__(self, layout: StateLayout, gain: float = 8.0) -> None:
        self.layout = layout
        self.gain = gain

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, None]:
        obs = np.atleast_2d(observation)
        ends = obs[:, self.layout["joint_positions"]].reshape(len(obs), -1, 2)
        pivots = np.concatenate((np.zeros((len(obs), 1, 2)), ends[:, :-1]), axis=1)
        error = 2.0 * obs[:, self.layout["ee_to_goal"]]  # the observation halves it
        lever = ends[:, -1:, :] - pivots
        signal = lever[..., 0] * error[:, None, 1] - lever[..., 1] * error[:, None, 0]
        action = np.clip(self.gain * signal, -1.0, 1.0).astype(np.float32)
        return (action if observation.ndim > 1 else action[0]), None

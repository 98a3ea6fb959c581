"""
The snake arm's reward terms (Table 2 of the paper) and their exact per-step bounds; one goal term serves
the step (a float) and hindsight relabelling (arrays), so a relabelled reward is what the env would pay.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sb3_hddpg.envs.snake.params import SnakeParams


def reward_bounds(params: SnakeParams) -> dict[str, tuple[float, float]]:
    """Each term's exact per-step ``(low, high)`` for the arm ``params``."""
    return {
        "goal": (-(1.0 + params.goal_radius_max), 1.0),
        "avoid": (-1.0, params.r_bf * params.n_joints * params.sensor_range),
    }


@dataclass(frozen=True)
class GoalTerm:
    """
    The goal term ``-d + 1[d <= touch_radius]`` for a tip-to-goal distance ``d``, clipped to ``[low, high]``
    (physics slack can put the tip a hair beyond reach).

    :param touch_radius: the tip touches the goal within this distance.
    :param low: the term's lower bound (``reward_bounds(...)["goal"][0]``).
    :param high: the term's upper bound.
    """

    touch_radius: float
    low: float
    high: float = 1.0

    def __call__(self, distance: float) -> tuple[float, bool]:
        """The term for one distance, and whether the tip touches the goal."""
        touched = distance <= self.touch_radius
        goal = 1.0 - distance if touched else -distance
        if goal < self.low:
            goal = self.low
        elif goal > self.high:
            goal = self.high
        return goal, touched

    def batch(self, distance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The term for an array of distances (the same values as calling it on each), and the touch flags."""
        touched = distance <= self.touch_radius
        return self.of(distance, touched), touched

    def of(self, distance: np.ndarray, touched: np.ndarray) -> np.ndarray:
        """The term for arrays of distances and touch flags (as an observation stores them)."""
        return np.minimum(np.maximum(-distance + touched, self.low), self.high)


def avoid_term(r_bf: float, clipped_clearances: float, collision: bool) -> float:
    """
    The avoid term ``r_bf * sum_i c_i - 1[any link touches an obstacle]``.

    :param r_bf: the factor on the summed clearances.
    :param clipped_clearances: the links' clearances, each clipped to ``[0, sensor_range]``, summed.
    :param collision: whether some link touches an obstacle.
    """
    return r_bf * clipped_clearances - 1.0 if collision else r_bf * clipped_clearances

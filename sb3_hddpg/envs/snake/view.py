"""A read-only view of what the snake arm senses at one moment: what a renderer or an inspector reads."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SnakeView:
    """
    The snake arm's state at one moment, as ``SnakeArmEnv.view()`` returns it (copies of the env's values).

    :param link_points: the ``(n_joints + 1, 2)`` chain points: the base, every joint, then the tip.
    :param goal: the goal's position, shape ``(2,)``.
    :param obstacles: the obstacle centres, shape ``(n_obstacles, 2)``.
    :param obstacle_radius: every obstacle disc's radius.
    :param touch_radius: the tip touches the goal within this distance.
    :param goal_touched: whether the tip touches the goal.
    :param touching: per link, whether it touches its closest obstacle.
    :param collision: whether some link touches an obstacle.
    :param min_clearance: the smallest clearance of a link to an obstacle's surface (negative: overlap).
    :param goal_distance: the tip's distance to the goal.
    """

    link_points: np.ndarray
    goal: np.ndarray
    obstacles: np.ndarray
    obstacle_radius: float
    touch_radius: float
    goal_touched: bool
    touching: tuple[bool, ...]
    collision: bool
    min_clearance: float
    goal_distance: float

    def touched_obstacles(self) -> np.ndarray:
        """Per obstacle, whether some link touches it (for highlighting)."""
        points = self.link_points
        starts, seg = points[:-1], points[1:] - points[:-1]
        rel = self.obstacles[None, :, :] - starts[:, None, :]
        t = np.clip(np.einsum("lod,ld->lo", rel, seg) / np.einsum("ld,ld->l", seg, seg)[:, None], 0.0, 1.0)
        closest = starts[:, None, :] + t[..., None] * seg[:, None, :]
        gaps = np.linalg.norm(closest - self.obstacles[None], axis=-1)
        return (gaps <= self.obstacle_radius).any(axis=0)

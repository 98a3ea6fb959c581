"""Drawing the snake arm: an RGB frame with Pillow, shown in a pygame window for ``render_mode="human"``."""

from __future__ import annotations

from typing import Any

import numpy as np

from sb3_hddpg.envs.snake.view import SnakeView
from sb3_hddpg.extras import Image, ImageDraw

_BACKGROUND = (250, 250, 247)
_WORKSPACE = (228, 232, 238)
_ARM = (40, 70, 140)
_ARM_HIT = (210, 40, 40)
_JOINT = (20, 20, 20)
_GOAL = (30, 160, 60)
_GOAL_TOUCHED = (250, 190, 0)
_OBSTACLE = (120, 120, 120)
_OBSTACLE_HIT = (230, 90, 60)


class SnakeRenderer:
    """
    Draws a :class:`~sb3_hddpg.envs.snake.view.SnakeView` of a snake arm; one per env, created on the first render.

    :param render_mode: ``"rgb_array"`` returns frames; ``"human"`` also shows them in a pygame window.
    :param size: frame width and height in pixels.
    :param fps: the human window's frame rate.
    """

    def __init__(self, render_mode: str, size: int = 400, fps: int = 10) -> None:
        self.render_mode = render_mode
        self.size = size
        self.fps = fps
        self._window: Any = None
        self._clock: Any = None
        if render_mode == "human":
            try:
                import pygame  # lazily: optional (the `render` extra), only for a window
            except ImportError as error:
                raise ImportError(
                    'render_mode="human" needs pygame: pip install "sb3-hddpg[render]" '
                    '(or use render_mode="rgb_array", which needs no display)'
                ) from error
            self._pygame = pygame

    def _to_pixels(self, points: np.ndarray) -> list[tuple[float, float]]:
        # Reach units -> pixels; the workspace disc of radius 1.1 fills the frame, y up.
        scale = self.size / 2.2
        centre = self.size / 2
        return [(centre + scale * x, centre - scale * y) for x, y in np.atleast_2d(points)]

    def draw(self, view: SnakeView) -> np.ndarray | None:
        """Draw a view of the arm (``env.view()``); return the frame for ``rgb_array``, ``None`` for ``human``."""
        scale = self.size / 2.2
        image = Image.new("RGB", (self.size, self.size), _BACKGROUND)
        pen = ImageDraw.Draw(image)
        ((cx, cy),) = self._to_pixels(np.zeros(2))
        pen.ellipse((cx - scale, cy - scale, cx + scale, cy + scale), fill=_WORKSPACE)

        for centre, touched in zip(view.obstacles, view.touched_obstacles()):
            ((x, y),) = self._to_pixels(centre)
            r = view.obstacle_radius * scale
            pen.ellipse((x - r, y - r, x + r, y + r), fill=_OBSTACLE_HIT if touched else _OBSTACLE)

        ((gx, gy),) = self._to_pixels(view.goal)
        r = view.touch_radius * scale
        goal_colour = _GOAL_TOUCHED if view.goal_touched else _GOAL
        pen.ellipse((gx - r, gy - r, gx + r, gy + r), outline=goal_colour, width=2)
        pen.ellipse((gx - 3, gy - 3, gx + 3, gy + 3), fill=goal_colour)

        points = self._to_pixels(view.link_points)
        for i, touching in enumerate(view.touching):
            pen.line(
                (points[i], points[i + 1]), fill=_ARM_HIT if touching else _ARM, width=max(2, self.size // 80)
            )
        for x, y in points[:-1]:
            pen.ellipse((x - 3, y - 3, x + 3, y + 3), fill=_JOINT)
        frame = np.asarray(image, dtype=np.uint8)

        if self.render_mode == "human":
            self._show(frame)
            return None
        return frame

    def _show(self, frame: np.ndarray) -> None:
        pygame = self._pygame
        if self._window is None:
            pygame.init()
            pygame.display.init()
            self._window = pygame.display.set_mode((self.size, self.size))
            pygame.display.set_caption("sb3-hddpg snake arm")
            self._clock = pygame.time.Clock()
        surface = pygame.surfarray.make_surface(np.transpose(frame, (1, 0, 2)))
        self._window.blit(surface, (0, 0))
        pygame.event.pump()
        pygame.display.flip()
        self._clock.tick(self.fps)

    def close(self) -> None:
        if self._window is not None:
            self._pygame.display.quit()
            self._pygame.quit()
            self._window = None

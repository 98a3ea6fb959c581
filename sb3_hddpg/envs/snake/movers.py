"""The goal's and the obstacles' motion: bounded random walks of their velocity inside their annuli."""

from __future__ import annotations

import math

import numpy as np

from sb3_hddpg.envs.snake.params import SnakeParams

#: Steps of walk noise drawn per generator call.
_NOISE_BLOCK = 256


def sample_annulus(rng: np.random.Generator, r_min: float, r_max: float) -> list[float]:
    """A point uniform over the area of the annulus between ``r_min`` and ``r_max`` (square-root law)."""
    radius = math.sqrt(rng.uniform(r_min**2, r_max**2))
    angle = rng.uniform(-math.pi, math.pi)
    return [radius * math.cos(angle), radius * math.sin(angle)]


class Movers:
    """
    The goal (index 0) and the obstacles: positions and velocities as plain lists, which the step reads and
    :meth:`walk` updates in place.

    :param params: the arm's parameters.
    """

    def __init__(self, params: SnakeParams) -> None:
        self.params = params
        # (top speed, min radius, max radius) of the goal's walk, then of each obstacle's.
        self.limits = [(params.goal_speed, params.goal_radius_min, params.goal_radius_max)] + [
            (params.obstacle_speed, params.obstacle_radius_min, params.obstacle_radius_max)
        ] * params.n_obstacles
        count = 1 + params.n_obstacles
        self.positions: list[list[float]] = [[0.0, 0.0] for _ in range(count)]
        self.velocities: list[list[float]] = [[0.0, 0.0] for _ in range(count)]
        self._noise: list[float] = []
        self._noise_index = 0
        self._link_walkers()

    @property
    def goal(self) -> list[float]:
        """The goal's position (the list the walk updates)."""
        return self.positions[0]

    @property
    def obstacles(self) -> list[list[float]]:
        """The obstacle centres (a new list of the lists the walk updates)."""
        return self.positions[1:]

    def spawn(self, rng: np.random.Generator, points: np.ndarray) -> None:
        """
        Place the goal and the obstacles at rest, uniform in their annuli, the obstacles at least
        ``spawn_margin`` from the arm's chain ``points`` and the goal (re-drawn until so), with ``rng``.
        """
        p = self.params
        goal = sample_annulus(rng, p.goal_radius_min, p.goal_radius_max)
        self.positions = [goal]
        for _ in range(p.n_obstacles):
            for _ in range(1000):
                candidate = sample_annulus(rng, p.obstacle_radius_min, p.obstacle_radius_max)
                if self._clear_of(np.array(candidate), points, np.array(goal)):
                    break
            self.positions.append(candidate)
        self.velocities = [[0.0, 0.0] for _ in self.positions]
        self._link_walkers()
        self._noise = []
        self._noise_index = 0

    def _clear_of(self, centre: np.ndarray, points: np.ndarray, goal: np.ndarray) -> bool:
        """Whether an obstacle at ``centre`` starts clear of the arm's links and the goal."""
        starts, seg = points[:-1], points[1:] - points[:-1]
        t = np.clip(np.sum((centre - starts) * seg, axis=1) / np.sum(seg * seg, axis=1), 0.0, 1.0)
        to_links = np.linalg.norm(starts + t[:, None] * seg - centre, axis=1).min()
        to_goal = np.linalg.norm(goal - centre)
        need = self.params.obstacle_radius + self.params.spawn_margin
        return bool(to_links > need and to_goal > need + self.params.touch_radius)

    def _link_walkers(self) -> None:
        """Gather every moving mover's lists, limits and noise offset; call when the lists are replaced."""
        self._walkers = [
            (pos, vel, top, r_min, r_max, 2 * k)
            for k, (pos, vel, (top, r_min, r_max)) in enumerate(
                zip(self.positions, self.velocities, self.limits)
            )
            if top != 0.0
        ]

    def walk(self, rng: np.random.Generator) -> None:
        """Advance every walk by one env step: jitter the velocity, cap the speed, move, reflect at the edge."""
        noise = self._noise
        k = self._noise_index
        per_step = 2 * len(self.positions)  # noise values per step: (x, y) per mover, moving or not
        if k >= len(noise):  # drawn in blocks of steps: one generator call per block, not per step
            noise = self._noise = rng.normal(0.0, 0.3, size=_NOISE_BLOCK * per_step).tolist()
            k = 0
        self._noise_index = k + per_step
        dt = self.params.dt
        hypot = math.hypot
        for pos, vel, top, r_min, r_max, offset in self._walkers:
            i = k + offset
            vx = vel[0] + noise[i] * top
            vy = vel[1] + noise[i + 1] * top
            speed = hypot(vx, vy)
            if speed > top:
                vx, vy = vx * top / speed, vy * top / speed
            x = pos[0] + vx * dt
            y = pos[1] + vy * dt
            radius = hypot(x, y)
            if radius > r_max or radius < r_min:
                ux, uy = x / max(radius, 1e-12), y / max(radius, 1e-12)
                radial = vx * ux + vy * uy
                vx, vy = vx - 2.0 * radial * ux, vy - 2.0 * radial * uy
                radius = min(max(radius, r_min), r_max)
                x, y = ux * radius, uy * radius
            pos[0] = x
            pos[1] = y
            vel[0] = vx
            vel[1] = vy

    def __getstate__(self) -> dict[str, object]:
        # The walkers hold the same lists as positions and velocities: rebuilt, so that a copy shares them.
        return {k: v for k, v in self.__dict__.items() if k != "_walkers"}

    def __setstate__(self, state: dict[str, object]) -> None:
        self.__dict__.update(state)
        self._link_walkers()

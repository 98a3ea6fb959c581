"""The snake arm's parameters: one frozen, checked record of everything its constructor configures."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

#: The reward choices of the snake arm: one per paper worker plus their normalised sum.
REWARD_CHOICES = ("goal", "avoid", "reach")
#: The reward terms computed every step (Table 2 of the paper).
REWARD_TERMS = ("goal", "avoid")
#: Upper limits of the counts, far above any sensible arm: env kwargs from a shared file cannot stall a step
#: (``sb3_hddpg.artifacts.limits`` names them with the other limits; the env checks its own constructor).
MAX_JOINTS = 32
MAX_OBSTACLES = 32
MAX_SUBSTEPS = 100

#: The parameters that must be finite and > 0, then those that must be finite and >= 0 (checked in order).
_POSITIVE = (
    "obstacle_radius",
    "touch_radius",
    "r_bf",
    "sensor_range",
    "max_joint_speed",
    "joint_limit",
    "dt",
    "goal_radius_max",
    "obstacle_radius_max",
)
_NON_NEGATIVE = ("obstacle_speed", "goal_speed", "goal_radius_min", "obstacle_radius_min", "spawn_margin")
_COUNTS = (("n_joints", 2, MAX_JOINTS), ("n_obstacles", 1, MAX_OBSTACLES), ("substeps", 1, MAX_SUBSTEPS))


@dataclass(frozen=True)
class SnakeParams:
    """
    The snake arm's task and physics, checked when built (a bad value is a ``ValueError`` naming it); the
    counts become ``int``, the rest ``float``. :class:`~sb3_hddpg.envs.snake.SnakeArmEnv`'s constructor
    describes each.
    """

    reward: str = "reach"
    n_joints: int = 6
    n_obstacles: int = 3
    obstacle_radius: float = 0.08
    obstacle_speed: float = 0.15
    goal_speed: float = 0.08
    touch_radius: float = 0.1
    r_bf: float = 0.2
    sensor_range: float = 0.3
    max_joint_speed: float = 1.5
    joint_limit: float = 2.4
    dt: float = 0.1
    substeps: int = 2
    goal_radius_min: float = 0.3
    goal_radius_max: float = 0.9
    obstacle_radius_min: float = 0.35
    obstacle_radius_max: float = 1.0
    spawn_margin: float = 0.1

    def __post_init__(self) -> None:
        check_choice("reward", self.reward, REWARD_CHOICES)
        for name, minimum, maximum in _COUNTS:
            _check_count(name, getattr(self, name), minimum, maximum)
        for name in (*_POSITIVE, *_NON_NEGATIVE):
            value, sign = getattr(self, name), ">" if name in _POSITIVE else ">="
            number = isinstance(value, (int, float, np.number)) and math.isfinite(value)
            if not number or value < 0 or (sign == ">" and value == 0):
                raise ValueError(f"Expected `{name}` to be a finite number {sign} 0, actually: {value!r}")
        if not self.goal_radius_min < self.goal_radius_max <= 1.0:
            raise ValueError(
                "Expected 0 <= goal_radius_min < goal_radius_max <= 1 (the goal must be reachable), "
                f"actually: goal_radius_min={self.goal_radius_min}, goal_radius_max={self.goal_radius_max}"
            )
        if not self.obstacle_radius_min < self.obstacle_radius_max:
            raise ValueError(
                "Expected obstacle_radius_min < obstacle_radius_max, actually: "
                f"obstacle_radius_min={self.obstacle_radius_min}, "
                f"obstacle_radius_max={self.obstacle_radius_max}"
            )
        # Plain Python numbers from here on: the step's scalar arithmetic is fastest on them.
        for field in fields(self):
            if field.name != "reward":
                kind = int if field.type == "int" else float
                object.__setattr__(self, field.name, kind(getattr(self, field.name)))

    @property
    def link_length(self) -> float:
        """Every link's length: the stretched arm reaches exactly 1."""
        return 1.0 / self.n_joints


def check_choice(name: str, value: object, choices: tuple[str, ...]) -> None:
    """Raise a ``ValueError`` naming ``name`` unless ``value`` is one of ``choices``."""
    if value not in choices:
        raise ValueError(f"Expected `{name}` to be one of {list(choices)}, actually: {value!r}")


def _check_count(name: str, value: object, minimum: int, maximum: int) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not minimum <= value <= maximum:
        raise ValueError(f"Expected `{name}` to be an integer in [{minimum}, {maximum}], actually: {value!r}")

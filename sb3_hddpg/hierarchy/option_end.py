"""``OptionEnd``: options that end when the state leaves the band the option was chosen in."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from sb3_hddpg.artifacts.limits import LimitError, brief
from sb3_hddpg.envs.layout import StateLayout


@dataclass(frozen=True)
class OptionEnd:
    """
    Options that also end, before ``option_steps`` env steps, as soon as the state leaves the band they were
    chosen in, so that the manager decides again when the situation changes. Read from the observation:

    :param distance_edges: increasing edges in ``(0, 1)`` on the nearest obstacle's clearance as a fraction
        of the sensor range (the least ``joint_obstacle_distances``); ``(0.5,)``: the option ends when an
        obstacle comes within half the range, or leaves it.
    :param goal_touch: end when the goal is touched or lost (``goal_touched`` changes).
    """

    distance_edges: tuple[float, ...] = ()
    goal_touch: bool = False

    def __post_init__(self) -> None:
        edges = list(self.distance_edges)
        if any(not (isinstance(e, (int, float)) and 0.0 < e < 1.0) for e in edges) or edges != sorted(
            set(edges)
        ):
            raise ValueError(f"Expected increasing distance edges in (0, 1), actually: {edges}")
        if not edges and not self.goal_touch:
            raise ValueError("An option end needs distance edges or goal_touch")

    @classmethod
    def parse(cls, text: str) -> OptionEnd:
        """``"distance=0.5"``, ``"distance=0.25/0.5,touch"`` or ``"touch"`` (the command line's form)."""
        edges: list[float] = []
        touch = False
        for part in filter(None, (p.strip() for p in text.split(","))):
            name, sep, value = part.partition("=")
            if name == "touch" and not sep:
                touch = True
            elif name == "distance" and sep:
                try:
                    edges = [float(v) for v in value.split("/")]
                except ValueError:
                    raise ValueError(f"Expected distance=EDGE[/EDGE...] with numbers, got {part!r}") from None
            else:
                raise ValueError(f"Expected distance=EDGE[/EDGE...] and/or touch, got {part!r} in {text!r}")
        return cls(tuple(edges), touch)

    @classmethod
    def from_json(cls, data: object, what: str = "option_end") -> OptionEnd:
        """The rule a bundle records (:meth:`to_json`), checked; a ``LimitError`` otherwise."""
        if not isinstance(data, Mapping) or set(data) - {"distance_edges", "goal_touch"}:
            raise LimitError(f"{what}: expected distance_edges and goal_touch, got {brief(data)}")
        edges, touch = data.get("distance_edges", []), data.get("goal_touch", False)
        if not isinstance(edges, list) or len(edges) > 16 or not isinstance(touch, bool):
            raise LimitError(f"{what}: expected a short list of edges and a boolean, got {brief(data)}")
        try:
            return cls(tuple(edges), touch)
        except (ValueError, TypeError) as error:
            raise LimitError(f"{what}: {error}") from None

    def to_json(self) -> dict[str, Any]:
        """The rule as a bundle records it (``selection.option_end``)."""
        return {"distance_edges": list(self.distance_edges), "goal_touch": self.goal_touch}

    def bind(self, layout: StateLayout) -> Callable[[np.ndarray], tuple[int, bool]]:
        """The band of a (full) observation of an env of this state ``layout``: the option ends when it changes."""
        try:
            distances = layout["joint_obstacle_distances"] if self.distance_edges else None
            touched = layout["goal_touched"].start if self.goal_touch else None
        except (KeyError, ValueError):
            raise ValueError(
                f"Options that end by state read joint_obstacle_distances / goal_touched, which this env's state "
                f"does not hold (its components: {list(layout)})"
            ) from None
        edges = np.asarray(self.distance_edges)

        def band(obs: np.ndarray) -> tuple[int, bool]:
            level = (
                int(np.searchsorted(edges, float(np.min(obs[distances])), side="right")) if distances else 0
            )
            return level, bool(obs[touched] > 0.5) if touched is not None else False

        return band

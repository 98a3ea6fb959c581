"""Named slices of the shared state, so any agent can be fed a chosen subset of it (paper design spec 4)."""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping

import numpy as np


class StateLayout(Mapping[str, slice]):
    """
    An ordered mapping from a state component's name to its slice of the flat observation.

    :param sizes: ``(name, length)`` pairs in observation order.
    """

    def __init__(self, sizes: Iterable[tuple[str, int]]) -> None:
        self._slices: dict[str, slice] = {}
        start = 0
        for name, length in sizes:
            self._slices[name] = slice(start, start + length)
            start += length
        self.size = start

    def __getitem__(self, name: str) -> slice:
        if name not in self._slices:
            raise KeyError(f"Unknown state component {name!r}; known: {list(self._slices)}")
        return self._slices[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._slices)

    def __len__(self) -> int:
        return len(self._slices)

    def indices(self, names: Iterable[str]) -> np.ndarray:
        """
        The indices that select the named components from an observation, in the order given.

        :param names: component names, e.g. ``["joint_positions", "ee_to_goal"]``.
        """
        names = list(names)
        unknown = [n for n in names if n not in self._slices]
        if unknown:
            raise ValueError(f"Unknown state components {unknown!r:.200}; known: {list(self._slices)}")
        if len(set(names)) != len(names):
            raise ValueError(f"Expected each state component named once, actually: {names!r:.200}")
        return np.concatenate([np.arange(self.size)[self._slices[n]] for n in names])

    def view(self, names: Iterable[str]) -> StateLayout:
        """The layout of an observation that holds only the named components, in the order given."""
        names = list(names)
        self.indices(names)  # unknown or repeated names are refused there
        return StateLayout((n, self._slices[n].stop - self._slices[n].start) for n in names)

    def __repr__(self) -> str:
        parts = ", ".join(f"{k}={v.start}:{v.stop}" for k, v in self._slices.items())
        return f"StateLayout({parts})"


def build_state_layout(n_joints: int) -> StateLayout:
    """
    The layout of :class:`~sb3_hddpg.envs.snake.SnakeArmEnv`'s observation (Table 1 of the paper).

    :param n_joints: the arm's number of joints.
    """
    return StateLayout(
        [
            ("joint_positions", 2 * n_joints),
            ("ee_to_goal", 2),
            ("joint_obstacle_vectors", 2 * n_joints),
            ("joint_obstacle_distances", n_joints),
            ("goal_touched", 1),
            ("obstacle_touched", n_joints),
        ]
    )

"""``OptionState``: the option each env is in, what ``Hierarchy.predict`` passes as a recurrent policy's state."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass
class OptionState:
    """
    Per env of a batch: the option it is in and what its manager saw last (``predict`` updates it in place).

    :param left: env steps left in each env's option (0: decide at the next step).
    :param choice: the index of each env's chosen worker.
    :param probabilities: each env's worker probabilities at its last decision, shape ``(n_envs, n_workers)``.
    :param band: each env's option-end band at its last decision (``None``: no band rule, or none yet).
    :param previous: each env's last observation, for a manager that observes motion (``None``: none yet).
    :param manager_action: each env's manager output at its last decision (``None``: none yet).
    :param workers: per env, worker index -> the state of a worker that is itself a hierarchy.
    """

    left: np.ndarray
    choice: np.ndarray
    probabilities: np.ndarray
    band: list[tuple[int, bool] | None]
    previous: list[np.ndarray | None]
    manager_action: list[np.ndarray | None]
    workers: list[dict[int, OptionState]]

    @classmethod
    def initial(
        cls, n_envs: int, n_workers: int, worker_states: Callable[[], dict[int, OptionState]]
    ) -> OptionState:
        """
        The state of ``n_envs`` envs at their episodes' start: no option, nothing seen.

        :param n_envs: the number of envs (rows of a batch; 1 for one observation).
        :param n_workers: the number of workers.
        :param worker_states: a fresh state for each worker that is a hierarchy, called once per env.
        """
        if n_envs < 1:
            raise ValueError(f"Expected `n_envs` to be at least 1, actually: {n_envs}")
        return cls(
            left=np.zeros(n_envs, dtype=np.int64),
            choice=np.zeros(n_envs, dtype=np.int64),
            probabilities=np.full((n_envs, n_workers), 1.0 / n_workers),
            band=[None] * n_envs,
            previous=[None] * n_envs,
            manager_action=[None] * n_envs,
            workers=[worker_states() for _ in range(n_envs)],
        )

    @property
    def n_envs(self) -> int:
        """The number of envs this state follows."""
        return len(self.left)

    def reset(self, index: int | None = None) -> None:
        """
        End the option of env ``index`` (``None``: of every env) and forget what its manager saw, as at an
        episode's start; nested hierarchies' options end with it.
        """
        for i in range(self.n_envs) if index is None else (index,):
            self.left[i] = 0
            self.band[i] = None
            self.previous[i] = None
            for nested in self.workers[i].values():
                nested.reset()

    def end_options(self) -> None:
        """End every env's option (the next step decides anew) but keep what the managers saw."""
        self.left[:] = 0

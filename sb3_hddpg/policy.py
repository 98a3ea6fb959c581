"""The policy protocol: anything that acts like an SB3 model's ``predict`` is a policy, and can be a worker."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Policy(Protocol):
    """
    What every policy in sb3-hddpg is: an SB3 model, a :class:`~sb3_hddpg.hierarchy.hierarchy.Hierarchy`, the HAM
    switch, or any object with SB3's ``predict`` signature. Any policy can be a worker of a manager.
    """

    def predict(
        self,
        observation: np.ndarray,
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]: ...

"""The policy protocol: anything that acts like an SB3 model's ``predict`` is a policy, and can be a worker."""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Policy(Protocol):
    """
    What every policy in sb3-hddpg is: an SB3 model, a :class:`~sb3_hddpg.hierarchy.hierarchy.Hierarchy`, the HAM
    switch, or any object with SB3's ``predict`` signature. Any policy can be a worker of a manager.

    ``state`` is whatever the policy carries from step to step, returned by one call and given to the next
    (SB3's recurrent policies: their hidden states; a hierarchy: the option each env is in; ``None``: none).
    """

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, Any]: ...

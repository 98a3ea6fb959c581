"""Hand-written policies to compare learned ones against."""

import importlib
from typing import Any

# Each loads with its first use: the training and evaluation commands need none of them.
_LAZY = {
    "HAMSwitch": "sb3_hddpg.baselines.ham",
    "load_ham": "sb3_hddpg.baselines.ham",
    "save_ham": "sb3_hddpg.baselines.ham",
    "RandomPolicy": "sb3_hddpg.baselines.random",
    "IKReacher": "sb3_hddpg.envs.snake.controllers",
    "JacobianReacher": "sb3_hddpg.envs.snake.controllers",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'sb3_hddpg.baselines' has no attribute {name!r}")


__all__ = ["HAMSwitch", "IKReacher", "JacobianReacher", "RandomPolicy", "load_ham", "save_ham"]

"""Hand-written policies to compare learned ones against."""

from sb3_hddpg.lazy import lazy_attributes

# Each loads with its first use: the training and evaluation commands need none of them.
_LAZY = {
    "HAMSwitch": "sb3_hddpg.baselines.ham",
    "load_ham": "sb3_hddpg.baselines.ham",
    "save_ham": "sb3_hddpg.baselines.ham",
    "RandomPolicy": "sb3_hddpg.baselines.random",
    "IKReacher": "sb3_hddpg.envs.snake.controllers",
    "JacobianReacher": "sb3_hddpg.envs.snake.controllers",
}

__getattr__ = lazy_attributes(__name__, _LAZY)


__all__ = ["HAMSwitch", "IKReacher", "JacobianReacher", "RandomPolicy", "load_ham", "save_ham"]

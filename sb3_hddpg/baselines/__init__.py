"""Hand-written policies to compare learned ones against."""

from sb3_hddpg.baselines.ham import HAMSwitch, load_ham, save_ham
from sb3_hddpg.baselines.random import RandomPolicy
from sb3_hddpg.envs.snake.controllers import IKReacher, JacobianReacher

__all__ = ["HAMSwitch", "IKReacher", "JacobianReacher", "RandomPolicy", "load_ham", "save_ham"]

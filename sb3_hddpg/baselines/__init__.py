"""Hand-written policies to compare learned ones against."""

from sb3_hddpg.baselines.ham import HAMSwitch, load_ham, save_ham
from sb3_hddpg.baselines.scripted import JacobianReacher

__all__ = ["HAMSwitch", "JacobianReacher", "load_ham", "save_ham"]

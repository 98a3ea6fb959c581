"""Hand-written policies to compare learned ones against."""

from sb3_hddpg.baselines.scripted import JacobianReacher

__all__ = ["JacobianReacher"]

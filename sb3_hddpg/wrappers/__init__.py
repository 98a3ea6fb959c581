"""Gymnasium wrappers of sb3-hddpg."""

from sb3_hddpg.hierarchy.preference import PreferenceReward
from sb3_hddpg.hierarchy.wrapper import WorkerSelectionWrapper

__all__ = ["PreferenceReward", "WorkerSelectionWrapper"]

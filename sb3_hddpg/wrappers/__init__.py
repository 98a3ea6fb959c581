"""Gymnasium wrappers of sb3-hddpg."""

from sb3_hddpg.wrappers.preference import PreferenceReward
from sb3_hddpg.wrappers.selection import WorkerSelectionWrapper

__all__ = ["PreferenceReward", "WorkerSelectionWrapper"]

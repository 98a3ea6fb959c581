"""Gymnasium wrappers of sb3-hddpg."""

from sb3_hddpg.wrappers.selection import WorkerSelectionWrapper

__all__ = ["WorkerSelectionWrapper"]

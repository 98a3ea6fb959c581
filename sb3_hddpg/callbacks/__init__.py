"""SB3 callbacks of sb3-hddpg."""

from sb3_hddpg.callbacks.checkpoint import ResumableCheckpointCallback, read_checkpoint_state
from sb3_hddpg.callbacks.evaluation import MetricsEvalCallback
from sb3_hddpg.callbacks.selection import SelectionStatsCallback

__all__ = [
    "MetricsEvalCallback",
    "ResumableCheckpointCallback",
    "SelectionStatsCallback",
    "read_checkpoint_state",
]

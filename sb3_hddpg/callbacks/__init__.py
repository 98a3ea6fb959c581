"""SB3 callbacks of sb3-hddpg."""

from sb3_hddpg.callbacks.checkpoint import ResumableCheckpointCallback, read_checkpoint_state
from sb3_hddpg.callbacks.evaluation import MetricsEvalCallback
from sb3_hddpg.callbacks.pruning import TrialPruningCallback, parameters_finite
from sb3_hddpg.callbacks.selection import SelectionStatsCallback

__all__ = [
    "MetricsEvalCallback",
    "ResumableCheckpointCallback",
    "SelectionStatsCallback",
    "TrialPruningCallback",
    "parameters_finite",
    "read_checkpoint_state",
]

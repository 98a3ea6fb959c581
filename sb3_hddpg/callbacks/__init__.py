"""SB3 callbacks of sb3-hddpg."""

from sb3_hddpg.callbacks.action_penalty import ActionL2Penalty, apply_action_l2
from sb3_hddpg.callbacks.checkpoint import ResumableCheckpointCallback, read_checkpoint_state
from sb3_hddpg.callbacks.controller_prior import ControllerPrior
from sb3_hddpg.callbacks.evaluation import MetricsEvalCallback
from sb3_hddpg.callbacks.selection_stats import SelectionStatsCallback

__all__ = [
    "ActionL2Penalty",
    "ControllerPrior",
    "MetricsEvalCallback",
    "ResumableCheckpointCallback",
    "SelectionStatsCallback",
    "apply_action_l2",
    "read_checkpoint_state",
]

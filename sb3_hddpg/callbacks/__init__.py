"""SB3 callbacks of sb3-hddpg."""

from sb3_hddpg.callbacks.action_penalty import ActionL2Penalty, apply_action_l2
from sb3_hddpg.callbacks.checkpoint import ResumableCheckpointCallback, read_checkpoint_state
from sb3_hddpg.callbacks.controller_prior import ControllerPrior
from sb3_hddpg.callbacks.evaluation import MetricsEvalCallback
from sb3_hddpg.callbacks.pruning import TrialPruningCallback, parameters_finite
from sb3_hddpg.callbacks.selection_stats import SelectionStatsCallback

__all__ = [
    "ActionL2Penalty",
    "ControllerPrior",
    "MetricsEvalCallback",
    "ResumableCheckpointCallback",
    "SelectionStatsCallback",
    "TrialPruningCallback",
    "apply_action_l2",
    "parameters_finite",
    "read_checkpoint_state",
]

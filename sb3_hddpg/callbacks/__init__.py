"""SB3 callbacks of sb3-hddpg."""

from sb3_hddpg.lazy import lazy_attributes

# Each module loads with its first use: a run that asks for no actor term never loads the actor-loss code.
_LAZY = {
    "ActionL2Penalty": "sb3_hddpg.callbacks.action_penalty",
    "apply_action_l2": "sb3_hddpg.callbacks.action_penalty",
    "ResumableCheckpointCallback": "sb3_hddpg.callbacks.checkpoint",
    "read_checkpoint_state": "sb3_hddpg.callbacks.checkpoint",
    "ControllerPrior": "sb3_hddpg.callbacks.controller_prior",
    "MetricsEvalCallback": "sb3_hddpg.callbacks.evaluation",
    "SelectionStatsCallback": "sb3_hddpg.callbacks.selection_stats",
}

__getattr__ = lazy_attributes(__name__, _LAZY)
__all__ = sorted(_LAZY)

"""SB3 callbacks of sb3-hddpg."""

import importlib
from typing import Any

# Each module loads with its first use: a run that asks for no actor term (the action penalty, the
# controller prior) never loads the actor-loss machinery.
_LAZY = {
    "ActionL2Penalty": "sb3_hddpg.callbacks.action_penalty",
    "apply_action_l2": "sb3_hddpg.callbacks.action_penalty",
    "ResumableCheckpointCallback": "sb3_hddpg.callbacks.checkpoint",
    "read_checkpoint_state": "sb3_hddpg.callbacks.checkpoint",
    "ControllerPrior": "sb3_hddpg.callbacks.controller_prior",
    "MetricsEvalCallback": "sb3_hddpg.callbacks.evaluation",
    "SelectionStatsCallback": "sb3_hddpg.callbacks.selection_stats",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'sb3_hddpg.callbacks' has no attribute {name!r}")


__all__ = [
    "ActionL2Penalty",
    "ControllerPrior",
    "MetricsEvalCallback",
    "ResumableCheckpointCallback",
    "SelectionStatsCallback",
    "apply_action_l2",
    "read_checkpoint_state",
]

"""Training: the algorithm registry and backends, the RL Zoo config, ``train_agent`` and what is built on it."""

from sb3_hddpg.training.run_options import RunOptions
from sb3_hddpg.training.training import (
    ManagerSetup,
    Workers,
    load_workers,
    prepare_manager,
    train_flat,
    train_manager,
    train_workers,
)

__all__ = [
    "ManagerSetup",
    "RunOptions",
    "Workers",
    "load_workers",
    "prepare_manager",
    "train_flat",
    "train_manager",
    "train_workers",
]

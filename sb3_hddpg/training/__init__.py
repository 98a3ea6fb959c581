"""Training: the algorithm registry and backends, the RL Zoo config, ``train_agent`` and what is built on it."""

from sb3_hddpg.training.run_options import RunOptions
from sb3_hddpg.training.training import load_workers, train_flat, train_manager, train_workers

__all__ = ["RunOptions", "load_workers", "train_flat", "train_manager", "train_workers"]

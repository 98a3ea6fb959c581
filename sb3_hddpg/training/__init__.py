"""Training: the algorithm registry and backends, the RL Zoo config, ``train_agent`` and what is built on it."""

from sb3_hddpg.artifacts.manifests import load_workers
from sb3_hddpg.artifacts.workers import Workers
from sb3_hddpg.training.flat import FlatResult, train_flat
from sb3_hddpg.training.manager import ManagerResult, train_manager
from sb3_hddpg.training.manager_setup import ManagerOptions, ManagerSetup, prepare_manager, setup_manager
from sb3_hddpg.training.run_options import RunOptions
from sb3_hddpg.training.workers import WorkersResult, train_workers

__all__ = [
    "FlatResult",
    "ManagerOptions",
    "ManagerResult",
    "ManagerSetup",
    "RunOptions",
    "Workers",
    "WorkersResult",
    "load_workers",
    "prepare_manager",
    "setup_manager",
    "train_flat",
    "train_manager",
    "train_workers",
]

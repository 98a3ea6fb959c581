"""Training: the algorithm registry and backends, the RL Zoo config, ``train_agent`` and what is built on it."""

from sb3_hddpg.artifacts.manifests import load_workers
from sb3_hddpg.artifacts.workers import Workers
from sb3_hddpg.training.flat import train_flat
from sb3_hddpg.training.manager import train_manager
from sb3_hddpg.training.manager_setup import ManagerOptions, ManagerSetup, prepare_manager, setup_manager
from sb3_hddpg.training.run_options import RunOptions
from sb3_hddpg.training.workers import train_workers

__all__ = [
    "ManagerOptions",
    "ManagerSetup",
    "RunOptions",
    "Workers",
    "load_workers",
    "prepare_manager",
    "setup_manager",
    "train_flat",
    "train_manager",
    "train_workers",
]

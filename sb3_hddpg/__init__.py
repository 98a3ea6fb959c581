"""sb3-hddpg: Hierarchical DDPG (Um, Nethala & Shin, AI 2022) on Stable-Baselines3."""

import os

from sb3_hddpg.envs import ENV_IDS, SnakeArmEnv
from sb3_hddpg.lazy import lazy_attributes
from sb3_hddpg.policy_loaders import register_policy_loader

with open(os.path.join(os.path.dirname(__file__), "version.txt")) as _file:
    __version__ = _file.read().strip()

# The heavy parts (torch, SB3) load on first use, so that `import sb3_hddpg` (which registers the env ids,
# e.g. in every SubprocVecEnv worker or for rl_zoo3's --gym-packages) stays cheap.
_LAZY = {
    "Hierarchy": "sb3_hddpg.hierarchy.hierarchy",
    "SelectionConfig": "sb3_hddpg.hierarchy.hierarchy",
    "WorkerSelectionWrapper": "sb3_hddpg.hierarchy.wrapper",
    "Workers": "sb3_hddpg.artifacts.workers",
    "evaluate": "sb3_hddpg.evaluation",
    "load_policy": "sb3_hddpg.hierarchy.loading",
    "load_workers": "sb3_hddpg.artifacts.manifests",
    "prepare_manager": "sb3_hddpg.training.manager_setup",
    "train_flat": "sb3_hddpg.training.flat",
    "train_manager": "sb3_hddpg.training.manager",
    "train_workers": "sb3_hddpg.training.workers",
}


# The policies a path may name besides bundles and SB3 zips, registered by entry point as the env ids are:
# the core imports none of them, and a module is imported only when its loader is first used.
register_policy_loader("ham", "sb3_hddpg.baselines.ham:load_ham_policy", suffixes=(".json",))
register_policy_loader(
    "reference",
    "sb3_hddpg.baselines.reference:load_reference_policy",
    names=("random", "scripted", "ik", "field"),
)

__getattr__ = lazy_attributes(__name__, _LAZY)


__all__ = ["ENV_IDS", "SnakeArmEnv", "__version__", *_LAZY]

"""sb3-hddpg: Hierarchical DDPG (Um, Nethala & Shin, AI 2022) on Stable-Baselines3."""

import os

from sb3_hddpg.envs import ENV_IDS, SnakeArmEnv

with open(os.path.join(os.path.dirname(__file__), "version.txt")) as _file:
    __version__ = _file.read().strip()

__all__ = ["ENV_IDS", "SnakeArmEnv", "__version__"]

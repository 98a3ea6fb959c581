"""The environments of sb3-hddpg, registered with gymnasium when :mod:`sb3_hddpg` is imported."""

from gymnasium.envs.registration import register, registry

from sb3_hddpg.envs.layout import StateLayout, build_state_layout
from sb3_hddpg.envs.snake import REWARD_TERMS, SnakeArmEnv

#: Steps per episode of every registered id (20 s of simulated time at the default ``dt``).
MAX_EPISODE_STEPS = 200

#: Registered id -> the reward it returns. One shared environment, one reward per id (paper spec 1 and 4).
ENV_IDS = {
    "hddpg/SnakeGoal-v0": "goal",
    "hddpg/SnakeAvoid-v0": "avoid",
    "hddpg/SnakeReach-v0": "reach",
}


def register_envs() -> None:
    """Register the snake-arm ids with gymnasium; safe to call more than once."""
    for env_id, reward in ENV_IDS.items():
        if env_id not in registry:
            register(
                id=env_id,
                entry_point="sb3_hddpg.envs.snake:SnakeArmEnv",
                max_episode_steps=MAX_EPISODE_STEPS,
                kwargs={"reward": reward},
            )


register_envs()

__all__ = ["ENV_IDS", "MAX_EPISODE_STEPS", "REWARD_TERMS", "SnakeArmEnv", "StateLayout", "build_state_layout"]

"""The environments of sb3-hddpg, registered with gymnasium when :mod:`sb3_hddpg` is imported."""

from typing import Any

from gymnasium.envs.registration import register, registry

from sb3_hddpg.envs.adapters import (
    ADAPTER_ENV_IDS,
    INFO_TERMS_ENV_ID,
    MULTI_OBJECTIVE_ENV_ID,
    EnvUnavailableError,
    InfoTermsEnv,
    MultiObjectiveEnv,
    TermReward,
)
from sb3_hddpg.envs.contract import (
    Proximity,
    RewardTermsEnv,
    TermNormaliser,
    env_contract,
    proximity_of,
    state_layout_of,
)
from sb3_hddpg.envs.ids import (
    ENV_IDS,
    SNAKE_AVOID_ENV_ID,
    SNAKE_GOAL_ENV_ID,
    SNAKE_MO_ENV_ID,
    SNAKE_REACH_ENV_ID,
    WORKER_ENV_IDS,
)
from sb3_hddpg.envs.layout import StateLayout, build_state_layout
from sb3_hddpg.envs.snake import REWARD_TERMS, SnakeArmEnv
from sb3_hddpg.lazy import lazy_attributes

#: Steps per episode of every registered id (20 s of simulated time at the default ``dt``).
MAX_EPISODE_STEPS = 200


#: Every id this package registers (the default allow-list for env ids read from files).
OWN_ENV_IDS = (*ENV_IDS, SNAKE_MO_ENV_ID, *ADAPTER_ENV_IDS)


def register_envs() -> None:
    """Register this package's ids with gymnasium; safe to call more than once."""
    snake: dict[str, Any] = {
        "entry_point": "sb3_hddpg.envs.snake:SnakeArmEnv",
        "max_episode_steps": MAX_EPISODE_STEPS,
    }
    # Gymnasium's checker expects a scalar reward, MO-Gymnasium's API returns a vector; an adapter's time
    # limit is the adapted env's.
    vector: dict[str, Any] = {"disable_env_checker": True}
    settings: dict[str, dict[str, Any]] = {
        env_id: {**snake, "kwargs": {"reward": reward}} for env_id, reward in ENV_IDS.items()
    }
    settings[SNAKE_MO_ENV_ID] = {**snake, **vector, "entry_point": "sb3_hddpg.envs.snake_mo:SnakeMOEnv"}
    settings[MULTI_OBJECTIVE_ENV_ID] = {**vector, "entry_point": "sb3_hddpg.envs.adapters:MultiObjectiveEnv"}
    settings[INFO_TERMS_ENV_ID] = {**vector, "entry_point": "sb3_hddpg.envs.adapters:InfoTermsEnv"}
    for env_id, kwargs in settings.items():
        if env_id not in registry:
            register(id=env_id, **kwargs)


register_envs()
# The MO-Gymnasium speaker loads when made or first named: only MORL libraries use it.
__getattr__ = lazy_attributes(__name__, {"SnakeMOEnv": "sb3_hddpg.envs.snake_mo"})

__all__ = [
    "ADAPTER_ENV_IDS",
    "ENV_IDS",
    "INFO_TERMS_ENV_ID",
    "MAX_EPISODE_STEPS",
    "MULTI_OBJECTIVE_ENV_ID",
    "OWN_ENV_IDS",
    "REWARD_TERMS",
    "SNAKE_AVOID_ENV_ID",
    "SNAKE_GOAL_ENV_ID",
    "SNAKE_MO_ENV_ID",
    "SNAKE_REACH_ENV_ID",
    "WORKER_ENV_IDS",
    "EnvUnavailableError",
    "InfoTermsEnv",
    "MultiObjectiveEnv",
    "Proximity",
    "RewardTermsEnv",
    "SnakeArmEnv",
    "SnakeMOEnv",
    "StateLayout",
    "TermNormaliser",
    "TermReward",
    "build_state_layout",
    "env_contract",
    "proximity_of",
    "state_layout_of",
]

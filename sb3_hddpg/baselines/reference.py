"""
The reference policies a user names instead of a file (``random``, and the snake's scripted controllers
``scripted``, ``ik`` and ``field``), as loaders in :mod:`sb3_hddpg.policy_loaders`.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym

from sb3_hddpg.baselines.random import RandomPolicy
from sb3_hddpg.envs import SnakeArmEnv
from sb3_hddpg.envs.contract import state_layout_of
from sb3_hddpg.envs.snake.controllers import JacobianReacher, make_controller
from sb3_hddpg.policy import Policy
from sb3_hddpg.policy_loaders import LoadedPolicy, policy_names


def load_reference_policy(name: str, env_id: str, env_kwargs: dict[str, Any]) -> LoadedPolicy:
    """
    A reference policy on ``env_id``: uniform random actions, or one of the snake's scripted controllers.

    :param name: ``random``, ``scripted``, ``ik`` or ``field`` (the names ``sb3_hddpg`` registers for it).
    :param env_id: the env it acts in.
    :param env_kwargs: that env's keyword arguments.
    """
    env = gym.make(env_id, **env_kwargs)
    layout = state_layout_of(env)
    try:
        if name == "random":
            policy: Policy = RandomPolicy(env.action_space, seed=0)
        elif name in ("ik", "field"):
            snake = env.unwrapped
            if not isinstance(snake, SnakeArmEnv):
                raise ValueError(f"The {name} controller drives the snake arm only, not {env_id!r}")
            policy = make_controller(name, layout, max_joint_speed=snake.max_joint_speed)
        elif name == "scripted":
            policy = JacobianReacher(layout)
        else:
            raise ValueError(f"Expected a policy name in {policy_names()}, actually: {name!r}")
    finally:
        env.close()
    return LoadedPolicy(policy, env_id, env_kwargs, name, name)

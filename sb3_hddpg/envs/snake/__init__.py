"""The snake arm (the paper's Figure 2 task): its parameters, physics, movers, rewards, env, view and renderer."""

from sb3_hddpg.envs.snake.env import SnakeArmEnv
from sb3_hddpg.envs.snake.params import REWARD_TERMS, SnakeParams
from sb3_hddpg.envs.snake.rewards import GoalTerm

__all__ = ["REWARD_TERMS", "GoalTerm", "SnakeArmEnv", "SnakeParams"]

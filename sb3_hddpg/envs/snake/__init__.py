"""
The snake arm (the paper's Figure 2 task): its parameters (:mod:`.params`), its pymunk body
(:mod:`.physics`), the goal's and the obstacles' motion (:mod:`.movers`), the reward terms (:mod:`.rewards`),
the gymnasium env over them (:mod:`.env`), a read-only view of its state (:mod:`.view`) and its renderer
(:mod:`.rendering`, loaded only when drawing).
"""

from sb3_hddpg.envs.snake.env import SnakeArmEnv
from sb3_hddpg.envs.snake.params import REWARD_TERMS, SnakeParams
from sb3_hddpg.envs.snake.rewards import GoalTerm

__all__ = ["REWARD_TERMS", "GoalTerm", "SnakeArmEnv", "SnakeParams"]

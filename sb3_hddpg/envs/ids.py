"""The snake arm's registered env ids: each spelled once, here."""

from __future__ import annotations

#: The goal worker's env: the snake arm rewarding the goal term.
SNAKE_GOAL_ENV_ID = "hddpg/SnakeGoal-v0"
#: The avoid worker's env: the snake arm rewarding the avoid term.
SNAKE_AVOID_ENV_ID = "hddpg/SnakeAvoid-v0"
#: The shared env: the snake arm rewarding both terms, normalised (the manager's, the flat baseline's and
#: HAM's task, and the default env wherever none is named).
SNAKE_REACH_ENV_ID = "hddpg/SnakeReach-v0"
#: The snake arm with MO-Gymnasium's vector reward and ``reward_space``.
SNAKE_MO_ENV_ID = "hddpg/SnakeMO-v0"

#: Registered id -> the reward it returns. One shared environment, one reward per id (paper spec 1 and 4).
ENV_IDS = {
    SNAKE_GOAL_ENV_ID: "goal",
    SNAKE_AVOID_ENV_ID: "avoid",
    SNAKE_REACH_ENV_ID: "reach",
}
#: Worker name -> the registered env id whose reward it learns (the snake arm's terms).
WORKER_ENV_IDS = {"goal": SNAKE_GOAL_ENV_ID, "avoid": SNAKE_AVOID_ENV_ID}

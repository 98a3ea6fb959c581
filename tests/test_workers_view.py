"""Workers carry the state components they see: the wrapper and a Hierarchy feed each its own view."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

from sb3_hddpg.artifacts.workers import Workers
from sb3_hddpg.hierarchy.hierarchy import Hierarchy
from sb3_hddpg.hierarchy.wrapper import WorkerSelectionWrapper
from tests.helpers import ConstantWorker

GOAL_VIEW = ["joint_positions", "ee_to_goal", "goal_touched"]


def _workers(env: gym.Env, goal_view: list[str] | int) -> dict[str, ConstantWorker]:
    """Fake goal and avoid workers; the goal worker sees ``goal_view`` (component names, or a count)."""
    box = env.observation_space
    assert isinstance(box, spaces.Box)
    index = (
        np.arange(goal_view) if isinstance(goal_view, int) else env.unwrapped.state_layout.indices(goal_view)
    )
    goal_space = spaces.Box(box.low[index], box.high[index], dtype=np.float32)
    action = np.zeros(env.action_space.shape, dtype=np.float32)
    return {
        "goal": ConstantWorker(action, goal_space, env.action_space),
        "avoid": ConstantWorker(action, box, env.action_space),
    }


def test_a_plain_worker_with_a_partial_view_gets_the_fix_in_one_line():
    env = gym.make("hddpg/SnakeReach-v0")
    with pytest.raises(ValueError) as error:
        WorkerSelectionWrapper(env, _workers(env, 15))
    message = str(error.value)
    assert "\n" not in message
    assert message.startswith(
        f"Worker 'goal' sees 15 values but the env gives {env.observation_space.shape[0]}"
    )
    assert "sb3_hddpg.load_workers(folder)" in message and "worker_states={'goal': [...]}" in message


def test_workers_that_carry_their_view_need_no_worker_states():
    env = gym.make("hddpg/SnakeReach-v0")
    size = len(env.unwrapped.state_layout.indices(GOAL_VIEW))
    workers = Workers(_workers(env, GOAL_VIEW), {"goal": GOAL_VIEW}, "hddpg/SnakeReach-v0", {})
    wrapper = WorkerSelectionWrapper(workers.make_env(), workers)
    assert wrapper.worker_states == {"goal": GOAL_VIEW}
    obs, _ = wrapper.reset(seed=3)
    wrapper.step(np.array([1.0, -1.0], dtype=np.float32))
    shown = [w.last_obs for w in workers.values() if w.last_obs is not None]
    assert shown and all(o.shape in ((size,), obs.shape) for o in shown)
    # An explicit worker_states entry wins over the carried one.
    given = WorkerSelectionWrapper(
        workers.make_env(), workers, worker_states={"goal": GOAL_VIEW[:2] + GOAL_VIEW[2:]}
    )
    assert given.worker_states["goal"] == GOAL_VIEW


def test_a_hierarchy_over_carried_views_reads_them_and_the_shared_env():
    env = gym.make("hddpg/SnakeReach-v0")
    workers = Workers(
        _workers(env, GOAL_VIEW), {"goal": GOAL_VIEW}, "hddpg/SnakeReach-v0", {"n_obstacles": 2}
    )
    manager = ConstantWorker(
        np.zeros(2, np.float32), env.observation_space, spaces.Box(-1, 1, (2,), np.float32)
    )
    hierarchy = Hierarchy(manager, workers)  # type: ignore[arg-type]
    assert hierarchy.config.worker_states == {"goal": GOAL_VIEW}
    assert (hierarchy.env_id, hierarchy.env_kwargs) == ("hddpg/SnakeReach-v0", {"n_obstacles": 2})
    assert hierarchy.make_env().unwrapped.spec.kwargs["n_obstacles"] == 2


def test_the_wrapper_documents_its_own_arguments():
    doc = WorkerSelectionWrapper.__init__.__doc__ or ""
    assert ":param workers:" in doc and ":param worker_states:" in doc
    assert "Wraps an environment" not in doc


def test_the_public_entry_points_import_from_the_package_and_from_training():
    import sb3_hddpg
    import sb3_hddpg.training as training

    for name in (
        "load_workers",
        "prepare_manager",
        "train_workers",
        "train_manager",
        "train_flat",
        "Workers",
    ):
        assert getattr(sb3_hddpg, name) is getattr(training, name), name

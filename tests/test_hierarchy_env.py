"""``Hierarchy(manager, workers, config)`` finds its env from the models and refuses models that do not fit it."""

import io

import gymnasium as gym
import pytest
from stable_baselines3 import DDPG

from sb3_hddpg.hierarchy import WorkerSelectionWrapper
from sb3_hddpg.hierarchy.hierarchy import Hierarchy, SelectionConfig, infer_env

CONFIG = SelectionConfig(preferences={"goal": 1.0, "avoid": 1.0})


def _ddpg(env: gym.Env) -> DDPG:
    return DDPG("MlpPolicy", env, policy_kwargs={"net_arch": [8]}, device="cpu")


def _hierarchy_models(env_id: str, **env_kwargs):
    workers = {
        "goal": _ddpg(gym.make("hddpg/SnakeGoal-v0", **env_kwargs)),
        "avoid": _ddpg(gym.make("hddpg/SnakeAvoid-v0", **env_kwargs)),
    }
    manager = _ddpg(WorkerSelectionWrapper(gym.make(env_id, **env_kwargs), workers))
    return manager, workers


def _without_env(model: DDPG) -> DDPG:
    """The model as a file gives it back: no training env attached."""
    buffer = io.BytesIO()
    model.save(buffer)
    buffer.seek(0)
    return DDPG.load(buffer, device="cpu")


def test_env_is_read_from_the_managers_training_env():
    manager, workers = _hierarchy_models("hddpg/SnakeGoal-v0", n_joints=3)
    hierarchy = Hierarchy(manager, workers, CONFIG)
    assert (hierarchy.env_id, hierarchy.env_kwargs) == ("hddpg/SnakeGoal-v0", {"n_joints": 3})
    assert hierarchy.observation_space == manager.observation_space


def test_env_is_read_from_the_workers_where_they_agree():
    env = gym.make("hddpg/SnakeGoal-v0", n_joints=3)
    workers = {"goal": _ddpg(env), "avoid": _ddpg(env)}
    manager = _without_env(_ddpg(WorkerSelectionWrapper(env, workers)))
    assert infer_env(manager, workers) == ("hddpg/SnakeGoal-v0", {"n_joints": 3})
    # Workers on different ids (the usual goal/avoid pair) do not say which env the manager acts in.
    _, pair = _hierarchy_models("hddpg/SnakeReach-v0")
    assert infer_env(manager, pair) is None


def test_models_that_do_not_fit_the_env_fail_at_construction_naming_the_mismatch():
    manager, workers = _hierarchy_models("hddpg/SnakeReach-v0", n_joints=3)
    loaded = {name: _without_env(worker) for name, worker in workers.items()}
    # Loaded from files the models carry no env: the default snake env (6 joints) does not fit them.
    with pytest.raises(ValueError, match=r"^The manager has observations of shape \(21,\).*needs \(39,\)"):
        Hierarchy(_without_env(manager), loaded, CONFIG)
    six_joints, _ = _hierarchy_models("hddpg/SnakeReach-v0")
    with pytest.raises(ValueError, match=r"^Worker 'goal' has observations of shape \(21,\).*needs \(39,\)"):
        Hierarchy(_without_env(six_joints), loaded, CONFIG)
    # With the env named, the same models are accepted.
    hierarchy = Hierarchy(_without_env(manager), loaded, CONFIG, env_kwargs={"n_joints": 3})
    assert hierarchy.env_id == "hddpg/SnakeReach-v0"
    # A manager trained over another number of workers.
    three = _ddpg(gym.make("hddpg/SnakeReach-v0", n_joints=3))
    with pytest.raises(
        ValueError, match=r"^The manager has actions of shape \(3,\).*needs \(2,\) \(one per worker\)"
    ):
        Hierarchy(three, workers, CONFIG)


def test_a_worker_trained_on_another_arm_is_named():
    manager, workers = _hierarchy_models("hddpg/SnakeReach-v0")
    workers["avoid"] = _ddpg(gym.make("hddpg/SnakeAvoid-v0", n_joints=4))
    with pytest.raises(ValueError, match=r"^Worker 'avoid' has observations of shape"):
        Hierarchy(manager, workers, CONFIG, env_id="hddpg/SnakeReach-v0")

"""
``FrozenWorker`` freezes copies, never the caller's model, and its numpy fast path acts exactly like
``predict`` (docs/ROBUSTNESS.md, "Integrity").
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from sb3_contrib import TQC
from stable_baselines3 import DDPG, SAC, TD3

import sb3_hddpg  # noqa: F401  (registers the ids)
from sb3_hddpg.hierarchy import WorkerSelectionWrapper
from sb3_hddpg.hierarchy.frozen import FrozenWorker
from sb3_hddpg.hierarchy.hierarchy import Hierarchy, SelectionConfig

SMALL = {"buffer_size": 500, "learning_starts": 20, "batch_size": 16, "seed": 0, "device": "cpu"}


def _model(cls: type, env_id: str, **kwargs: object) -> object:
    return cls("MlpPolicy", gym.make(env_id), policy_kwargs={"net_arch": [16, 16]}, **SMALL, **kwargs)


def _parameters(model: object) -> dict[str, th.Tensor]:
    return {k: v.detach().clone() for k, v in model.policy.state_dict().items()}  # type: ignore[attr-defined]


def test_a_worker_keeps_training_after_being_wrapped() -> None:
    goal = _model(DDPG, "hddpg/SnakeGoal-v0")
    avoid = _model(DDPG, "hddpg/SnakeAvoid-v0")
    env = WorkerSelectionWrapper(gym.make("hddpg/SnakeReach-v0"), {"goal": goal, "avoid": avoid})
    obs, _ = env.reset(seed=0)
    frozen_action = env.frozen[0].act(obs)
    before = _parameters(goal)
    assert all(p.requires_grad for p in goal.policy.parameters())  # type: ignore[attr-defined]
    goal.learn(60)  # type: ignore[attr-defined]
    after = _parameters(goal)
    assert any(not th.equal(before[k], after[k]) for k in before), "the worker did not train"
    # The wrapper froze a copy: it still acts with the weights it had when wrapped.
    np.testing.assert_array_equal(env.frozen[0].act(obs), frozen_action)


def test_the_manager_keeps_training_after_a_hierarchy_is_built() -> None:
    goal = _model(DDPG, "hddpg/SnakeGoal-v0")
    avoid = _model(DDPG, "hddpg/SnakeAvoid-v0")
    manager_env = WorkerSelectionWrapper(gym.make("hddpg/SnakeReach-v0"), {"goal": goal, "avoid": avoid})
    manager = DDPG("MlpPolicy", manager_env, policy_kwargs={"net_arch": [16]}, **SMALL)
    Hierarchy(
        manager, {"goal": goal, "avoid": avoid}, SelectionConfig(preferences={"goal": 1.0, "avoid": 1.0})
    )
    before = _parameters(manager)
    manager.learn(60)
    assert any(not th.equal(before[k], v) for k, v in _parameters(manager).items())


def test_the_torch_path_freezes_a_copy() -> None:
    # gSDE makes SAC's actor something the numpy path does not mirror: the torch path is used.
    sac = _model(SAC, "hddpg/SnakeGoal-v0", use_sde=True)
    frozen = FrozenWorker(sac)
    assert frozen._layers is None and frozen._policy is not sac.policy  # type: ignore[attr-defined]
    assert all(p.requires_grad for p in sac.policy.parameters())  # type: ignore[attr-defined]
    obs = np.random.default_rng(1).uniform(-1, 1, size=(4, *sac.observation_space.shape)).astype(np.float32)
    expected, _ = sac.predict(obs, deterministic=True)  # type: ignore[attr-defined]
    np.testing.assert_allclose(frozen.act(obs), expected, rtol=1e-5, atol=1e-5)
    sac.learn(40)  # type: ignore[attr-defined]


@pytest.mark.parametrize("cls", [DDPG, TD3, SAC, TQC], ids=lambda c: c.__name__)
def test_numpy_fast_path_matches_predict(cls: type) -> None:
    extra = {"policy_kwargs": {"net_arch": [32, 32], "n_quantiles": 5}} if cls is TQC else {}
    model = cls(
        "MlpPolicy",
        gym.make("hddpg/SnakeGoal-v0"),
        **SMALL,
        **(extra or {"policy_kwargs": {"net_arch": [32, 32]}}),
    )
    model.learn(60)  # trained weights, not the initial ones
    frozen = FrozenWorker(model)
    assert frozen._layers is not None, "the numpy fast path was not taken"
    rng = np.random.default_rng(0)
    batch = rng.uniform(-3, 3, size=(64, *model.observation_space.shape)).astype(np.float32)
    expected, _ = model.predict(batch, deterministic=True)
    np.testing.assert_allclose(frozen.act(batch), expected, rtol=1e-5, atol=1e-5)
    for row in batch[:8]:
        single, _ = model.predict(row, deterministic=True)
        np.testing.assert_allclose(frozen.act(row), single, rtol=1e-5, atol=1e-5)

"""Workers trained on part of the shared state (env kwarg ``observe``): env, training, bundle and HAM."""

import json

import gymnasium as gym
import numpy as np
import pytest
import yaml

from sb3_hddpg.baselines.ham import load_ham, save_ham
from sb3_hddpg.hierarchy.hierarchy import Hierarchy
from sb3_hddpg.training.config import DEFAULT_CONFIG
from sb3_hddpg.training.manager import train_manager
from sb3_hddpg.training.workers import train_workers

GOAL_VIEW = ["joint_positions", "ee_to_goal", "goal_touched"]


def test_observe_returns_the_named_components_of_the_full_state():
    part = gym.make("hddpg/SnakeGoal-v0", observe=GOAL_VIEW)
    full = gym.make("hddpg/SnakeGoal-v0")
    index = full.unwrapped.state_layout.indices(GOAL_VIEW)
    assert part.observation_space.shape == (15,) and part.unwrapped.observed_components == tuple(GOAL_VIEW)
    assert np.array_equal(part.observation_space.low, full.observation_space.low[index])
    a, _ = part.reset(seed=4)
    b, _ = full.reset(seed=4)
    assert np.array_equal(a, b[index])
    rng = np.random.default_rng(0)
    for _ in range(20):
        action = rng.uniform(-1, 1, 6).astype(np.float32)
        a, ra, *_ = part.step(action)
        b, rb, *_ = full.step(action)
        assert np.array_equal(a, b[index]) and ra == rb
        assert part.observation_space.contains(a)


@pytest.mark.parametrize(
    "observe, message",
    [
        ("ee_to_goal", "non-empty list"),
        ([], "non-empty list"),
        (["ee_to_goal", "nope"], "Unknown state components"),
        (["ee_to_goal", "ee_to_goal"], "once"),
    ],
)
def test_bad_observe_is_refused(observe, message):
    with pytest.raises(ValueError, match=message):
        gym.make("hddpg/SnakeGoal-v0", observe=observe)


@pytest.fixture(scope="module")
def partial_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("observe")
    config = yaml.safe_load(DEFAULT_CONFIG.read_text())
    for key in list(config):
        config[key].pop("<<", None)
    block = dict(config["hddpg/SnakeGoal-v0"])
    block["env_kwargs"] = {"observe": GOAL_VIEW}
    config["hddpg/SnakeGoal-v0"] = block
    path = root / "config.yml"
    path.write_text(yaml.safe_dump(config))
    tiny = {"timesteps": 300, "eval_freq": 0, "eval_episodes": 1}
    manifest = train_workers(root / "w", seed=1, config=path, **tiny).manifest
    hierarchy = train_manager(root / "w", root / "m", seed=1, config=path, **tiny).hierarchy
    return root, manifest, hierarchy


def test_manager_feeds_a_partial_worker_its_own_components(partial_run):
    root, manifest, hierarchy = partial_run
    assert manifest["workers"]["goal"]["env_kwargs"] == {"observe": GOAL_VIEW}
    assert manifest["workers"]["goal"]["spec"]["observation_space"]["shape"] == [15]
    assert hierarchy.config.worker_states == {"goal": GOAL_VIEW}
    loaded = Hierarchy.load(root / "m" / "hierarchy.zip")
    assert loaded.config.worker_states == {"goal": GOAL_VIEW}
    env = gym.make(loaded.env_id, **loaded.env_kwargs)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (39,)
    # The goal worker, given the full state, acts exactly as it does on its own 15 components.
    goal = loaded.workers["goal"]
    index = env.unwrapped.state_layout.indices(GOAL_VIEW)
    expected, _ = goal.predict(obs[index], deterministic=True)
    np.testing.assert_allclose(loaded._frozen[0].act(obs), expected, atol=1e-6)
    action, _ = loaded.predict(obs, deterministic=True)
    assert action.shape == (6,)


def test_ham_slices_the_state_for_a_partial_worker(partial_run):
    root, _, _ = partial_run
    path = save_ham(root / "ham.json", root / "w" / "workers" / "manifest.json", threshold=5.9)
    switch, meta = load_ham(path)
    env = gym.make(meta["env_id"], **meta["env_kwargs"])
    obs, _ = env.reset(seed=2)
    action, _ = switch.predict(obs, deterministic=True)
    assert action.shape == (6,)
    batch = np.stack([obs, obs])
    actions, _ = switch.predict(batch, deterministic=True)
    assert actions.shape == (2, 6)


def test_manager_env_may_not_drop_components(partial_run, tmp_path):
    root, _, _ = partial_run
    config = yaml.safe_load((root / "config.yml").read_text())
    config["manager"]["env_kwargs"] = {"observe": GOAL_VIEW}
    path = tmp_path / "bad.yml"
    path.write_text(json.dumps(config))
    with pytest.raises(ValueError, match="full state"):
        train_manager(root / "w", tmp_path / "m", config=path, timesteps=10)

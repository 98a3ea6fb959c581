"""A manager that sees motion: its input, the wrapper's observations, the same input in a loaded bundle."""

import json
import zipfile

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium import spaces

from sb3_hddpg.artifacts.limits import LimitError
from sb3_hddpg.envs.contract import state_layout_of
from sb3_hddpg.hierarchy import WorkerSelectionWrapper
from sb3_hddpg.hierarchy.hierarchy import Hierarchy
from sb3_hddpg.hierarchy.manager_input import ManagerInput
from sb3_hddpg.hierarchy.selection import check_selection_settings
from sb3_hddpg.training.manager import train_manager
from sb3_hddpg.training.workers import train_workers
from tests.cli_runner import run_cli
from tests.helpers import ConstantWorker

SCALE = 20.0


def test_the_input_holds_the_state_its_scaled_clipped_change_and_the_weights():
    space = spaces.Box(-1.0, 1.0, (4,), np.float32)
    make = ManagerInput(space, indices=np.array([0, 2]), motion=10.0, n_preferences=2)
    assert make.observation_space.shape == (6,)
    assert list(make.observation_space.low) == [-1, -1, -1, -1, 0, 0]
    weights = np.array([0.25, 0.75], np.float32)
    now = np.array([0.5, 9.0, 0.3, 9.0], np.float32)
    before = np.array([0.45, -9.0, 0.9, -9.0], np.float32)
    np.testing.assert_allclose(make(now, before, weights), [0.5, 0.3, 0.5, -1.0, 0.25, 0.75], rtol=1e-6)
    # No previous state (an episode's first step): no motion.
    np.testing.assert_allclose(make(now, None, weights), [0.5, 0.3, 0, 0, 0.25, 0.75])
    # A batch is a batch of the same rows.
    batch = make(np.stack([now, before]), np.stack([before, before]), weights)
    np.testing.assert_allclose(batch[0], make(now, before, weights))
    np.testing.assert_allclose(batch[1, 2:4], 0.0)
    # Without motion or weights the state keeps its own shape; motion flattens a matrix.
    matrix = spaces.Box(-2.0, 2.0, (3, 2), np.float32)
    assert ManagerInput(matrix).observation_space == matrix
    assert ManagerInput(matrix, motion=1.0).observation_space.shape == (12,)
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="manager_motion"):
            ManagerInput(space, motion=bad)
    with pytest.raises(ValueError, match="needs a Box"):
        ManagerInput(spaces.Discrete(3), motion=1.0)


def test_the_wrapper_shows_the_change_over_the_last_env_step():
    env = gym.make("hddpg/SnakeReach-v0")
    layout = state_layout_of(env)
    state = ["joint_obstacle_vectors", "joint_obstacle_distances"]
    indices = layout.indices(state)
    # Workers that swing the arm one way or the other, so that the state moves.
    swinging = {"goal": ConstantWorker(np.full(6, 1.0)), "avoid": ConstantWorker(np.full(6, -1.0))}
    wrapper = WorkerSelectionWrapper(env, swinging, option_steps=3, manager_state=state, manager_motion=SCALE)
    n = len(indices)
    assert wrapper.observation_space.shape == (2 * n,)
    obs, _ = wrapper.reset(seed=3)
    np.testing.assert_array_equal(obs[n:], 0.0)  # nothing has moved yet
    moved = 0
    for _ in range(20):
        before = wrapper._previous_obs
        obs, *_ = wrapper.step(np.array([1.0, -1.0], np.float32))
        now, previous = wrapper._last_obs, wrapper._previous_obs
        assert previous is not None and previous is not before  # the option's last env step, not its first
        np.testing.assert_allclose(obs[:n], now[indices])
        expected = np.clip(SCALE * (now[indices] - previous[indices]), -1.0, 1.0)
        np.testing.assert_allclose(obs[n:], expected, atol=1e-6)
        moved += bool(np.abs(obs[n:]).max() > 0.05)
    assert moved >= 10  # the swinging arm and the drifting obstacles show as motion
    assert wrapper.selection_config().manager_motion == SCALE


@pytest.fixture(scope="module")
def workers(tmp_path_factory):
    root = tmp_path_factory.mktemp("motion")
    train_workers(root / "w", seed=6, timesteps=200, eval_freq=0, eval_episodes=1)
    return root / "w"


def test_a_loaded_bundle_decides_as_the_manager_did_in_training(workers, tmp_path):
    train_manager(workers, tmp_path / "m", algo="dqn", manager_motion=SCALE, seed=6, timesteps=120,
                  eval_freq=60, eval_episodes=1)  # fmt: skip
    with zipfile.ZipFile(tmp_path / "m" / "hierarchy.zip") as archive:
        manifest = json.loads(archive.read("manifest.json"))
    assert manifest["selection"]["manager_motion"] == SCALE
    trained = Hierarchy.load(tmp_path / "m" / "hierarchy.zip")
    # So tiny a budget leaves the Q-network near its initialisation, one worker everywhere. Set its weights
    # to a rule on motion alone: the first worker while the tip-to-goal vector's x grows, else the second.
    net = trained.manager.q_net.q_net
    size = trained.observation_space.shape[0]  # the manager sees the whole state, then its motion
    watched = size + state_layout_of(trained.make_env())["ee_to_goal"].start
    with torch.no_grad():
        for parameter in net.parameters():
            parameter.zero_()
        net[0].weight[0, watched], net[0].weight[1, watched] = 100.0, -100.0
        net[2].weight[0, 0] = net[2].weight[1, 1] = 1.0
        net[4].weight[0, 0] = net[4].weight[1, 1] = 1.0
    trained.save(tmp_path / "swinging.zip")
    loaded = Hierarchy.load(tmp_path / "swinging.zip")
    # The training wrapper over the same workers, driven by the same DQN: the bundle, fed the raw states one
    # at a time, must choose the same worker at every decision, motion included.
    wrapper = WorkerSelectionWrapper(loaded.make_env(), loaded.workers, **loaded.config.wrapper_kwargs())
    manager_obs, _ = wrapper.reset(seed=11)
    env = loaded.make_env()
    obs, _ = env.reset(seed=11)
    loaded.reset_episode()
    chosen_by_wrapper, chosen_by_bundle, inputs_moved = [], [], 0
    for _ in range(15):
        action, _ = loaded.manager.predict(manager_obs, deterministic=True)
        manager_obs, *_, info = wrapper.step(action)
        chosen_by_wrapper.append(info["selected_worker"])
        inputs_moved += bool(np.abs(manager_obs[-len(manager_obs) // 2 :]).max() > 0)
        for step in range(info["option_length"]):
            env_action, _ = loaded.predict(obs, deterministic=True)
            assert loaded.last_decided == (step == 0)
            if step == 0:
                chosen_by_bundle.append(loaded.last_selection)
            obs, *_ = env.step(env_action)
        np.testing.assert_allclose(obs, wrapper._last_obs)
    assert chosen_by_bundle == chosen_by_wrapper
    assert set(chosen_by_wrapper) == {"goal", "avoid"}
    assert inputs_moved >= 10
    # A batch keeps one stream per row, motion included: two envs stepped together decide as each alone.
    envs = [loaded.make_env() for _ in range(2)]
    rows = np.stack([env.reset(seed=seed)[0] for env, seed in zip(envs, (11, 12))])
    alone, together = [loaded.initial_state() for _ in envs], loaded.initial_state(2)
    for _ in range(12):
        batched, together = loaded.predict(rows, together, deterministic=True)
        for i in range(2):
            single, alone[i] = loaded.predict(rows[i], alone[i], deterministic=True)
            np.testing.assert_array_equal(batched[i], single)
            assert together.choice[i] == alone[i].choice[0] and together.left[i] == alone[i].left[0]
        rows = np.stack([env.step(action)[0] for env, action in zip(envs, batched)])
    assert together.previous[0] is not None and not np.array_equal(together.previous[0], together.previous[1])
    # A batch of one, as SB3's evaluate_policy gives on one env, is the same stream.
    loaded.reset_episode()
    first, _ = loaded.predict(obs, deterministic=True)
    loaded.reset_episode()
    batched, _ = loaded.predict(obs[None], deterministic=True)
    assert batched.shape == (1, *first.shape) and np.allclose(batched[0], first)


def test_a_bad_motion_setting_is_refused_by_name(workers, tmp_path):
    for bad in (-1, "fast", float("inf"), True):
        with pytest.raises(LimitError, match="manager_motion"):
            check_selection_settings({"manager_motion": bad}, ["goal", "avoid"], "selection")
    result = run_cli("train-manager", "--workers", workers, "--out", tmp_path / "m", "--manager-motion", "-2")
    output = result.stdout + result.stderr
    assert result.returncode == 2 and "--manager-motion" in output and "Traceback" not in output
    assert not (tmp_path / "m").exists()

"""Hindsight goal relabelling: relabelled transitions are ones the env itself would give."""

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3 import DDPG

from sb3_hddpg.goal_relabeling import GoalRelabelingReplayBuffer

VIEW = ["joint_positions", "ee_to_goal", "goal_touched"]


def _rollout(env, steps=60, seed=0):
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    out = []
    for _ in range(steps):
        action = rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
        next_obs, reward, terminated, truncated, info = env.step(action)
        out.append((obs, action, reward, next_obs, info))
        obs = next_obs
    return out


@pytest.mark.parametrize("observe", [None, VIEW])
def test_relabelling_with_the_real_goal_reproduces_the_env(observe):
    kwargs = {} if observe is None else {"observe": observe}
    env = gym.make("hddpg/SnakeGoal-v0", **kwargs)
    buffer = GoalRelabelingReplayBuffer(
        100, env.observation_space, env.action_space, device="cpu", observe=observe
    )
    transitions = _rollout(env)
    obs = np.stack([t[0] for t in transitions])
    next_obs = np.stack([t[3] for t in transitions])
    rewards = np.array([t[2] for t in transitions], dtype=np.float32)
    # The goal after each step, as the env had it: tip + 2 * ee_to_goal of the next observation.
    goals = next_obs[:, buffer._tip] + 2 * next_obs[:, buffer._to_goal]
    np.testing.assert_allclose(goals[-1], env.unwrapped.goal, atol=1e-5)
    relabelled_next, relabelled_rewards = next_obs.copy(), rewards.copy()
    buffer.relabel(obs.copy(), relabelled_next, relabelled_rewards, np.arange(len(obs)), goals)
    np.testing.assert_allclose(relabelled_next, next_obs, atol=1e-6)
    np.testing.assert_allclose(relabelled_rewards, rewards, atol=1e-5)


def test_hindsight_goals_come_from_the_same_episode_and_pay_touches():
    env = gym.make("hddpg/SnakeGoal-v0", observe=VIEW, max_episode_steps=20)
    model = DDPG(
        "MlpPolicy",
        env,
        replay_buffer_class=GoalRelabelingReplayBuffer,
        replay_buffer_kwargs={"observe": VIEW, "relabel_fraction": 1.0},
        learning_starts=100,
        policy_kwargs={"net_arch": [8]},
        seed=0,
        device="cpu",
    )
    model.learn(100)  # 5 episodes of 20 steps
    buffer = model.replay_buffer
    assert sorted(set(buffer._episode[:100, 0].tolist())) == [0, 1, 2, 3, 4]
    indices = np.random.default_rng(0).integers(0, 100, 500)
    futures = buffer.future_indices(indices, np.zeros_like(indices))
    assert np.all(buffer._episode[futures, 0] == buffer._episode[indices, 0]) and np.all(futures >= indices)
    assert np.all(futures - indices < 20) and len(set((futures - indices).tolist())) > 10
    samples = buffer.sample(512)
    rewards = samples.rewards.numpy().ravel()
    touched = samples.next_observations.numpy()[:, -1]
    # A hindsight goal at the very step's own tip is touched: rewards above 0 appear, and they are the touches.
    assert (touched == 1).any()
    np.testing.assert_array_equal(rewards > 0, touched == 1)
    assert samples.observations.shape == (512, 15)


def test_wrong_layout_is_refused():
    env = gym.make("hddpg/SnakeGoal-v0", observe=VIEW)
    with pytest.raises(ValueError, match="n_joints and observe"):
        GoalRelabelingReplayBuffer(10, env.observation_space, env.action_space, device="cpu")
    avoid_view = gym.make("hddpg/SnakeGoal-v0", observe=["joint_positions", "joint_obstacle_distances"])
    with pytest.raises(ValueError, match="needs the state components"):
        GoalRelabelingReplayBuffer(
            10,
            avoid_view.observation_space,
            avoid_view.action_space,
            device="cpu",
            observe=["joint_positions", "joint_obstacle_distances"],
        )


def test_config_key_trains_the_goal_worker_with_relabelling(tmp_path):
    import yaml

    from sb3_hddpg.artifacts.manifests import load_workers
    from sb3_hddpg.training.config import DEFAULT_CONFIG
    from sb3_hddpg.training.workers import train_workers

    config = yaml.safe_load(DEFAULT_CONFIG.read_text())
    block = {k: v for k, v in config["hddpg/SnakeGoal-v0"].items() if k != "<<"}
    block.update(
        replay_buffer_class="GoalRelabelingReplayBuffer", replay_buffer_kwargs={"relabel_fraction": 0.5}
    )
    path = tmp_path / "config.yml"
    path.write_text(yaml.safe_dump({"hddpg/SnakeGoal-v0": block}))
    train_workers(tmp_path / "w", workers=["goal"], config=path, timesteps=200, eval_freq=0, eval_episodes=1)
    models = load_workers(tmp_path / "w")
    manifest = models.manifest
    assert models["goal"].observation_space.shape == (15,)
    assert (
        manifest["workers"]["goal"]["config"]["block"]["replay_buffer_class"] == "GoalRelabelingReplayBuffer"
    )


@pytest.mark.parametrize(
    "extra, message",
    [
        ({"replay_buffer_class": "os.system"}, "Unknown replay_buffer_class"),
        ({"replay_buffer_kwargs": {"device": "cuda"}}, "relabel_fraction"),
    ],
)
def test_config_refuses_other_buffers(extra, message):
    from sb3_hddpg.training.config import parse_block
    from sb3_hddpg.training.config_values import ConfigError

    with pytest.raises(ConfigError, match=message):
        parse_block({"n_timesteps": 10, **extra}, DDPG)

"""The fair flat baseline: a flat agent on the reach reward with the goal worker's relabelling and penalty."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv

from hddpg_zoo.benchmark import METHOD_REGISTRY, BenchmarkSettings
from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID
from sb3_hddpg.goal_relabeling import GoalRelabelingReplayBuffer
from sb3_hddpg.hierarchy.loading import load_policy
from sb3_hddpg.training.flat import FLAT_HER_KEY, flat_hyperparams, train_flat


def reach_buffer(steps: int = 60) -> tuple[GoalRelabelingReplayBuffer, gym.Env]:
    """A relabelling buffer filled with random steps of the reach env (one episode boundary included)."""
    env = gym.make(SNAKE_REACH_ENV_ID, max_episode_steps=25)
    buffer = GoalRelabelingReplayBuffer(
        200,
        env.observation_space,
        env.action_space,
        device="cpu",
        **GoalRelabelingReplayBuffer.env_kwargs(env),
    )
    obs, _ = env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(steps):
        action = rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
        next_obs, reward, terminated, truncated, info = env.step(action)
        buffer.add(
            obs[None],
            next_obs[None],
            action[None],
            np.array([reward]),
            np.array([terminated or truncated]),
            [info],
        )
        obs = next_obs if not (terminated or truncated) else env.reset()[0]
    return buffer, env


def test_reach_relabelling_changes_only_the_goal_share_of_the_reward():
    buffer, env = reach_buffer()
    kwargs = GoalRelabelingReplayBuffer.env_kwargs(env)
    low, high = env.unwrapped.reward_bounds["goal"]
    assert kwargs["goal_scale"] == pytest.approx(1 / (high - low))
    rows = np.arange(40)
    obs, next_obs = buffer.observations[rows, 0].copy(), buffer.next_observations[rows, 0].copy()
    rewards = buffer.rewards[rows, 0].copy()
    # The real goal (tip + 2 * ee_to_goal of the next observation): the reward stays what the env paid.
    real_goals = next_obs[:, buffer._tip] + 2 * next_obs[:, buffer._to_goal]
    same = rewards.copy()
    buffer.relabel(obs.copy(), next_obs.copy(), same, rows, real_goals)
    assert same == pytest.approx(rewards, abs=1e-5)
    # The tip itself as the goal: a touch, the goal term at its maximum (1), the avoid share unchanged.
    tips = next_obs[:, buffer._tip]
    relabelled = rewards.copy()
    buffer.relabel(obs.copy(), next_obs.copy(), relabelled, rows, tips)
    distance = 2 * np.linalg.norm(next_obs[:, buffer._to_goal], axis=1)
    old_goal = np.maximum(-distance + next_obs[:, buffer._touched], low)
    assert relabelled == pytest.approx(rewards + (1.0 - old_goal) / (high - low), abs=1e-5)
    with pytest.raises(ValueError, match="holds the goal term"):
        GoalRelabelingReplayBuffer.env_kwargs(gym.make("hddpg/SnakeAvoid-v0"))


def test_the_her_methods_are_flat_baselines_with_the_flat_budget():
    settings = BenchmarkSettings(
        methods=["hddpg", "sac-her", "ddpg-her"], seeds=[0], timesteps=1000, worker_timesteps=300
    )
    for name in ("sac-her", "ddpg-her"):
        method = METHOD_REGISTRY[name]
        assert method.baseline and method.cost(settings) == settings.flat_budget
        (label,) = method.config_blocks(settings)
        assert label.endswith(f"[{FLAT_HER_KEY}]")
    assert flat_hyperparams("ddpg", SNAKE_REACH_ENV_ID, block=FLAT_HER_KEY).raw["callback"]


@pytest.mark.parametrize("algo", ["sac", "ddpg"])
def test_train_flat_from_the_her_block(tmp_path, algo, monkeypatch):
    seen = {}
    original = GoalRelabelingReplayBuffer.__init__

    def spy(self, *args, **kwargs):
        seen.update(kwargs)
        original(self, *args, **kwargs)

    monkeypatch.setattr(GoalRelabelingReplayBuffer, "__init__", spy)
    manifest = train_flat(
        tmp_path, algo=algo, block=FLAT_HER_KEY, timesteps=200, eval_freq=200, eval_episodes=1
    ).manifest
    assert seen["relabel_fraction"] == 0.8 and seen["goal_scale"] is not None and seen["observe"] is None
    entry = manifest["models"][algo]
    assert entry["config"]["block"]["gamma"] == 0.7
    loaded = load_policy(tmp_path / "flat" / f"{algo}.zip")
    env = DummyVecEnv([loaded.make_env])
    assert loaded.policy.predict(env.reset(), deterministic=True)[0].shape == (1, *env.action_space.shape)


def test_the_her_block_is_tunable_with_the_same_study_machinery():
    from hddpg_zoo.tuning import TuningTarget

    target = TuningTarget(
        level="flat", algo="sac", block=FLAT_HER_KEY, budget_fraction=0.1, final_budget=340_000
    )
    assert target.block_key == FLAT_HER_KEY and target.describe()["block"] == FLAT_HER_KEY
    assert target.base_block()["replay_buffer_class"] == "GoalRelabelingReplayBuffer"
    target.check()
    with pytest.raises(ValueError, match="no such block"):
        TuningTarget(level="flat", block="nope").check()
    with pytest.raises(ValueError, match="level 'flat'"):
        TuningTarget(level="worker", worker="goal", block=FLAT_HER_KEY)

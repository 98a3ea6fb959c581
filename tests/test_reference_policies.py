"""The scripted reference reachers: the IK reacher holds the goal, its bang-bang version cannot."""

import gymnasium as gym
import numpy as np

from sb3_hddpg.baselines import IKReacher
from sb3_hddpg.envs.snake.controllers import FieldAvoider
from sb3_hddpg.evaluation import evaluate
from sb3_hddpg.hierarchy.loading import load_policy


def test_ik_reacher_holds_the_goal_and_saturation_costs_it_the_touch():
    env = gym.make("hddpg/SnakeGoal-v0")
    layout = env.unwrapped.state_layout
    smooth = evaluate(IKReacher(layout), env, n_episodes=3, seed=15000).summary()
    bang_bang = evaluate(IKReacher(layout, bang_bang=True), env, n_episodes=3, seed=15000).summary()
    assert smooth["goal_touch_rate"] > 0.5 and smooth["action_saturation"] < 0.2
    assert bang_bang["goal_touch_rate"] < 0.25 and bang_bang["action_saturation"] == 1.0


def test_ik_reacher_batches_like_single_observations():
    env = gym.make("hddpg/SnakeReach-v0")
    reacher = IKReacher(env.unwrapped.state_layout)
    observations = np.stack([env.reset(seed=s)[0] for s in range(4)])
    batched, _ = reacher.predict(observations)
    single = np.stack([reacher.predict(o)[0] for o in observations])
    np.testing.assert_allclose(batched, single, atol=1e-6)
    assert batched.shape == (4, 6) and np.all(np.abs(batched) <= 1)


def test_ik_is_a_reference_policy_name():
    loaded = load_policy("ik")
    assert isinstance(loaded.policy, IKReacher)


def test_the_field_avoider_keeps_clear_with_small_commands_and_rests_with_no_obstacle_in_range():
    env = gym.make("hddpg/SnakeAvoid-v0")
    layout = env.unwrapped.state_layout
    field = load_policy("field", env_id="hddpg/SnakeAvoid-v0").policy
    assert isinstance(field, FieldAvoider)
    held = evaluate(_Still(), env, n_episodes=10, seed=15000).summary()
    avoided = evaluate(field, env, n_episodes=10, seed=15000).summary()
    assert held["collisions_per_episode"] > 2, held  # these episodes bring obstacles onto a still arm
    assert avoided["collisions_per_episode"] < 0.25 * held["collisions_per_episode"], (avoided, held)
    assert avoided["action_saturation"] < 0.05
    clear = env.reset(seed=0)[0].copy()
    clear[layout["joint_obstacle_distances"]] = 1.0  # every obstacle at or beyond the sensor range
    np.testing.assert_array_equal(FieldAvoider(layout).predict(clear)[0], np.zeros(6, np.float32))


class _Still:
    """Holds every joint still: what the arm suffers from the obstacles alone."""

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        return np.zeros((*np.shape(observation)[:-1], 6), np.float32), None

"""The scripted reference reachers: the IK reacher holds the goal, its bang-bang version cannot."""

import gymnasium as gym
import numpy as np

from sb3_hddpg.baselines import IKReacher
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

"""WorkerSelectionWrapper with fake workers: what reaches the env, the reward arithmetic, options, validation."""

import gymnasium as gym
import numpy as np
import pytest

from sb3_hddpg.hierarchy import WorkerSelectionWrapper
from sb3_hddpg.hierarchy.selection import SimplexMap, parse_preferences, preferences_from_bias
from tests.helpers import ActionRecorder, ConstantWorker

GOAL_ACTION = np.full(6, 0.5, np.float32)
AVOID_ACTION = np.full(6, -0.25, np.float32)


def make(selection="sample", option_steps=1, preferences=None, **kwargs):
    inner = ActionRecorder(gym.make("hddpg/SnakeReach-v0"))
    workers = {"goal": ConstantWorker(GOAL_ACTION), "avoid": ConstantWorker(AVOID_ACTION)}
    env = WorkerSelectionWrapper(
        inner, workers, preferences=preferences, selection=selection, option_steps=option_steps, **kwargs
    )
    return env, inner, workers


def test_spaces():
    env, _, _ = make()
    assert env.action_space == gym.spaces.Box(-1, 1, (2,), np.float32)
    assert env.observation_space == gym.make("hddpg/SnakeReach-v0").observation_space


@pytest.mark.parametrize("manager_action", [np.array([1.0, -1.0]), np.array([-1.0, 1.0])])
def test_argmax_applies_the_most_probable_workers_action(manager_action):
    env, inner, workers = make(selection="argmax")
    env.reset(seed=0)
    _, _, _, _, info = env.step(manager_action.astype(np.float32))
    expected_name = "goal" if manager_action[0] > 0 else "avoid"
    expected = GOAL_ACTION if expected_name == "goal" else AVOID_ACTION
    np.testing.assert_array_equal(inner.actions[-1], expected)
    assert info["selected_worker"] == expected_name
    # Only the chosen worker ran.
    other = "avoid" if expected_name == "goal" else "goal"
    assert workers[expected_name].calls == 1 and workers[other].calls == 0


@pytest.mark.parametrize("selection", ["argmax", "sample"])
def test_an_exact_tie_is_broken_at_random_not_by_worker_order(selection):
    # A manager saturated at (+1, +1) gives both workers 0.5: it states no preference, so the first-listed
    # worker must not win every step (the argmax, and sample's deterministic choice).
    from sb3_hddpg.hierarchy.selection import get_selector

    selector, rng = get_selector(selection), np.random.default_rng(0)
    chosen = [selector.choose([0.5, 0.5], rng, deterministic=True) for _ in range(1000)]
    assert 0.45 < np.mean(chosen) < 0.55
    three_way = [selector.choose([0.1, 0.45, 0.45], rng, deterministic=True) for _ in range(1000)]
    assert set(three_way) == {1, 2}  # only the tied ones
    # Untied choices are deterministic and draw nothing: the generator's stream is untouched.
    state = rng.bit_generator.state
    assert selector.choose([0.4999, 0.5001], rng, deterministic=True) == 1
    assert rng.bit_generator.state == state
    # Seeded, the draws repeat.
    again = np.random.default_rng(0)
    assert [selector.choose([0.5, 0.5], again, deterministic=True) for _ in range(1000)] == chosen


def test_a_saturated_manager_runs_both_workers_in_the_wrapper():
    env, inner, workers = make(selection="argmax")
    env.reset(seed=3)
    names = [env.step(np.ones(2, np.float32))[4]["selected_worker"] for _ in range(100)]
    assert 30 < names.count("goal") < 70 and workers["avoid"].calls == names.count("avoid")


def test_sample_follows_the_probabilities_and_is_seeded():
    env, inner, _ = make(selection="sample", temperature=1.0, floor=0.0)
    env.reset(seed=1)
    action = np.array([0.5, -0.5], np.float32)
    expected_p_goal = SimplexMap(2, 1.0, 0.0)(action)[0]
    chosen = []
    for _ in range(2000):
        _, _, _, truncated, info = env.step(action)
        chosen.append(info["selected_worker"])
        if truncated:
            env.reset()
        np.testing.assert_allclose(info["selection_probabilities"]["goal"], expected_p_goal)
    rate = np.mean([c == "goal" for c in chosen])
    assert abs(rate - expected_p_goal) < 0.04, (rate, expected_p_goal)
    # The applied action is always the chosen worker's.
    applied_goal = [np.array_equal(a, GOAL_ACTION) for a in inner.actions]
    assert applied_goal == [c == "goal" for c in chosen]
    # Same seed, same choices; and the env's own trajectory is not perturbed by the sampling.
    env2, _, _ = make(selection="sample", temperature=1.0, floor=0.0)
    env2.reset(seed=1)
    again = [env2.step(action)[4]["selected_worker"] for _ in range(50)]
    assert again == chosen[:50]


def test_mix_blends_actions_by_probability():
    env, inner, workers = make(selection="mix", temperature=1.0, floor=0.0)
    env.reset(seed=0)
    action = np.array([0.3, -0.1], np.float32)
    p = SimplexMap(2, 1.0, 0.0)(action)
    env.step(action)
    np.testing.assert_allclose(inner.actions[-1], p[0] * GOAL_ACTION + p[1] * AVOID_ACTION, rtol=1e-6)
    assert workers["goal"].calls == 1 and workers["avoid"].calls == 1


def test_uniform_warm_up_actions_give_valid_probabilities():
    simplex = SimplexMap(3, temperature=0.5, floor=0.02)
    actions = np.random.default_rng(0).uniform(-1, 1, (1000, 3))
    p = simplex(actions)
    np.testing.assert_allclose(p.sum(axis=1), 1.0)
    assert p.min() >= 0.02 - 1e-12
    assert p.max() <= np.exp(4) / (np.exp(4) + 2) + 1e-9  # no saturation even at the corners
    # Out-of-range actions (a user's, unclipped) are clipped, not extrapolated.
    np.testing.assert_allclose(simplex(np.array([50.0, -50.0, 0.0])), simplex(np.array([1.0, -1.0, 0.0])))


def test_reward_is_preference_weighted_sum_of_normalised_terms():
    env, _, _ = make(selection="argmax", preferences={"goal": 1.15, "avoid": 1.0})
    env.reset(seed=3)
    _, reward, _, _, info = env.step(np.array([1.0, -1.0], np.float32))
    bounds = env.unwrapped.reward_bounds
    terms = info["reward_terms"]
    norm = {k: (terms[k] - bounds[k][0]) / (bounds[k][1] - bounds[k][0]) for k in terms}
    assert reward == pytest.approx(1.15 * norm["goal"] + 1.0 * norm["avoid"])
    assert info["normalised_terms"] == pytest.approx(norm)
    assert all(0.0 <= v <= 1.0 for v in norm.values())


def test_option_steps_keep_the_worker_and_discount_the_reward():
    env, inner, _ = make(selection="sample", option_steps=4, option_gamma=0.9)
    env.reset(seed=5)
    base = gym.make("hddpg/SnakeReach-v0")
    base.reset(seed=5)
    _, reward, _, _, info = env.step(np.array([0.2, 0.1], np.float32))
    assert info["option_length"] == 4 and len(inner.actions) == 4
    assert all(np.array_equal(a, inner.actions[0]) for a in inner.actions)
    # Replay the same env actions on a bare env: the manager's reward is their discounted sum.
    manager_rewards = []
    for action in inner.actions:
        *_, base_info = base.step(action)
        r, _ = env.manager_reward(base_info["reward_terms"])
        manager_rewards.append(r)
    assert reward == pytest.approx(sum(0.9**j * r for j, r in enumerate(manager_rewards)))


def test_a_manager_with_options_is_evaluated_per_env_step():
    """The same worker held for 4 env steps per decision, or chosen at every step: the same env actions,
    so ``evaluate`` must report the same episode (the wrapper's own reward discounts inside an option)."""
    from sb3_hddpg.evaluation import evaluate

    class Always:
        def predict(self, obs, deterministic=True):
            return np.array([1.0, -1.0], np.float32), None

    summaries = []
    for option_steps in (1, 4):
        env, _, _ = make(selection="argmax", option_steps=option_steps, option_gamma=0.9)
        summaries.append(evaluate(Always(), env, n_episodes=2).summary())
    per_step, per_option = summaries
    assert per_option["mean_length"] == per_step["mean_length"] == 200
    for key in (
        "mean_reward",
        "mean_reach_reward",
        "goal_touch_rate",
        "collisions_per_episode",
        "min_clearance",
    ):
        assert per_option[key] == pytest.approx(per_step[key]), key
    assert per_option["selection_rate"] == per_step["selection_rate"] == {"avoid": 0.0, "goal": 1.0}
    assert per_option["selections_near"] == per_step["selections_near"]
    assert per_option["selections_clear"] == per_step["selections_clear"]


def test_option_stops_at_episode_end():
    inner = gym.make("hddpg/SnakeReach-v0", max_episode_steps=6)
    env = WorkerSelectionWrapper(
        inner,
        {"a": ConstantWorker(GOAL_ACTION), "b": ConstantWorker(AVOID_ACTION)},
        reward_terms={"a": "goal", "b": "avoid"},
        option_steps=4,
    )
    env.reset(seed=0)
    lengths = []
    truncated = False
    while not truncated:
        *_, truncated, info = env.step(np.zeros(2, np.float32))
        lengths.append(info["option_length"])
    assert lengths == [4, 2]


def test_state_subsets_for_manager_and_workers():
    inner = gym.make("hddpg/SnakeReach-v0")
    goal = ConstantWorker(GOAL_ACTION)
    env = WorkerSelectionWrapper(
        inner,
        {"goal": goal, "avoid": ConstantWorker(AVOID_ACTION)},
        selection="argmax",
        manager_state=["ee_to_goal", "joint_obstacle_distances"],
        worker_states={"goal": ["joint_positions", "ee_to_goal"]},
    )
    obs, _ = env.reset(seed=0)
    assert obs.shape == (2 + 6,) and env.observation_space.shape == (8,)
    env.step(np.array([1.0, -1.0], np.float32))
    assert goal.last_obs.shape == (12 + 2,)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"workers": {"goal": ConstantWorker(GOAL_ACTION)}}, "at least 2 workers"),
        (
            {"workers": [("goal", ConstantWorker(GOAL_ACTION)), ("goal", ConstantWorker(AVOID_ACTION))]},
            "unique worker names",
        ),
        ({"preferences": {"goal": 0.0}}, "preference of 'goal'"),
        ({"preferences": {"goal": float("nan")}}, "preference of 'goal'"),
        ({"preferences": {"goal": float("inf")}}, "preference of 'goal'"),
        ({"preferences": {"speed": 1.0}}, "unknown workers"),
        ({"reward_terms": {"goal": "speed"}}, "unknown reward terms"),
        ({"selection": "vote"}, "selection"),
        ({"option_steps": 0}, "option_steps"),
        ({"temperature": 0.0}, "temperature"),
        ({"floor": 0.6}, "floor"),
        ({"manager_state": ["elbow"]}, "Unknown state components"),
        (
            {
                "workers": {
                    "goal": ConstantWorker(
                        GOAL_ACTION, gym.spaces.Box(-1, 1, (5,)), gym.spaces.Box(-1, 1, (6,))
                    ),
                    "avoid": ConstantWorker(AVOID_ACTION),
                }
            },
            "Worker .goal. sees 5 values but the env gives",
        ),
        (
            {
                "workers": {
                    "goal": ConstantWorker(
                        GOAL_ACTION,
                        gym.make("hddpg/SnakeReach-v0").observation_space,
                        gym.spaces.Box(-1, 1, (3,), np.float32),
                    ),
                    "avoid": ConstantWorker(AVOID_ACTION),
                }
            },
            "Action spaces do not match",
        ),
        ({"workers": {"goal": object(), "avoid": ConstantWorker(AVOID_ACTION)}}, "no predict"),
    ],
)
def test_validation_errors(kwargs, message):
    arguments = {
        "workers": {"goal": ConstantWorker(GOAL_ACTION), "avoid": ConstantWorker(AVOID_ACTION)},
        **kwargs,
    }
    with pytest.raises(ValueError, match=message):
        WorkerSelectionWrapper(gym.make("hddpg/SnakeReach-v0"), **arguments)


def test_preference_helpers():
    assert preferences_from_bias(["goal", "avoid"], "goal", 0.15) == {"goal": 1.15, "avoid": 1.0}
    assert parse_preferences("goal=1.15, avoid=1") == {"goal": 1.15, "avoid": 1.0}
    for bad in ("goal", "goal=x", "goal=1,goal=2", ""):
        with pytest.raises(ValueError):
            parse_preferences(bad)
    with pytest.raises(ValueError, match="speed"):
        preferences_from_bias(["goal", "avoid"], "speed")


def test_sb3_env_checker_accepts_the_manager_env():
    from stable_baselines3.common.env_checker import check_env

    env, _, _ = make()
    check_env(env, warn=True)

"""The snake-arm environment: API conformance, determinism, layout, reward bounds, rendering, validation."""

import math
import pickle
import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sb3_hddpg
from sb3_hddpg.envs import ENV_IDS, SnakeArmEnv

IDS = list(ENV_IDS)


@pytest.mark.parametrize("env_id", IDS)
def test_both_env_checkers_pass_without_warnings(env_id):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env = gym.make(env_id, render_mode="rgb_array")
        gym_check_env(env.unwrapped, skip_render_check=False)
        sb3_check_env(env.unwrapped, warn=True)


@pytest.mark.parametrize("env_id", IDS)
def test_registered_with_time_limit_and_reward(env_id):
    env = gym.make(env_id)
    assert env.spec.max_episode_steps == sb3_hddpg.envs.MAX_EPISODE_STEPS
    assert env.unwrapped.reward_name == ENV_IDS[env_id]


def rollout(env, seed, actions):
    obs, _ = env.reset(seed=seed)
    trajectory = [obs]
    rewards = []
    for action in actions:
        obs, reward, *_ = env.step(action)
        trajectory.append(obs)
        rewards.append(reward)
    return np.array(trajectory), np.array(rewards)


def test_same_seed_and_actions_give_identical_trajectories():
    actions = np.random.default_rng(0).uniform(-1, 1, (150, 6)).astype(np.float32)
    env_a = gym.make("hddpg/SnakeReach-v0")
    env_b = gym.make("hddpg/SnakeReach-v0")
    obs_a, rew_a = rollout(env_a, 7, actions)
    rollout(env_b, 3, actions)  # a different history first: nothing may leak across resets
    obs_b, rew_b = rollout(env_b, 7, actions)
    np.testing.assert_array_equal(obs_a, obs_b)
    np.testing.assert_array_equal(rew_a, rew_b)
    obs_c, _ = rollout(env_b, 8, actions)
    assert not np.array_equal(obs_a, obs_c)


def test_layout_matches_docstring_and_observation():
    env = gym.make("hddpg/SnakeReach-v0")
    layout = env.unwrapped.state_layout
    n = env.unwrapped.n_joints
    expected = {
        "joint_positions": slice(0, 2 * n),
        "ee_to_goal": slice(2 * n, 2 * n + 2),
        "joint_obstacle_vectors": slice(2 * n + 2, 4 * n + 2),
        "joint_obstacle_distances": slice(4 * n + 2, 5 * n + 2),
        "goal_touched": slice(5 * n + 2, 5 * n + 3),
        "obstacle_touched": slice(5 * n + 3, 6 * n + 3),
    }
    assert dict(layout) == expected
    for name in expected:
        assert f"``{name}``" in SnakeArmEnv.__doc__
    assert layout.size == env.observation_space.shape[0] == 6 * n + 3
    obs, info = env.reset(seed=0)
    u = env.unwrapped
    np.testing.assert_allclose(obs[layout["joint_positions"]], u.link_points()[1:].ravel(), atol=1e-6)
    np.testing.assert_allclose(obs[layout["ee_to_goal"]], (u.goal - u.link_points()[-1]) / 2, atol=1e-6)
    assert obs[layout["goal_touched"]][0] == float(info["goal_touched"])
    assert np.array_equal(layout.indices(["ee_to_goal"]), np.arange(2 * n, 2 * n + 2))


def test_observation_distances_and_touch_flags_are_consistent():
    env = gym.make("hddpg/SnakeAvoid-v0", max_episode_steps=600)
    env.reset(seed=1)
    layout = env.unwrapped.state_layout
    rng = np.random.default_rng(1)
    saw_touch = False
    for _ in range(600):
        obs, reward, _, _, info = env.step(rng.uniform(-1, 1, 6).astype(np.float32))
        touched = obs[layout["obstacle_touched"]]
        distances = obs[layout["joint_obstacle_distances"]]
        assert np.all(distances[touched == 1] == 0.0)
        assert bool(touched.any()) == info["collision"]
        saw_touch |= info["collision"]
        expected = env.unwrapped.r_bf * distances.sum() * env.unwrapped.sensor_range - float(
            info["collision"]
        )
        assert reward == pytest.approx(expected, abs=1e-5)
    assert saw_touch


def test_observation_and_rewards_match_a_numpy_reference():
    # The step computes the observation in hand-optimised scalar Python; check it against a plain numpy
    # version of the docstring's definitions, from the public link_points, goal and obstacles. A wide
    # touch radius so that the rollout both touches the goal and collides.
    env = gym.make("hddpg/SnakeReach-v0", max_episode_steps=400, touch_radius=0.6)
    u = env.unwrapped
    layout = u.state_layout
    env.reset(seed=5)
    rng = np.random.default_rng(5)
    touches = collisions = 0
    for _ in range(400):
        obs, reward, _, _, info = env.step(rng.uniform(-1, 1, 6).astype(np.float32))
        points, goal, centres = u.link_points(), u.goal, u.obstacles
        starts, seg = points[:-1, None, :], (points[1:] - points[:-1])[:, None, :]
        t = np.clip(np.sum((centres[None] - starts) * seg, axis=-1) / np.sum(seg * seg, axis=-1), 0.0, 1.0)
        vectors = centres[None] - (starts + t[..., None] * seg)  # (link, obstacle, 2)
        closest = np.linalg.norm(vectors, axis=-1).argmin(axis=1)
        vector = vectors[np.arange(u.n_joints), closest]
        clearance = np.linalg.norm(vector, axis=-1) - u.obstacle_radius
        clipped = np.clip(clearance, 0.0, u.sensor_range)
        touching = clearance <= 0.0
        distance = np.linalg.norm(goal - points[-1])
        np.testing.assert_allclose(obs[layout["joint_positions"]], points[1:].ravel(), atol=1e-6)
        np.testing.assert_allclose(obs[layout["ee_to_goal"]], (goal - points[-1]) / 2, atol=1e-6)
        np.testing.assert_allclose(obs[layout["joint_obstacle_vectors"]], vector.ravel() / 2, atol=1e-6)
        np.testing.assert_allclose(
            obs[layout["joint_obstacle_distances"]], clipped / u.sensor_range, atol=1e-6
        )
        np.testing.assert_array_equal(obs[layout["obstacle_touched"]], touching.astype(np.float32))
        assert obs[layout["goal_touched"]][0] == float(distance <= u.touch_radius)
        goal_term = np.clip(-distance + float(distance <= u.touch_radius), *u.reward_bounds["goal"])
        avoid_term = u.r_bf * clipped.sum() - float(touching.any())
        assert info["reward_terms"]["goal"] == pytest.approx(goal_term, abs=1e-9)
        assert info["reward_terms"]["avoid"] == pytest.approx(avoid_term, abs=1e-9)
        normalised = u.normalise_terms(info["reward_terms"])
        assert reward == pytest.approx(normalised["goal"] + normalised["avoid"], abs=1e-12)
        assert info["min_clearance"] == pytest.approx(clearance.min(), abs=1e-9)
        assert info["distance_to_goal"] == pytest.approx(distance, abs=1e-9)
        touches += info["goal_touched"]
        collisions += info["collision"]
    assert touches > 5 and collisions > 5, (touches, collisions)


@pytest.mark.parametrize("policy", ["random", "bang-bang"])
def test_reward_terms_stay_within_bounds_over_long_rollouts(policy):
    env = gym.make("hddpg/SnakeReach-v0", max_episode_steps=2000)
    bounds = env.unwrapped.reward_bounds
    rng = np.random.default_rng(2)
    env.reset(seed=2)
    seen = {k: [math.inf, -math.inf] for k in bounds}
    for _ in range(2000):
        action = rng.uniform(-1, 1, 6) if policy == "random" else rng.choice([-1.0, 1.0], 6)
        obs, reward, _, _, info = env.step(action.astype(np.float32))
        assert env.observation_space.contains(obs)
        for name, value in info["reward_terms"].items():
            low, high = bounds[name]
            assert low <= value <= high, (name, value, bounds[name])
            seen[name] = [min(seen[name][0], value), max(seen[name][1], value)]
        assert 0.0 <= reward <= 2.0
    # The bounds are tight enough to be useful: the rollout covers a good part of each range.
    for name, (low, high) in bounds.items():
        assert seen[name][1] - seen[name][0] > 0.3 * (high - low), (name, seen[name])


def test_goal_term_pays_touching():
    env = gym.make("hddpg/SnakeGoal-v0", touch_radius=5.0)
    env.reset(seed=0)
    _, reward, _, _, info = env.step(np.zeros(6, np.float32))
    assert info["goal_touched"]
    assert reward == pytest.approx(1.0 - info["distance_to_goal"])


def test_is_success_means_touched_without_collision():
    env = gym.make("hddpg/SnakeReach-v0", touch_radius=5.0, obstacle_radius=1e-3, n_obstacles=1)
    env.reset(seed=0)
    *_, info = env.step(np.zeros(6, np.float32))
    assert info["is_success"] is True
    env = gym.make("hddpg/SnakeReach-v0", touch_radius=1e-3)
    env.reset(seed=0)
    *_, info = env.step(np.zeros(6, np.float32))
    assert info["is_success"] is False


def test_obstacles_start_clear_of_arm_and_goal():
    env = gym.make("hddpg/SnakeReach-v0")
    u = env.unwrapped
    for seed in range(50):
        _, info = env.reset(seed=seed)
        assert not info["collision"]
        assert info["min_clearance"] >= u.spawn_margin - 1e-9
        assert np.linalg.norm(u.obstacles - u.goal, axis=1).min() > u.obstacle_radius + u.touch_radius


def test_joint_limits_hold_and_arm_stays_connected():
    env = gym.make("hddpg/SnakeReach-v0")
    u = env.unwrapped
    env.reset(seed=0)
    for _ in range(100):
        env.step(np.ones(6, np.float32))
    assert np.all(np.abs(u.joint_angles()[1:]) <= u.joint_limit + 1e-3)
    assert u.joint_gaps().max() < 0.3 * u.link_length


def test_motors_track_commanded_joint_speed():
    env = gym.make("hddpg/SnakeReach-v0")
    u = env.unwrapped
    env.reset(seed=0)
    before = u.joint_angles().copy()
    for _ in range(5):
        env.step(np.full(6, 0.5, np.float32))
    turned = u.joint_angles() - before
    np.testing.assert_allclose(turned, 0.5 * u.max_joint_speed * 5 * u.dt, rtol=0.1)


@pytest.mark.parametrize("mode", ["rgb_array", "human"])
def test_render(mode):
    env = gym.make("hddpg/SnakeReach-v0", render_mode=mode)
    env.reset(seed=0)
    frame = env.render()
    if mode == "rgb_array":
        assert frame.shape == (400, 400, 3) and frame.dtype == np.uint8
        assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 4
    else:
        assert frame is None
    env.close()


def test_pickle_round_trip_keeps_state():
    env = gym.make("hddpg/SnakeReach-v0")
    env.reset(seed=4)
    env.step(np.full(6, 0.3, np.float32))
    blob = pickle.dumps(env)
    clone_a, clone_b = pickle.loads(blob), pickle.loads(blob)
    for clone in (clone_a, clone_b):
        np.testing.assert_array_equal(clone.unwrapped.link_points(), env.unwrapped.link_points())
        np.testing.assert_array_equal(clone.unwrapped.obstacles, env.unwrapped.obstacles)
        np.testing.assert_array_equal(clone.unwrapped.goal, env.unwrapped.goal)
    # pymunk's solver warm-start cache is not part of the pickled state, so a clone does not replay the
    # original bit for bit; but two clones of one pickle do replay each other exactly.
    action = np.full(6, -0.2, np.float32)
    for _ in range(10):
        np.testing.assert_array_equal(clone_a.step(action)[0], clone_b.step(action)[0])


def test_subproc_vec_env_runs():
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv

    # The "module:id" form makes the subprocesses import sb3_hddpg, which registers the ids.
    vec = make_vec_env("sb3_hddpg:hddpg/SnakeGoal-v0", n_envs=2, seed=0, vec_env_cls=SubprocVecEnv)
    obs = vec.reset()
    obs, rewards, dones, infos = vec.step(np.zeros((2, 6), np.float32))
    assert obs.shape == (2, 39) and "reward_terms" in infos[0]
    vec.close()


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"n_joints": 1}, "n_joints"),
        ({"n_joints": 2.5}, "n_joints"),
        ({"n_obstacles": -1}, "n_obstacles"),
        ({"obstacle_radius": 0.0}, "obstacle_radius"),
        ({"obstacle_radius": float("nan")}, "obstacle_radius"),
        ({"touch_radius": -0.1}, "touch_radius"),
        ({"r_bf": float("inf")}, "r_bf"),
        ({"obstacle_speed": -1.0}, "obstacle_speed"),
        ({"goal_speed": float("nan")}, "goal_speed"),
        ({"substeps": 0}, "substeps"),
        ({"dt": 0}, "dt"),
        ({"max_joint_speed": -2}, "max_joint_speed"),
        ({"goal_radius_max": 1.5}, "goal_radius_max"),
        ({"reward": "speed"}, "reward"),
        ({"render_mode": "ascii"}, "render_mode"),
    ],
)
def test_bad_constructor_arguments_raise_value_error(kwargs, name):
    with pytest.raises(ValueError, match=name) as error:
        SnakeArmEnv(**kwargs)
    assert repr(next(iter(kwargs.values())))[:3] in str(error.value)


@pytest.mark.parametrize("bad", [np.full(6, np.nan), np.full(6, np.inf), np.zeros(5)])
def test_bad_actions_raise_value_error(bad):
    env = gym.make("hddpg/SnakeReach-v0").unwrapped
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.step(bad.astype(np.float32))


def test_every_space_the_env_lets_go_of_is_emptied_first():
    # pymunk 7 aborts the process when the cyclic collector frees a joint before its space; an emptied
    # space frees safely in any order (this aborted `hddpg-cli evaluate` at random before the fix).
    env = SnakeArmEnv()
    env.reset(seed=0)
    old = env.space
    env.reset(seed=1)
    assert not old.constraints and not old.bodies
    assert len(env.space.constraints) == 2 * env.n_joints  # a pivot and a motor per joint
    env.close()
    assert not env.space.constraints and not env.space.bodies


def test_a_script_that_never_closes_its_env_exits_without_noise():
    # An SBX model keeps its env alive until interpreter teardown, after pymunk's globals are gone: its
    # finaliser then printed a traceback per space at every exit of such a script.
    pytest.importorskip("sbx")
    script = (
        "import gymnasium as gym, sb3_hddpg\n"
        "from sbx import DDPG\n"
        "env = gym.make('hddpg/SnakeReach-v0')\n"
        "model = DDPG('MlpPolicy', env)\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr and "Exception ignored" not in done.stderr, done.stderr


def test_parameters_are_one_frozen_checked_record():
    from dataclasses import FrozenInstanceError

    from sb3_hddpg.envs.snake import SnakeParams

    env = SnakeArmEnv(n_joints=np.int64(4), dt=1)
    assert env.params == SnakeParams(n_joints=4, dt=1.0)
    assert type(env.n_joints) is int and type(env.dt) is float
    with pytest.raises(FrozenInstanceError):
        env.params.n_joints = 3  # type: ignore[misc]
    with pytest.raises(ValueError, match="n_joints"):
        SnakeParams(n_joints=33)


def test_goal_term_is_one_definition_for_a_step_and_a_batch():
    from sb3_hddpg.envs.snake import GoalTerm

    term = GoalTerm(touch_radius=0.1, low=-1.9)
    distances = np.array([0.0, 0.05, 0.1, 0.1000001, 0.7, 2.5])
    batch, touched = term.batch(distances)
    one_by_one = [term(float(d)) for d in distances]
    assert batch.tolist() == [value for value, _ in one_by_one]
    assert touched.tolist() == [flag for _, flag in one_by_one]
    assert batch[-1] == -1.9  # clipped to the lower bound


def test_view_reports_the_state_without_stepping():
    env = SnakeArmEnv(touch_radius=5.0)
    env.reset(seed=3)
    _, _, _, _, info = env.step(np.zeros(6, np.float32))
    points = env.link_points()
    view = env.view()
    assert view.goal_touched == info["goal_touched"] and view.collision == info["collision"]
    assert view.goal_distance == pytest.approx(info["distance_to_goal"])
    np.testing.assert_array_equal(view.link_points, points)
    np.testing.assert_array_equal(env.link_points(), points)
    assert len(view.touching) == env.n_joints and view.touched_obstacles().shape == (env.n_obstacles,)

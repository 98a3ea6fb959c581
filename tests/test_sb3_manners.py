"""``Hierarchy`` acts, saves and loads as an SB3 model does, and is scored on VecEnvs with its options intact."""

from __future__ import annotations

import inspect
from functools import partial

import gymnasium as gym
import numpy as np
import pytest
from sb3_contrib import TQC
from stable_baselines3 import DDPG, DQN, PPO, SAC
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv, VecMonitor

from sb3_hddpg import evaluate
from sb3_hddpg.hierarchy.hierarchy import Hierarchy
from sb3_hddpg.hierarchy.selection import SelectionConfig
from sb3_hddpg.hierarchy.wrapper import WorkerSelectionWrapper
from sb3_hddpg.training.agent import make_snake_env

ENV_ID = "hddpg/SnakeReach-v0"
OPTION_STEPS = 3
SMALL = {"net_arch": [16]}


@pytest.fixture(scope="module")
def bundle(tmp_path_factory):
    """An untrained sampling hierarchy with 3-step options, saved: acting is what is tested, not skill."""
    workers = {
        name: DDPG("MlpPolicy", gym.make(ENV_ID), policy_kwargs=SMALL, seed=seed)
        for seed, name in enumerate(("goal", "avoid"))
    }
    config = SelectionConfig(
        preferences={"goal": 1.0, "avoid": 1.0}, selection="sample", option_steps=OPTION_STEPS
    )
    manager_env = WorkerSelectionWrapper(gym.make(ENV_ID), workers, **config.wrapper_kwargs())
    # Untrained: close to uniform, so that sampling reaches both workers where the most probable is one.
    manager = DDPG("MlpPolicy", manager_env, policy_kwargs=SMALL, seed=2)
    hierarchy = Hierarchy(manager, workers, config, env_id=ENV_ID)
    return hierarchy.save(tmp_path_factory.mktemp("manners") / "hierarchy")


def _make_env() -> gym.Env:
    return gym.make(ENV_ID)


@pytest.fixture(params=[(DummyVecEnv, 4), (SubprocVecEnv, 2)], ids=["dummy4", "subproc2"])
def vec_env(request):
    """A VecEnv of the snake: 4 envs in this process, or 2 in processes of their own (started by forkserver:
    forking a process that runs torch is unsafe), whose observations are all the hierarchy sees."""
    cls, n_envs = request.param
    kwargs = {"start_method": "forkserver"} if cls is SubprocVecEnv else {}
    # A module-level factory: a SubprocVecEnv pickles it into its processes.
    envs = VecMonitor(cls([partial(make_snake_env, ENV_ID)] * n_envs, **kwargs))
    yield envs
    envs.close()


def test_save_appends_zip_and_load_finds_it_as_sb3_does(bundle, tmp_path):
    assert bundle.name == "hierarchy.zip" and bundle.is_file()
    loaded = Hierarchy.load(bundle.with_suffix(""))  # no suffix: found as hierarchy.zip
    assert loaded.save(tmp_path / "kept.bundle").name == "kept.bundle"  # a suffix given is kept
    assert not (tmp_path / "kept.bundle.zip").exists()


def test_predict_samples_by_default_as_sb3(bundle):
    assert inspect.signature(Hierarchy.predict).parameters["deterministic"].default is False
    loaded = Hierarchy.load(bundle)
    loaded.seed(0)
    obs, _ = _make_env().reset(seed=0)
    start = np.array([True])  # a new decision at every call
    sampled = {loaded.predict(obs, episode_start=start)[1].choice[0] for _ in range(40)}
    most_probable = {
        loaded.predict(obs, episode_start=start, deterministic=True)[1].choice[0] for _ in range(10)
    }
    assert sampled == {0, 1} and len(most_probable) == 1


def test_options_are_kept_per_env_of_a_batch(bundle):
    loaded = Hierarchy.load(bundle)
    envs = [_make_env() for _ in range(4)]
    obs = np.stack([env.reset(seed=seed)[0] for seed, env in enumerate(envs)])
    state = loaded.initial_state(4)
    lefts, choices = [], []
    for step in range(7):
        start = np.array([step == 4, False, False, False])  # env 0 starts a new episode at step 4
        actions, state = loaded.predict(obs, state, start, deterministic=True)
        lefts.append(state.left.copy())
        choices.append(state.choice.copy())
        obs = np.stack([env.step(action)[0] for env, action in zip(envs, actions)])
    lefts = np.array(lefts)
    # Every env holds its worker for OPTION_STEPS steps; env 0's early episode start cut its option short.
    np.testing.assert_array_equal(lefts[:, 1], [2, 1, 0, 2, 1, 0, 2])
    np.testing.assert_array_equal(lefts[:, 0], [2, 1, 0, 2, 2, 1, 0])
    for begin in (0, 3):
        assert all((np.array(choices[begin : begin + 3])[:, 1:] == choices[begin][1:]).all(axis=1))
    # The same rows one at a time, each with its own state, act identically.
    single = Hierarchy.load(bundle)
    rows = np.stack([env.reset(seed=seed)[0] for seed, env in enumerate(envs)])
    together, alone = single.initial_state(4), [single.initial_state() for _ in envs]
    batched, together = single.predict(rows, together, deterministic=True)
    for i in range(4):
        action, alone[i] = single.predict(rows[i], alone[i], deterministic=True)
        np.testing.assert_array_equal(action, batched[i])
    with pytest.raises(ValueError, match="state for 4 envs"):
        single.predict(rows, alone[0])


def test_load_takes_env_and_device_as_sb3(bundle):
    loaded = Hierarchy.load(bundle, env=_make_env(), device="cpu")
    assert isinstance(loaded.get_env(), VecEnv) and loaded.get_env().num_envs == 1
    assert loaded.manager.device.type == "cpu"
    with pytest.raises(ValueError, match="Observation spaces do not match"):
        Hierarchy.load(bundle, env=gym.make("Pendulum-v1"))


def test_load_and_set_env_take_a_vec_env_as_sb3(bundle, vec_env):
    loaded = Hierarchy.load(bundle, env=vec_env)
    assert loaded.get_env() is vec_env
    loaded.set_env(_make_env())  # a single env is wrapped, as SB3 does
    assert isinstance(loaded.get_env(), DummyVecEnv) and loaded.get_env().num_envs == 1


@pytest.mark.parametrize("algorithm", [SAC, DDPG, DQN, PPO, TQC])
def test_an_sb3_class_pointed_at_a_bundle_says_what_the_file_is(bundle, algorithm):
    with pytest.raises(
        ValueError, match=r"sb3-hddpg hierarchy bundle, which sb3_hddpg.Hierarchy.load opens"
    ) as info:
        algorithm.load(bundle)
    assert "\n" not in str(info.value)
    Hierarchy.load(bundle)  # the entry SB3 reads leaves the bundle verifiable


def test_sb3_evaluate_policy_scores_a_hierarchy_on_a_vec_env_with_options(bundle, vec_env):
    loaded = Hierarchy.load(bundle)
    lefts: list[np.ndarray] = []

    class Watched:
        """The loaded hierarchy, its options' counters read after every step evaluate_policy takes."""

        def predict(self, observation, state=None, episode_start=None, deterministic=False):
            action, state = loaded.predict(observation, state, episode_start, deterministic)
            lefts.append(state.left.copy())
            return action, state

    vec_env.seed(0)
    rewards, lengths = evaluate_policy(
        Watched(), vec_env, n_eval_episodes=4, deterministic=True, return_episode_rewards=True
    )
    assert len(rewards) == 4 and all(np.isfinite(rewards)) and set(lengths) == {200}
    steps = np.array(lefts)
    # Options intact: every env decides every OPTION_STEPS steps (its counter cycles 2, 1, 0), never anew each step.
    expected = [(OPTION_STEPS - 1 - t % OPTION_STEPS) for t in range(200)]
    np.testing.assert_array_equal(steps[:200], np.tile(np.array(expected)[:, None], (1, vec_env.num_envs)))
    vec_env.seed(0)
    mean, _ = evaluate_policy(loaded, vec_env, n_eval_episodes=4, deterministic=True)
    assert mean == pytest.approx(np.mean(rewards))


def test_sb3_hddpg_evaluate_scores_a_hierarchy_on_a_vec_env_like_one_env(bundle, vec_env):
    loaded = Hierarchy.load(bundle)
    on_one = evaluate(loaded, _make_env(), n_episodes=5, seed=7)
    on_vec = evaluate(loaded, vec_env, n_episodes=5, seed=7)
    assert [e.seed for e in on_vec.episodes] == [7, 8, 9, 10, 11]
    assert (on_vec.near_clearance, on_vec.clear_clearance) == (on_one.near_clearance, on_one.clear_clearance)
    for one, vec in zip(on_one.episodes, on_vec.episodes):
        assert vec.length == one.length
        assert vec.reward == pytest.approx(one.reward, rel=1e-5)  # the VecEnv stores float32 rewards
        assert vec.term_rewards == pytest.approx(one.term_rewards, rel=1e-6)
        # Options intact: the same workers for as many steps as on one env.
        assert vec.selections == one.selections
        assert (vec.selections_near, vec.collisions) == (one.selections_near, one.collisions)


def test_evaluate_records_only_envs_of_this_process(bundle, vec_env):
    loaded, seen = Hierarchy.load(bundle), []
    if isinstance(vec_env.unwrapped, DummyVecEnv):
        evaluate(loaded, vec_env, n_episodes=1, on_step=lambda env, info: seen.append(env))
        assert len(seen) == 200 and all(isinstance(env, gym.Env) for env in seen)
    else:
        with pytest.raises(
            ValueError, match="SubprocVecEnv runs in another process; use a DummyVecEnv"
        ) as info:
            evaluate(loaded, vec_env, n_episodes=1, on_step=lambda env, info: seen.append(env))
        assert "\n" not in str(info.value) and not seen

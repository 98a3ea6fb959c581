"""
Every algorithm one record: each trains a few hundred steps (tiny networks), saves, loads safely from its
spec and acts the same; SBX's TQC and CrossQ export to sb3-contrib models that act like the JAX policy
(batch renormalisation statistics included); workers pick their learner per worker; frozen workers run
every learner's policy as its own ``predict`` does.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from stable_baselines3.common.env_util import make_vec_env

from hddpg_zoo.hyperparams_opt import SAMPLERS, search_space
from hddpg_zoo.media.figures import COLOURS
from sb3_hddpg.algorithms import ACTION_SPACES, REGISTRY, ROLES, NetworkShape, algorithm, algorithms_for
from sb3_hddpg.artifacts.limits import (
    LimitError,
)
from sb3_hddpg.artifacts.manifests import load_workers
from sb3_hddpg.artifacts.network_limits import check_parameter_count
from sb3_hddpg.artifacts.safe_load import load_model
from sb3_hddpg.artifacts.spec import model_spec
from sb3_hddpg.envs.terms_env import TermsEnv
from sb3_hddpg.hierarchy.frozen import FrozenWorker
from sb3_hddpg.training.backends import sbx_installed
from sb3_hddpg.training.config import default_config
from sb3_hddpg.training.models import make_model, to_sb3
from sb3_hddpg.training.workers import parse_worker_algorithms, train_workers, worker_algorithms

needs_sbx = pytest.mark.skipif(not sbx_installed(), reason='needs SBX: pip install "sb3-hddpg[fast]"')

#: Tiny constructor arguments per algorithm: a few hundred steps train every network at least once.
TINY: dict[str, dict] = {
    "ddpg": dict(learning_starts=50, batch_size=16, buffer_size=500, policy_kwargs=dict(net_arch=[16])),
    "td3": dict(learning_starts=50, batch_size=16, buffer_size=500, policy_kwargs=dict(net_arch=[16])),
    "sac": dict(learning_starts=50, batch_size=16, buffer_size=500, policy_kwargs=dict(net_arch=[16])),
    "tqc": dict(
        learning_starts=50, batch_size=16, buffer_size=500, policy_kwargs=dict(net_arch=[16], n_quantiles=5)
    ),
    "crossq": dict(learning_starts=50, batch_size=16, buffer_size=500, policy_kwargs=dict(net_arch=[16])),
    "dqn": dict(learning_starts=50, batch_size=16, buffer_size=500, policy_kwargs=dict(net_arch=[16])),
    "qrdqn": dict(
        learning_starts=50, batch_size=16, buffer_size=500, policy_kwargs=dict(net_arch=[16], n_quantiles=5)
    ),
    "ppo": dict(n_steps=64, batch_size=32, n_epochs=2, policy_kwargs=dict(net_arch=[16])),
}


def _env_id(algo: str) -> str:
    return "Pendulum-v1" if algorithm(algo).takes(gym.spaces.Box(-1, 1)) else "CartPole-v1"


def test_every_algorithm_has_its_facts_in_one_record():
    assert set(TINY) == set(REGISTRY)
    colours = [record.colour for record in REGISTRY.values()]
    assert len(set(colours)) == len(colours)
    for name, record in REGISTRY.items():
        assert record.name == name and algorithm(record.class_name) is record
        assert record.roles <= set(ROLES) and record.action_spaces <= set(ACTION_SPACES)
        assert record.sampler in SAMPLERS and search_space("flat", name)
        assert default_config(name).is_file()
        assert COLOURS[name] == record.colour
        assert record.hyperparameters and record.policy_kwargs
    assert algorithms_for("flat", gym.spaces.Discrete(3)) == ("dqn", "qrdqn", "ppo")
    assert "ppo" in algorithms_for("manager", gym.spaces.Box(-1, 1))


def test_parameter_rules_refuse_huge_networks_of_every_algorithm():
    for name in REGISTRY:
        small = check_parameter_count(name, 10, 3, [16], [16])
        assert small == algorithm(name).parameter_count(NetworkShape(10, 3, [16], [16]))
        assert small > 0
        with pytest.raises(LimitError, match="net_arch"):
            check_parameter_count(name, 10, 3, [1 << 15, 1 << 15], [1 << 15, 1 << 15])


@pytest.mark.parametrize("algo", list(TINY))
def test_train_save_safe_load_same_actions(algo, tmp_path):
    env = make_vec_env(_env_id(algo), n_envs=1, seed=0)
    model = make_model(algo, "sb3", env, TINY[algo], seed=0)
    model.learn(200)
    path = tmp_path / f"{algo}.zip"
    model.save(path)
    spec = model_spec(model)
    assert spec["algorithm"] == algorithm(algo).class_name
    loaded = load_model(path, spec=spec)
    assert type(loaded) is algorithm(algo).cls
    obs = np.stack([env.observation_space.sample() for _ in range(16)])
    expected = model.predict(obs, deterministic=True)[0]
    np.testing.assert_allclose(loaded.predict(obs, deterministic=True)[0], expected, atol=1e-6)
    # A frozen worker acts as predict does (numpy, torch or predict, whichever the policy allows).
    frozen = FrozenWorker(loaded)
    np.testing.assert_allclose(frozen.act(obs), expected, atol=1e-5)


@needs_sbx
@pytest.mark.slow  # jax compiles each algorithm's update: tens of seconds on a shared machine
@pytest.mark.parametrize("algo", ["tqc", "crossq"])
def test_sbx_export_acts_like_the_jax_policy(algo, tmp_path):
    sb3_env = make_vec_env("hddpg/SnakeGoal-v0", n_envs=1, seed=0)
    obs = np.stack([sb3_env.observation_space.sample() for _ in range(32)])
    # Same seed, same initial networks on both backends.
    start = make_model(algo, "sb3", sb3_env, TINY[algo], seed=1).predict(obs, deterministic=True)[0]
    model = make_model(algo, "sbx", make_vec_env("hddpg/SnakeGoal-v0", n_envs=1, seed=0), TINY[algo], seed=1)
    np.testing.assert_allclose(model.predict(obs, deterministic=True)[0], start, atol=1e-5)
    model.learn(200)  # weights (and CrossQ's running statistics) move off their initial values
    jax_actions = model.predict(obs, deterministic=True)[0]
    assert np.abs(jax_actions - start).max() > 1e-3
    exported = to_sb3(model)
    assert type(exported) is algorithm(algo).cls
    np.testing.assert_allclose(exported.predict(obs, deterministic=True)[0], jax_actions, atol=1e-5)
    if algo == "crossq":
        moved = exported.policy.actor.latent_pi[0]
        assert int(moved.steps) > 0 and float(moved.ra_var.sub(1).abs().max()) > 1e-4
    log_ent_coef = float(np.asarray(model.ent_coef_state.params["log_ent_coef"]))
    assert exported.log_ent_coef.item() == pytest.approx(log_ent_coef, abs=1e-6) and log_ent_coef != 0.0
    path = tmp_path / f"{algo}.zip"
    exported.save(path)
    for loaded in (algorithm(algo).cls.load(path, device="cpu"), load_model(path, spec=model_spec(exported))):
        np.testing.assert_allclose(loaded.predict(obs, deterministic=True)[0], jax_actions, atol=1e-5)


@needs_sbx
@pytest.mark.slow
def test_sbx_crossq_critics_match_the_exported_ones():
    model = make_model("crossq", "sbx", make_vec_env("Pendulum-v1", n_envs=1, seed=0), TINY["crossq"], seed=2)
    model.learn(150)
    exported = to_sb3(model)
    rng = np.random.default_rng(0)
    obs = rng.uniform(-1, 1, (16, 3)).astype(np.float32)
    actions = rng.uniform(-1, 1, (16, 1)).astype(np.float32)
    state = model.policy.qf_state
    q_jax = np.asarray(
        state.apply_fn({"params": state.params, "batch_stats": state.batch_stats}, obs, actions, train=False)
    )
    exported.critic.set_bn_training_mode(False)
    with torch.no_grad():
        q_torch = np.stack(
            [q.numpy() for q in exported.critic(torch.as_tensor(obs), torch.as_tensor(actions))]
        )
    np.testing.assert_allclose(q_torch, q_jax, atol=1e-4)


def test_worker_algorithms_are_parsed_and_checked():
    workers = ["goal", "avoid"]
    assert parse_worker_algorithms("goal=crossq,avoid=SAC", workers) == {"goal": "crossq", "avoid": "sac"}
    # A worker not named keeps its default: the snake arm's study-chosen learner, DDPG on another env.
    assert parse_worker_algorithms("goal=ppo", workers) == {"goal": "ppo", "avoid": "ddpg"}
    assert worker_algorithms(workers) == {"goal": "ddpg", "avoid": "ddpg"}
    other = TermsEnv("hddpg/SnakeReach-v0", {}, ("goal", "avoid"))
    assert parse_worker_algorithms("goal=ppo", workers, other) == {"goal": "ppo", "avoid": "ddpg"}
    assert parse_worker_algorithms("tqc", workers) == {"goal": "tqc", "avoid": "tqc"}
    for text, needle in (
        ("goal=a2c", "a2c"),
        ("reach=sac", "reach"),
        ("goal=sac,goal=td3", "twice"),
        ("goal=sac,avoid", "WORKER=ALGORITHM"),
    ):
        with pytest.raises(ValueError, match=needle):
            parse_worker_algorithms(text, workers)


TINY_WORKERS = """\
default:
  n_timesteps: 120
  policy: 'MlpPolicy'
  buffer_size: 500
  learning_starts: 50
  batch_size: 16
  policy_kwargs: "dict(net_arch=[16])"
"""


def test_train_workers_with_a_learner_per_worker(tmp_path):
    config = tmp_path / "tiny.yml"
    config.write_text(TINY_WORKERS)
    manifest = train_workers(
        tmp_path / "run",
        ["goal", "avoid"],
        config,
        algos={"goal": "crossq", "avoid": "sac"},
        eval_freq=60,
        eval_episodes=1,
        progress_bar=False,
    ).manifest
    assert {name: entry["algo"] for name, entry in manifest["workers"].items()} == {
        "goal": "crossq",
        "avoid": "sac",
    }
    workers = load_workers(tmp_path / "run")
    assert type(workers["goal"]).__name__ == "CrossQ" and type(workers["avoid"]).__name__ == "SAC"


def test_a_discrete_manager_picks_a_worker_by_index(tmp_path):
    from sb3_hddpg.hierarchy import WorkerSelectionWrapper
    from sb3_hddpg.hierarchy.hierarchy import Hierarchy
    from sb3_hddpg.hierarchy.selection import SelectionConfig
    from tests.helpers import ActionRecorder, ConstantWorker

    goal, avoid = np.full(6, 0.5, np.float32), np.full(6, -0.25, np.float32)
    inner = ActionRecorder(gym.make("hddpg/SnakeReach-v0"))
    workers = {"goal": ConstantWorker(goal), "avoid": ConstantWorker(avoid)}
    env = WorkerSelectionWrapper(inner, workers, selection="discrete")
    assert env.action_space == gym.spaces.Discrete(2)
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.int64(1))
    assert info["selected_worker"] == "avoid" and info["selection_probabilities"] == {
        "goal": 0.0,
        "avoid": 1.0,
    }
    np.testing.assert_array_equal(inner.actions[-1], avoid)
    # A DQN learns on it, and a hierarchy with it as manager acts through the chosen worker.
    manager = make_model("dqn", "sb3", env, TINY["dqn"], seed=0)
    manager.learn(120)
    config = SelectionConfig(preferences={"goal": 1.0, "avoid": 1.0}, selection="discrete")
    hierarchy = Hierarchy(manager, workers, config, env_id="hddpg/SnakeReach-v0")
    obs, _ = gym.make("hddpg/SnakeReach-v0").reset(seed=0)
    action, _ = hierarchy.predict(obs, deterministic=True)
    chosen = int(manager.predict(obs, deterministic=True)[0])
    np.testing.assert_array_equal(action, (goal, avoid)[chosen])
    assert sorted(hierarchy.probabilities(obs).values()) == [0.0, 1.0]


TINY_PPO = """\
default:
  n_timesteps: 128
  policy: 'MlpPolicy'
  n_steps: 64
  batch_size: 32
  n_epochs: 1
  policy_kwargs: "dict(net_arch=dict(pi=[16], vf=[16]))"
"""


def test_an_on_policy_flat_agent_trains_checkpoints_and_resumes(tmp_path):
    from sb3_hddpg.training.flat import check_flat_env, train_flat

    with pytest.raises(ValueError, match=r"dqn takes \(\['Discrete'\]\), actually Box"):
        check_flat_env("dqn")
    config = tmp_path / "ppo.yml"
    config.write_text(TINY_PPO)
    options = dict(
        eval_freq=64, eval_episodes=1, checkpoint_freq=64, progress_bar=False, keep_checkpoints=True
    )
    result = train_flat(tmp_path, "ppo", config, **options)
    manifest, first = result.manifest, result.outcome
    assert first is not None and first.num_timesteps == 128 and manifest["models"]["ppo"]["algo"] == "ppo"
    # Resumed with a larger budget: it continues from its checkpoint (no replay buffer to restore).
    result = train_flat(tmp_path, "ppo", config, timesteps=256, resume=True, **options)
    manifest, resumed = result.manifest, result.outcome
    assert resumed is not None and resumed.num_timesteps == 256
    assert [h["timesteps"] for h in resumed.history][:2] == [64, 128]
    entry = manifest["models"]["ppo"]
    loaded = load_model(tmp_path / "flat" / entry["file"], spec=entry["spec"])
    assert type(loaded).__name__ == "PPO"


TINY_DISCRETE = """\
default: &tiny
  n_timesteps: 150
  policy: 'MlpPolicy'
  learning_starts: 50
  batch_size: 16
  buffer_size: 500
  policy_kwargs: "dict(net_arch=[16])"
manager:
  <<: *tiny
  n_timesteps: 100
  learning_starts: 20
  wrapper_kwargs:
    selection: 'discrete'
"""


def test_discrete_workers_and_a_discrete_manager_on_a_discrete_env(tmp_path):
    pytest.importorskip("mo_gymnasium")
    from sb3_hddpg.envs.terms_env import terms_env
    from sb3_hddpg.hierarchy.hierarchy import Hierarchy
    from sb3_hddpg.training.manager import train_manager

    shared = terms_env("resource-gathering-v0", terms=["death", "gold", "gem"])
    config = tmp_path / "tiny.yml"
    config.write_text(TINY_DISCRETE)
    algos = {"death": "dqn", "gold": "qrdqn", "gem": "dqn"}
    manifest = train_workers(
        tmp_path / "w", config=config, env=shared, algos=algos, eval_freq=0, eval_episodes=1
    ).manifest
    assert {name: entry["algo"] for name, entry in manifest["workers"].items()} == algos
    train_manager(tmp_path / "w", tmp_path / "m", algo="qrdqn", config=config, eval_freq=50, eval_episodes=1)
    hierarchy = Hierarchy.load(tmp_path / "m" / "hierarchy.zip")  # the safe loader: spec and weights only
    assert type(hierarchy.manager).__name__ == "QRDQN" and hierarchy.config.selection == "discrete"
    env = gym.make(hierarchy.env_id, **hierarchy.env_kwargs)
    obs, _ = env.reset(seed=0)
    # The chosen discrete worker's action, an index of the env's actions.
    action, _ = hierarchy.predict(obs, deterministic=True)
    assert env.action_space.contains(int(np.asarray(action).reshape(-1)[0]))

"""Workers, the manager and bundles, through the Python API on tiny budgets."""

import io
import json
import subprocess
import sys
import zipfile

import gymnasium as gym
import numpy as np
import pytest
import torch
from stable_baselines3 import DDPG

from sb3_hddpg.artifacts.provenance import sha256_file
from sb3_hddpg.hierarchy import WorkerSelectionWrapper
from sb3_hddpg.hierarchy.bundle import BundleError
from sb3_hddpg.hierarchy.hierarchy import Hierarchy, SelectionConfig
from sb3_hddpg.training.manager import train_manager
from sb3_hddpg.training.workers import train_workers

TINY = {"timesteps": 400, "eval_freq": 200, "eval_episodes": 1}


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    root = tmp_path_factory.mktemp("run")
    manifest = train_workers(root / "w", seed=3, **TINY).manifest
    result = train_manager(root / "w", root / "m", prefer="goal", bias=0.15, seed=3, **TINY)
    hierarchy, outcome = result.hierarchy, result.outcome
    return root, manifest, hierarchy, outcome


def test_worker_zips_are_plain_sb3_and_manifest_is_complete(trained):
    root, manifest, _, _ = trained
    assert set(manifest["workers"]) == {"goal", "avoid"}
    on_disk = json.loads((root / "w" / "workers" / "manifest.json").read_text())
    assert on_disk == json.loads(json.dumps(manifest))
    for name, entry in manifest["workers"].items():
        path = root / "w" / "workers" / entry["file"]
        # Nothing but SB3: the snake arm's default learner, DDPG, for both workers.
        model = DDPG.load(path)
        # The bundled config feeds the goal worker its 15 goal-relevant values (env kwarg observe).
        assert model.observation_space.shape == {"goal": (15,), "avoid": (39,)}[name]
        assert entry["sha256"] == sha256_file(path)
        assert entry["env_id"] == {"goal": "hddpg/SnakeGoal-v0", "avoid": "hddpg/SnakeAvoid-v0"}[name]
        assert entry["reward_term"] == name
        assert entry["reward_bounds"] == list(gym.make(entry["env_id"]).unwrapped.reward_bounds[name])
        assert entry["seed"] == 3 and entry["timesteps_trained"] == 400
        assert {"stable_baselines3", "torch", "gymnasium", "pymunk"} <= set(entry["versions"])
        assert {
            "mean_reward",
            "goal_touch_rate",
            "collisions_per_episode",
            "success_rate",
            "min_clearance",
        } <= set(entry["metrics"])
        # Each worker's own block, as the config wrote it (the goal worker has larger networks).
        nets = {"goal": "dict(net_arch=[256, 256])", "avoid": "dict(net_arch=[64, 64])"}
        assert entry["config"]["block"]["policy_kwargs"] == nets[name]
        assert entry["spec"]["algorithm"] == "DDPG"


def test_same_seed_gives_identical_weights(tmp_path):
    a = train_workers(
        tmp_path / "a", workers=["goal"], seed=11, timesteps=300, eval_freq=0, eval_episodes=1
    ).manifest
    b = train_workers(
        tmp_path / "b", workers=["goal"], seed=11, timesteps=300, eval_freq=0, eval_episodes=1
    ).manifest
    c = train_workers(
        tmp_path / "c", workers=["goal"], seed=12, timesteps=300, eval_freq=0, eval_episodes=1
    ).manifest
    weights = [
        DDPG.load(p / "workers" / "goal.zip").policy.state_dict()
        for p in (tmp_path / "a", tmp_path / "b", tmp_path / "c")
    ]
    assert all(torch.equal(weights[0][k], weights[1][k]) for k in weights[0])
    assert not all(torch.equal(weights[0][k], weights[2][k]) for k in weights[0])
    assert a["workers"]["goal"]["sha256"] != c["workers"]["goal"]["sha256"]
    assert b["workers"]["goal"]["metrics"] == a["workers"]["goal"]["metrics"]


def test_bundle_round_trip_in_a_fresh_process(trained):
    root, _, hierarchy, _ = trained
    path = root / "m" / "hierarchy.zip"
    obs = np.stack([gym.make("hddpg/SnakeReach-v0").reset(seed=s)[0] for s in range(8)])
    # Seeded as a freshly loaded hierarchy is: a tiny manager may output exact ties, which draw from it.
    hierarchy.seed(0)
    expected, _ = hierarchy.predict(obs, deterministic=True)
    np.save(root / "obs.npy", obs)
    script = (
        "import numpy as np, sys; from sb3_hddpg import Hierarchy;"
        f"h = Hierarchy.load({str(path)!r});"
        f"a, _ = h.predict(np.load({str(root / 'obs.npy')!r}), deterministic=True);"
        f"np.save({str(root / 'out.npy')!r}, a)"
    )
    subprocess.run([sys.executable, "-c", script], check=True)
    np.testing.assert_array_equal(np.load(root / "out.npy"), expected)
    # Single observations behave like batched ones, and every member still opens with plain SB3 loading.
    hierarchy.seed(0)
    hierarchy.reset_episode()  # a new option, as at an episode start (the batch decides every row anew)
    single, _ = hierarchy.predict(obs[0], deterministic=True)
    np.testing.assert_array_equal(single, expected[0])
    with zipfile.ZipFile(path) as archive:
        manifest = json.loads(archive.read("manifest.json"))
        for member, cls in (("manager.zip", DDPG), ("workers/goal.zip", DDPG), ("workers/avoid.zip", DDPG)):
            cls.load(io.BytesIO(archive.read(member)))
    assert manifest["selection"]["preferences"] == {"goal": 1.15, "avoid": 1.0}
    assert manifest["worker_names"] == ["goal", "avoid"]
    assert manifest["workers"]["goal"]["reward_bounds"] == [-1.9, 1.0]


def _rewrite(path, out, change):
    with zipfile.ZipFile(path) as source, zipfile.ZipFile(out, "w") as target:
        for item in source.infolist():
            target.writestr(item, change(item.filename, source.read(item.filename)))


def test_tampered_bundles_are_refused(trained, tmp_path):
    root, _, _, _ = trained
    path = root / "m" / "hierarchy.zip"

    def flip_worker(name, data):
        if name == "workers/avoid.zip":
            data = bytearray(data)
            data[len(data) // 2] ^= 0xFF
            return bytes(data)
        return data

    _rewrite(path, tmp_path / "tampered.zip", flip_worker)
    with pytest.raises(BundleError, match=r"sha256 of 'workers/avoid.zip' does not match"):
        Hierarchy.load(tmp_path / "tampered.zip")

    def drop_member_hash(name, data):
        if name == "manifest.json":
            manifest = json.loads(data)
            manifest["manager"]["sha256"] = "0" * 64
            return json.dumps(manifest).encode()
        return data

    _rewrite(path, tmp_path / "bad_manifest.zip", drop_member_hash)
    with pytest.raises(BundleError, match=r"manager\.zip"):
        Hierarchy.load(tmp_path / "bad_manifest.zip")

    (tmp_path / "truncated.zip").write_bytes(path.read_bytes()[:1000])
    with pytest.raises(BundleError, match="truncated"):
        Hierarchy.load(tmp_path / "truncated.zip")


def test_nested_hierarchy_is_a_worker_and_saves_as_one_bundle(trained, tmp_path):
    root, _, hierarchy, _ = trained
    avoid = DDPG.load(root / "w" / "workers" / "avoid.zip")
    env = WorkerSelectionWrapper(
        gym.make("hddpg/SnakeReach-v0"), {"reach": hierarchy, "avoid": avoid}, selection="argmax"
    )
    # The sub-hierarchy's reward is its own preference-weighted mix of goal and avoid.
    assert env.reward_specs["reach"] == pytest.approx({"goal": 1.15 / 2.15, "avoid": 1.0 / 2.15})
    top = DDPG("MlpPolicy", env, learning_starts=50, policy_kwargs={"net_arch": [16]}, seed=0)
    top.learn(100)
    nested = Hierarchy(
        top,
        {"reach": hierarchy, "avoid": avoid},
        SelectionConfig(preferences={"reach": 1.0, "avoid": 1.0}, selection="argmax"),
    )
    nested.save(tmp_path / "nested.zip")
    loaded = Hierarchy.load(tmp_path / "nested.zip")
    assert isinstance(loaded.workers["reach"], Hierarchy)
    obs = np.stack([gym.make("hddpg/SnakeReach-v0").reset(seed=s)[0] for s in range(5)])
    np.testing.assert_array_equal(
        loaded.predict(obs, deterministic=True)[0], nested.predict(obs, deterministic=True)[0]
    )
    with zipfile.ZipFile(tmp_path / "nested.zip") as archive:
        assert "workers/reach.hierarchy.zip" in archive.namelist()


def test_training_metrics_and_selection_are_reported(trained):
    _, _, hierarchy, outcome = trained
    assert set(outcome.metrics["selection_rate"]) == {"goal", "avoid"}
    assert sum(outcome.metrics["selection_rate"].values()) == pytest.approx(1.0)
    # SB3 runs whole rollouts of train_freq decisions, so a run ends at the first rollout at or past 400.
    from stable_baselines3 import DDPG

    from sb3_hddpg.training.config import MANAGER_KEY, load_hyperparams

    rollout = int(load_hyperparams(MANAGER_KEY, DDPG, manager=True).algo_kwargs["train_freq"])
    assert outcome.num_timesteps == -(-400 // rollout) * rollout


def test_parallel_envs_in_subprocesses(tmp_path):
    manifest = train_workers(
        tmp_path, workers=["avoid"], n_envs=2, timesteps=400, eval_freq=200, eval_episodes=1
    ).manifest
    assert manifest["workers"]["avoid"]["timesteps_trained"] == 400


class _Constant:
    """A policy that always gives the same action."""

    def __init__(self, value: float) -> None:
        self.value = value

    def predict(self, obs, deterministic=True):
        return np.full(6, self.value, dtype=np.float32), None


@pytest.mark.parametrize(("value", "expected"), [(1.0, 1.0), (-0.995, 1.0), (0.5, 0.0), (0.0, 0.0)])
def test_action_saturation_of_a_flat_policy(value, expected):
    from sb3_hddpg.evaluation import evaluate

    summary = evaluate(_Constant(value), gym.make("hddpg/SnakeReach-v0"), n_episodes=1).summary()
    assert summary["action_saturation"] == expected


class _IndexManager(_Constant):
    """A hierarchy-like policy whose manager picks a worker by index, as a DQN manager does."""

    last_manager_action = np.array(1)


def test_an_index_has_no_action_saturation():
    # A worker's index (a DQN manager's choice, a discrete action) is no network output pinned at +-1: it
    # is left out, not counted as "saturated" whenever it is 1.
    from sb3_hddpg.evaluation import evaluate

    result = evaluate(_IndexManager(1.0), gym.make("hddpg/SnakeReach-v0"), n_episodes=1)
    assert result.episodes[0].action_saturation is None
    assert "action_saturation" not in result.summary()


def test_action_saturation_of_a_hierarchy_is_its_managers(trained):
    # For a hierarchy the deciding network is the manager: its raw action, not the worker's env action.
    from sb3_hddpg.evaluation import SATURATION_LEVEL, evaluate

    root = trained[0]
    hierarchy = Hierarchy.load(root / "m" / "hierarchy.zip")
    seen = []
    summary = evaluate(
        hierarchy,
        gym.make("hddpg/SnakeReach-v0"),
        n_episodes=2,
        on_step=lambda env, info: seen.append(np.array(hierarchy.last_manager_action)),
    ).summary()
    manager_actions = np.stack(seen)
    assert manager_actions.shape == (400, 2)
    expected = np.mean(np.abs(manager_actions) >= SATURATION_LEVEL)
    assert summary["action_saturation"] == pytest.approx(expected)


def test_train_manager_loads_each_worker_once(trained, tmp_path, monkeypatch):
    """Each worker's zip is read once per train-manager (the issue measured 6 loads for 2 workers before)."""
    import sb3_hddpg.artifacts.manifests as manifests
    from sb3_hddpg.training.manager_setup import prepare_manager

    root = trained[0]
    loaded: list[str] = []
    made: list[str] = []
    real_load, real_make = manifests.load_model, gym.make

    def counting_load(path, *args, **kwargs):
        # The zip is read once into memory, hashed and loaded from those bytes, which carry its name.
        loaded.append(getattr(path, "name", str(path)))
        return real_load(path, *args, **kwargs)

    def counting_make(env_id, *args, **kwargs):
        made.append(str(env_id))
        return real_make(env_id, *args, **kwargs)

    monkeypatch.setattr(manifests, "load_model", counting_load)
    monkeypatch.setattr(gym, "make", counting_make)
    # The CLI's path: check everything first, then train on the checked set-up.
    setup = prepare_manager(root / "w", prefer="goal")
    train_manager(setup, tmp_path / "m", timesteps=100, eval_freq=0, eval_episodes=1)
    assert sorted(loaded) == sorted(str(root / "w" / "workers" / f"{n}.zip") for n in ("goal", "avoid"))
    # The probe that checks the workers fit the env, the training env, the evaluation env, and the one
    # Hierarchy builds to check the bundle's spaces against its env.
    assert made == ["hddpg/SnakeReach-v0"] * 4
    # The one-call path loads them once too.
    loaded.clear()
    made.clear()
    train_manager(root / "w", tmp_path / "m2", timesteps=100, eval_freq=0, eval_episodes=1)
    assert len(loaded) == 2 and len(made) == 4


def test_run_options_are_one_object_or_keywords(tmp_path):
    """The run-control settings: checked when built, given as RunOptions or as keywords, typos refused."""
    from sb3_hddpg.training import RunOptions

    with pytest.raises(ValueError, match="Expected seed in"):
        RunOptions(seed=-1)
    with pytest.raises(ValueError, match="timesteps: expected an integer in \\[1, "):
        train_workers(tmp_path, timesteps=0)
    with pytest.raises(TypeError, match="unexpected keyword argument 'timestep'"):
        train_workers(tmp_path, timestep=10)
    with pytest.raises(ValueError, match="checkpoint_freq: expected an integer in \\[0, "):
        train_manager(tmp_path, tmp_path / "m", run=RunOptions(), checkpoint_freq=-1)
    assert RunOptions(seed=2).replace(timesteps=5) == RunOptions(timesteps=5, seed=2)
    assert not (tmp_path / "workers").exists()  # nothing started


def test_a_sac_manager_trains_bundles_and_reloads(trained, tmp_path):
    """`train_manager(algo="sac")`: SAC on the same action, its own config block, in a bundle like DDPG's."""
    from stable_baselines3 import SAC

    from hddpg_zoo.agent_settings import manager_option_steps

    root = trained[0]
    result = train_manager(root / "w", tmp_path / "m", algo="sac", seed=3, **TINY)
    hierarchy, outcome = result.hierarchy, result.outcome
    assert type(hierarchy.manager) is SAC and outcome.num_timesteps >= TINY["timesteps"]
    # The bundled sac.yml's manager block, not ddpg.yml's: its own selection settings.
    assert hierarchy.config.option_steps == manager_option_steps(algo="sac")
    assert hierarchy.config.temperature == pytest.approx(0.3914) != trained[2].config.temperature
    loaded = Hierarchy.load(tmp_path / "m" / "hierarchy.zip")
    assert type(loaded.manager) is SAC
    obs = np.stack([gym.make("hddpg/SnakeReach-v0").reset(seed=s)[0] for s in range(4)])
    hierarchy.seed(0)
    loaded.seed(0)
    np.testing.assert_array_equal(
        hierarchy.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0]
    )
    with zipfile.ZipFile(tmp_path / "m" / "hierarchy.zip") as archive:
        SAC.load(io.BytesIO(archive.read("manager.zip")))  # a plain SB3 zip
    with pytest.raises(ValueError, match="Unknown manager algorithm 'a2c'"):
        train_manager(root / "w", tmp_path / "m2", algo="a2c", **TINY)

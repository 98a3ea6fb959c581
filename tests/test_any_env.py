"""
Any env with several objectives (docs/ENVIRONMENTS.md): MO-Gymnasium envs through the adapter, envs with
per-term rewards in ``info``, a user's own env that meets the contract, three workers; tiny budgets.
"""

from __future__ import annotations

import json
import math
from typing import ClassVar

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

from hddpg_zoo.benchmark.settings import BenchmarkSettings
from sb3_hddpg.artifacts.limits import LimitError
from sb3_hddpg.artifacts.values import check_env_kwargs
from sb3_hddpg.baselines.random import RandomPolicy
from sb3_hddpg.envs import (
    EnvUnavailableError,
    InfoTermsEnv,
    MultiObjectiveEnv,
    Proximity,
    RewardTermsEnv,
    TermNormaliser,
    env_contract,
    proximity_of,
    state_layout_of,
)
from sb3_hddpg.envs.terms_env import parse_term_bounds, parse_terms, terms_env
from sb3_hddpg.evaluation import evaluate
from sb3_hddpg.hierarchy import Hierarchy
from sb3_hddpg.training import train_manager, train_workers
from tests.cli_runner import run_cli
from tests.helpers import TINY_CONFIG

TINY = {"timesteps": 200, "eval_freq": 0, "eval_episodes": 1}


# ------------------------------------------------------------------------ envs a user would write
class PointEnv(gym.Env):
    """A point on a line must be near a target (``near``), move little (``calm``), stay right of 0 (``right``)."""

    def __init__(self) -> None:
        self.observation_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x, self.target = self.np_random.uniform(-1, 1, 2)
        return np.array([self.x, self.target], np.float32), {}

    def _move(self, action) -> tuple[np.ndarray, dict[str, float]]:
        move = float(np.clip(action[0], -1, 1))
        self.x = float(np.clip(self.x + 0.1 * move, -1, 1))
        terms = {"near": -abs(self.x - self.target), "calm": -(move**2), "right": float(self.x > 0)}
        return np.array([self.x, self.target], np.float32), terms


class ThreeTermsEnv(PointEnv):
    """A user's own env meeting the contract natively: these few lines are all it takes."""

    reward_bounds: ClassVar[dict] = {"near": (-2.0, 0.0), "calm": (-1.0, 0.0), "right": (0.0, 1.0)}

    def __init__(self) -> None:
        super().__init__()
        self.normalise_terms = TermNormaliser(self.reward_bounds)

    def step(self, action):
        obs, terms = self._move(action)
        return obs, sum(self.normalise_terms(terms).values()), False, False, {"reward_terms": terms}


class InfoRewardsEnv(PointEnv):
    """An env that reports per-term rewards in ``info`` only (as MuJoCo's do): no contract of its own."""

    def step(self, action):
        obs, terms = self._move(action)
        return obs, terms["near"], False, False, {"reward_near": terms["near"], "reward_calm": terms["calm"]}


class UnboundedMOEnv(gym.Env):
    """An MO-Gymnasium-style env whose ``reward_space`` is unbounded (as MuJoCo's are)."""

    def __init__(self) -> None:
        self.observation_space = spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.reward_space = spaces.Box(-np.inf, np.inf, (2,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return np.zeros(1, np.float32), {}

    def step(self, action):
        a = float(action[0])
        return np.zeros(1, np.float32), np.array([3 * a, -(a**2)], np.float32), False, False, {}


def _register(env_id: str, cls: type) -> None:
    if env_id not in gym.registry:
        gym.register(env_id, entry_point=cls, max_episode_steps=20)


_register("test/ThreeTerms-v0", ThreeTermsEnv)
_register("test/InfoRewards-v0", InfoRewardsEnv)
_register("test/UnboundedMO-v0", UnboundedMOEnv)


@pytest.fixture()
def tiny(tmp_path):
    path = tmp_path / "tiny.yml"
    path.write_text(TINY_CONFIG)
    return path


# ------------------------------------------------------------------------ the contract
def test_the_snake_and_a_users_env_meet_the_contract_natively():
    snake = gym.make("hddpg/SnakeReach-v0")
    assert isinstance(env_contract(snake), RewardTermsEnv)
    assert list(env_contract(snake).reward_bounds) == ["goal", "avoid"]
    assert "joint_positions" in state_layout_of(snake)
    own = gym.make("test/ThreeTerms-v0")
    assert list(env_contract(own).reward_bounds) == ["near", "calm", "right"]
    # No declared layout: the whole observation is one component.
    assert dict(state_layout_of(own)) == {"state": slice(0, 2)}
    with pytest.raises(ValueError, match="declares its reward terms"):
        env_contract(gym.make("Pendulum-v1"))


def test_one_normaliser_and_its_episode_sums_agree():
    normalise = TermNormaliser({"a": (-2.0, 0.0), "b": (0.0, 4.0)})
    steps = [{"a": -2.0, "b": 1.0}, {"a": -0.5, "b": 4.0}, {"a": 0.0, "b": 0.0}]
    per_step = [normalise(s) for s in steps]
    assert per_step[0] == {"a": 0.0, "b": 0.25}
    for term in ("a", "b"):
        raw_sum = sum(s[term] for s in steps)
        assert normalise.episode_sum(term, raw_sum, len(steps)) == pytest.approx(
            sum(p[term] for p in per_step)
        )
    assert normalise.weighted_sum(steps[1], [("a", 2.0), ("b", 1.0)]) == pytest.approx(2 * 0.75 + 1.0)
    with pytest.raises(ValueError, match=r"low < high"):
        TermNormaliser({"a": (1.0, 1.0)})
    with pytest.raises(ValueError, match=r"finite"):
        TermNormaliser({"a": (0.0, math.inf)})


# ------------------------------------------------------------------------ MO-Gymnasium
def test_mo_gymnasium_env_through_the_adapter():
    env = gym.make("hddpg/MultiObjective-v0", env_id="mo-mountaincarcontinuous-v0", terms=["time", "fuel"])
    base = env.unwrapped
    assert isinstance(base, MultiObjectiveEnv)
    assert base.reward_bounds == {"time": (-1.0, 0.0), "fuel": (-1.0, 0.0)}  # from reward_space
    env.reset(seed=0)
    _, reward, _, _, info = env.step(np.array([0.5], np.float32))
    terms = info["reward_terms"]
    assert terms == {"time": -1.0, "fuel": pytest.approx(float(info["vector_reward"][1]))}
    assert reward == pytest.approx(sum(base.normalise_terms(terms).values()))
    # A worker's view: LinearReward with a one-hot weight gives the raw term.
    view = gym.make(
        "hddpg/MultiObjective-v0", env_id="mo-mountaincarcontinuous-v0", terms=["time", "fuel"], term="fuel"
    )
    view.reset(seed=0)
    _, reward, _, _, info = view.step(np.array([0.5], np.float32))
    assert reward == pytest.approx(info["reward_terms"]["fuel"]) and reward < 0
    assert list(info["reward_weights"]) == [0.0, 1.0]
    # Default names obj0..objN; a miscount is refused.
    assert terms_env("mo-mountaincarcontinuous-v0").terms == ("obj0", "obj1")
    with pytest.raises(ValueError, match="Expected 2 `terms`"):
        terms_env("mo-mountaincarcontinuous-v0", terms=["a", "b", "c"])


def test_unbounded_reward_space_is_estimated_loudly_and_recorded():
    with pytest.warns(UserWarning, match="ESTIMATED"):
        resolved = terms_env("test/UnboundedMO-v0", terms=["speed", "energy"])
    bounds = resolved.env_kwargs["term_bounds"]
    # The random rollout saw speed in about [-3, 3] and energy in about [-1, 0]; widened by the margin.
    assert bounds["speed"][0] < -2.5 and bounds["speed"][1] > 2.5
    assert bounds["energy"][0] < -0.9 and bounds["energy"][1] >= 0.0
    # Rebuilt from the recorded kwargs (as a manifest does): the same bounds, no new estimate.
    rebuilt = resolved.make()
    assert rebuilt.unwrapped.reward_bounds == {k: tuple(v) for k, v in bounds.items()}
    assert not rebuilt.unwrapped.estimated_bounds
    # User-given bounds win and need no estimate.
    given = terms_env(
        "test/UnboundedMO-v0", terms=["speed", "energy"], term_bounds={"speed": (-3, 3), "energy": (-1, 0)}
    )
    assert given.make().unwrapped.reward_bounds == {"speed": (-3.0, 3.0), "energy": (-1.0, 0.0)}


def test_snake_speaks_mo_gymnasium():
    from mo_gymnasium.wrappers import LinearReward

    env = gym.make("hddpg/SnakeMO-v0")
    base = env.unwrapped
    assert np.allclose(base.reward_space.low, [base.reward_bounds["goal"][0], base.reward_bounds["avoid"][0]])
    env.reset(seed=1)
    _, vector, _, _, info = env.step(env.action_space.sample())
    assert vector.shape == (2,) and np.allclose(
        vector, [info["reward_terms"]["goal"], info["reward_terms"]["avoid"]]
    )
    scalar = LinearReward(gym.make("hddpg/SnakeMO-v0"), weight=np.array([1.0, 0.0]))
    scalar.reset(seed=1)
    reward, info = scalar.step(np.zeros(6, np.float32))[1::3]
    assert reward == pytest.approx(info["reward_terms"]["goal"])
    # Our tools take it through the MO adapter too.
    assert terms_env("hddpg/SnakeMO-v0").env_id == "hddpg/SnakeMO-v0"  # it meets the contract natively


# ------------------------------------------------------------------------ info terms
def test_info_terms_env_through_the_adapter():
    resolved = terms_env(
        "test/InfoRewards-v0",
        terms=["reward_near", "reward_calm"],
        term_bounds=parse_term_bounds("reward_near=-2:0,reward_calm=-1:0"),
    )
    assert resolved.env_id == "hddpg/InfoTerms-v0" and resolved.terms == ("reward_near", "reward_calm")
    env = resolved.make()
    assert isinstance(env.unwrapped, InfoTermsEnv)
    env.reset(seed=0)
    _, reward, _, _, info = env.step(np.array([1.0], np.float32))
    assert info["reward_terms"] == {"reward_near": info["reward_near"], "reward_calm": -1.0}
    assert reward == pytest.approx(info["reward_terms"]["reward_near"] / 2 + 1 + 0.0)
    with pytest.raises(ValueError, match="term_bounds"):
        terms_env("test/InfoRewards-v0", terms=["reward_near"])
    with pytest.raises(ValueError, match="declares no reward terms"):
        terms_env("test/InfoRewards-v0")
    # Terms missing from the env's info are refused when the env is resolved, before any run folder exists.
    with pytest.raises(ValueError, match="reward_run") as caught:
        terms_env("test/InfoRewards-v0", terms=["reward_run"], term_bounds={"reward_run": (0, 1)})
    assert "\n" not in str(caught.value) and "reward_calm" in str(caught.value)


def test_an_info_terms_bundle_evaluates_and_packages_with_its_own_env(tmp_path, tiny):
    """An info-terms hierarchy: train-manager reads the env from the workers manifest, and the bundle is
    evaluated through the CLI with --env naming the env it adapts (a user's id: the opt-in)."""
    from types import SimpleNamespace

    from hddpg_zoo.benchmark.methods import final_test
    from sb3_hddpg.hierarchy.loading import load_policy
    from tests.cli_batch import run_one

    env = terms_env(
        "test/InfoRewards-v0",
        terms=["reward_near", "reward_calm"],
        term_bounds=parse_term_bounds("reward_near=-2:0,reward_calm=-1:0"),
        episode_steps=15,
    )
    train_workers(tmp_path / "w", config=tiny, seed=0, env=env, **TINY)
    # A user's own env id is opted in by naming it (as train-manager --env does); Gymnasium's own ids
    # (HalfCheetah-v5...) are read from the workers manifest without it.
    with pytest.raises(ValueError, match="allowed ids"):
        train_manager(tmp_path / "w", tmp_path / "x", config=tiny, seed=0, **TINY)
    train_manager(
        tmp_path / "w",
        tmp_path / "m",
        config=tiny,
        seed=0,
        env_id=env.env_id,
        env_kwargs=env.env_kwargs,
        **TINY,
    )
    bundle = tmp_path / "m" / "hierarchy.zip"
    args = ["--env", "test/InfoRewards-v0", "--terms", "reward_near,reward_calm"]
    args += ["--term-bounds", "reward_near=-2:0,reward_calm=-1:0", "--episode-steps", "15"]
    done = run_one(["evaluate", str(bundle), *args, "--episodes", "1", "--json", str(tmp_path / "e.json")])
    assert done["code"] == 0, done["stderr"]
    summary = json.loads((tmp_path / "e.json").read_text())["summary"]
    assert summary["mean_length"] == 15 and "mean_reward_calm_reward" in summary
    loaded = load_policy(bundle, allowed_env_ids=["test/InfoRewards-v0"])
    assert loaded.make_env().spec.kwargs["env_id"] == "test/InfoRewards-v0"  # the bundle rebuilds its env
    # The benchmark's final test (benchmark --env) loads it the same way, the adapted env allowed.
    from sb3_hddpg.episode_sets import DEVELOPMENT

    settings = SimpleNamespace(
        env={"env_id": env.env_id, "env_kwargs": env.env_kwargs},
        test_episodes=1,
        test_set=DEVELOPMENT,
        test_episode_set=DEVELOPMENT.describe(1),
    )
    assert final_test(bundle, settings)["test"]["mean_length"] == 15


def test_cli_parsers_name_the_bad_part():
    assert parse_terms("speed, energy") == ["speed", "energy"]
    assert parse_term_bounds("a=-1:2.5") == {"a": (-1.0, 2.5)}
    for text in ("a", "a=1", "a=x:1", "=0:1", "a=2:1"):
        with pytest.raises(ValueError, match=r"term_bounds|TERM=LOW:HIGH"):
            parse_term_bounds(text)
    with pytest.raises(ValueError, match="once"):
        parse_terms("a,a")


# ------------------------------------------------------------------------ safe loading
def test_adapted_ids_from_a_file_are_allow_listed():
    ok = check_env_kwargs(
        "hddpg/MultiObjective-v0",
        {"env_id": "mo-mountaincarcontinuous-v0", "terms": ["a", "b"], "term_bounds": {"a": [-1, 0]}},
        "f",
    )
    assert ok["term_bounds"] == {"a": [-1, 0]}
    with pytest.raises(LimitError, match="module prefix"):
        check_env_kwargs("hddpg/MultiObjective-v0", {"env_id": "os:Evil-v0"}, "f")
    # A registered id that is not MO-Gymnasium's: only when the user opts in.
    with pytest.raises(LimitError, match="allowed_env_ids"):
        check_env_kwargs("hddpg/InfoTerms-v0", {"env_id": "test/InfoRewards-v0"}, "f")
    assert check_env_kwargs(
        "hddpg/InfoTerms-v0", {"env_id": "test/InfoRewards-v0"}, "f", ["test/InfoRewards-v0"]
    )
    with pytest.raises(LimitError, match="term_bounds"):
        check_env_kwargs("hddpg/MultiObjective-v0", {"term_bounds": {"a": [[1]]}}, "f")


def test_a_run_on_an_env_whose_package_is_missing_is_read_but_not_made():
    """Its records can be read (a report needs no env); making it is one line naming the missing package."""
    if "test/PackageMissing-v0" not in gym.registry:
        gym.register("test/PackageMissing-v0", entry_point="hddpg_no_such_package.envs:Env")
    env = {"env_id": "test/PackageMissing-v0", "terms": ["fast", "safe"], "lanes_count": 4}
    assert check_env_kwargs("hddpg/MultiObjective-v0", env, "f", trusted=True)["lanes_count"] == 4
    # Still no file names, unplain strings or unbounded numbers, with no constructor to check them against.
    for bad in ({"config_path": "x"}, {"name": "../x"}, {"n": 1e300}, {"not an identifier": 1}):
        with pytest.raises(LimitError):
            check_env_kwargs("hddpg/MultiObjective-v0", {**env, **bad}, "f", trusted=True)
    settings = BenchmarkSettings(
        env={"env_id": "hddpg/MultiObjective-v0", "env_kwargs": env, "terms": ["fast", "safe"]},
        methods=["hddpg", "dqn"],
        worker_timesteps=100,
    )
    assert settings.flat_budget == settings.manager_env_steps + 200
    assert settings.terms_env is not None
    # With the workers' budgets from the config, which needs the env: read all the same, budgets unknown.
    from_config = BenchmarkSettings(env=settings.env, methods=["hddpg", "dqn"])
    with pytest.raises(EnvUnavailableError, match="hddpg_no_such_package"):
        _ = from_config.flat_budget
    with pytest.raises(EnvUnavailableError, match=r"cannot be made here.*hddpg_no_such_package"):
        gym.make("hddpg/MultiObjective-v0", **env)


# ------------------------------------------------------------------------ end to end
def test_mo_gymnasium_end_to_end_and_load_in_a_fresh_process(tmp_path, tiny):
    """Workers -> manager -> bundle (API, tiny), then a fresh process loads the bundle and evaluates it."""
    env = terms_env("mo-mountaincarcontinuous-v0", terms=["time", "fuel"], episode_steps=50)
    manifest = train_workers(tmp_path / "w", config=tiny, seed=1, env=env, **TINY).manifest
    assert manifest["shared_env"]["env_kwargs"]["env_id"] == "mo-mountaincarcontinuous-v0"
    assert {n: e["env_kwargs"]["term"] for n, e in manifest["workers"].items()} == {
        "time": "time",
        "fuel": "fuel",
    }
    hierarchy = train_manager(tmp_path / "w", tmp_path / "m", config=tiny, seed=1, **TINY).hierarchy
    assert hierarchy.env_id == "hddpg/MultiObjective-v0"
    out = tmp_path / "eval.json"
    run_cli("evaluate", tmp_path / "m" / "hierarchy.zip", "--episodes", "2", "--json", out, check=True)
    summary = json.loads(out.read_text())["summary"]
    assert summary["mean_length"] == 50
    assert summary["mean_time_reward"] == pytest.approx(-50.0)  # -1 per step until the (unreached) goal
    assert -50.0 <= summary["mean_fuel_reward"] <= 0.0
    assert summary["mean_reach_reward"] == pytest.approx(
        100 + summary["mean_time_reward"] + summary["mean_fuel_reward"]
    )
    assert set(summary["selection_rate"]) <= {"time", "fuel"}
    assert "goal_touch_rate" not in summary and "min_clearance" not in summary  # not reported by this env


def test_three_workers_on_a_users_own_env(tmp_path, tiny):
    env = terms_env("test/ThreeTerms-v0")
    assert env.terms == ("near", "calm", "right")
    manifest = train_workers(tmp_path / "w", config=tiny, seed=2, env=env, **TINY).manifest
    assert list(manifest["workers"]) == ["near", "calm", "right"]
    assert manifest["workers"]["right"]["reward_bounds"] == [0.0, 1.0]
    # The workers' manifest names a user's id: the user opts in by naming the env (the CLI's --env).
    with pytest.raises(ValueError, match="allowed_env_ids"):
        train_manager(tmp_path / "w", tmp_path / "m", config=tiny, **TINY)
    hierarchy = train_manager(
        tmp_path / "w",
        tmp_path / "m",
        config=tiny,
        seed=2,
        preferences={"near": 2.0},
        env_id="test/ThreeTerms-v0",
        **TINY,
    ).hierarchy
    assert sorted(hierarchy.names) == ["calm", "near", "right"] and hierarchy.env_id == "test/ThreeTerms-v0"
    # A user's own id loads once they opt in to it.
    with pytest.raises(ValueError, match="allowed_env_ids"):
        Hierarchy.load(tmp_path / "m" / "hierarchy.zip")
    loaded = Hierarchy.load(tmp_path / "m" / "hierarchy.zip", allowed_env_ids=["test/ThreeTerms-v0"])
    result = evaluate(loaded, gym.make("test/ThreeTerms-v0"), n_episodes=2).summary()
    assert {"mean_near_reward", "mean_calm_reward", "mean_right_reward"} <= set(result)
    assert set(result["selection_rate"]) <= {"near", "calm", "right"}
    assert sum(result["selection_rate"].values()) == pytest.approx(1.0)
    assert loaded.reward_spec == {"near": 2.0, "calm": 1.0, "right": 1.0}


def test_cli_trains_workers_on_an_mo_gymnasium_env(tmp_path, tiny):
    done = run_cli(
        "train-workers",
        "--no-progress",
        "--env",
        "mo-mountaincarcontinuous-v0",
        "--terms",
        "time,fuel",
        "--episode-steps",
        "30",
        "--workers",
        "fuel",
        "--config",
        tiny,
        "--timesteps",
        "100",
        "--eval-freq",
        "0",
        "--out",
        tmp_path / "w",
        check=True,
    )
    assert "fuel" in done.stdout
    manifest = json.loads((tmp_path / "w" / "workers" / "manifest.json").read_text())
    assert list(manifest["workers"]) == ["fuel"]
    assert manifest["shared_env"] == {
        "env_id": "hddpg/MultiObjective-v0",
        "env_kwargs": {
            "env_id": "mo-mountaincarcontinuous-v0",
            "terms": ["time", "fuel"],
            "episode_steps": 30,
        },
    }


@pytest.mark.slow
def test_mujoco_half_cheetah_with_estimated_bounds_end_to_end(tmp_path, tiny):
    """mo-halfcheetah-v5 (unbounded reward_space): estimated bounds recorded, and the bundle rebuilds them."""
    pytest.importorskip("mujoco")
    with pytest.warns(UserWarning, match="ESTIMATED"):
        env = terms_env("mo-halfcheetah-v5", terms=["speed", "energy"], episode_steps=50)
    bounds = env.env_kwargs["term_bounds"]
    train_workers(tmp_path / "w", config=tiny, seed=0, env=env, **TINY)
    train_manager(tmp_path / "w", tmp_path / "m", config=tiny, seed=0, **TINY)
    loaded = Hierarchy.load(tmp_path / "m" / "hierarchy.zip")
    assert loaded.env_kwargs["term_bounds"] == bounds
    rebuilt = gym.make(loaded.env_id, **loaded.env_kwargs)
    assert rebuilt.unwrapped.reward_bounds == {k: tuple(v) for k, v in bounds.items()}
    summary = evaluate(loaded, rebuilt, n_episodes=1).summary()
    assert summary["mean_length"] == 50 and {"mean_speed_reward", "mean_energy_reward"} <= set(summary)


def test_selection_timeline_of_an_env_without_the_snakes_panels(tmp_path):
    """plot-selection's figure on any env: its reward terms stand where the snake's clearance would."""
    from hddpg_zoo.media.figures import plot_selection_timeline
    from sb3_hddpg.media.trace import trace_episodes

    env = gym.make("test/ThreeTerms-v0")
    records, _ = trace_episodes(RandomPolicy(env.action_space, seed=0), env, n_episodes=2, seed=0)
    assert len(records) == 40 and set(records[0].reward_terms) == {"near", "calm", "right"}
    assert all(math.isnan(r.min_clearance) for r in records)
    for record, name in zip(records, ["near", "calm", "right"] * 14):  # as a hierarchy would report
        record.selected = name
    path = plot_selection_timeline(records, tmp_path / "s.png", names=["near", "calm", "right"])
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# ------------------------------------------------------------------------ tune --env
#: Trials as small as tests/test_tuning's: small nets, a small buffer.
TUNE_FIXED = {"net_arch": "small", "buffer_size": 10_000, "batch_size": 32}


def _tune_once(tmp_path, target):
    from hddpg_zoo.study_storage import default_storage_url
    from hddpg_zoo.tuning import StudySettings, tune

    settings = StudySettings(
        storage=default_storage_url(tmp_path),
        study_name=target.name,
        n_trials=1,
        pruner="none",
        seed=0,
        fixed_params=TUNE_FIXED,
    )
    study = tune(target, settings, tmp_path)
    assert [t.state.name for t in study.trials] == ["COMPLETE"]
    return study


def test_a_worker_reads_its_own_block_before_its_envs(tmp_path, tiny):
    """An easy skill can get a smaller budget than its siblings: the block ``<env id>/<term>`` is its own."""
    from sb3_hddpg.training.workers import worker_hyperparams

    tiny.write_text(TINY_CONFIG + "test/ThreeTerms-v0/calm:\n  <<: *tiny\n  n_timesteps: 120\n")
    env = terms_env("test/ThreeTerms-v0")
    blocks = worker_hyperparams(list(env.terms), tiny, env)
    assert {name: block.n_timesteps for name, block in blocks.items()} == {
        "near": 150,
        "calm": 120,
        "right": 150,
    }
    manifest = train_workers(
        tmp_path / "w", ["near", "calm"], tiny, env=env, eval_freq=0, eval_episodes=1
    ).manifest
    assert {name: entry["timesteps_trained"] for name, entry in manifest["workers"].items()} == {
        "near": 150,
        "calm": 120,
    }
    # The manifest records the block the worker read.
    assert manifest["workers"]["calm"]["config"]["block"]["n_timesteps"] == 120


def test_tune_a_worker_and_a_flat_agent_on_other_envs(tmp_path, tiny):
    from hddpg_zoo.tuning import TuningTarget

    mountain_car = terms_env("mo-mountaincarcontinuous-v0", terms=["time", "fuel"], episode_steps=30)
    budget = {"config": str(tiny), "timesteps": 100, "n_evaluations": 1, "eval_episodes": 1}
    worker = TuningTarget(level="worker", worker="time", env=mountain_car, **budget)
    # A worker's tuned block is its own, read by train-workers before the env's.
    assert worker.name == "worker-time" and worker.block_key == "mo-mountaincarcontinuous-v0/time"
    study = _tune_once(tmp_path / "worker", worker)
    # The trial learned on the `time` term's view: -1 per step, 30 steps (the flag is out of reach).
    assert study.best_value == pytest.approx(-30.0)
    assert study.user_attrs["target"]["env"]["env_kwargs"]["env_id"] == "mo-mountaincarcontinuous-v0"
    with pytest.raises(ValueError, match=r"among \['time', 'fuel'\]"):
        TuningTarget(level="worker", worker="goal", env=mountain_car)

    info = terms_env(
        "test/InfoRewards-v0",
        terms=["reward_near", "reward_calm"],
        term_bounds={"reward_near": (-2, 0), "reward_calm": (-1, 0)},
    )
    flat = TuningTarget(level="flat", env=info, **budget)
    assert flat.block_key == "test/InfoRewards-v0"
    value = _tune_once(tmp_path / "flat", flat).best_value
    # The flat agent's reward is the normalised sum of both terms: each in [0, 1] per step, 20 steps.
    assert 0.0 < value <= 40.0


def test_tune_the_manager_over_workers_of_another_env(tmp_path, tiny):
    from hddpg_zoo.tuning import TuningTarget

    env = terms_env("mo-mountaincarcontinuous-v0", terms=["time", "fuel"], episode_steps=30)
    train_workers(tmp_path / "w", config=tiny, seed=0, env=env, timesteps=100, eval_freq=0, eval_episodes=1)
    budget = {"config": str(tiny), "timesteps": 100, "n_evaluations": 1, "eval_episodes": 1}
    # No env given: the manager acts in the shared env the workers' manifest records (as train-manager).
    target = TuningTarget(level="manager", workers_dir=str(tmp_path / "w"), **budget)
    target.check()
    value = _tune_once(tmp_path / "m", target).best_value
    # Manager reward: normalised time (0 until the flag) + normalised fuel (in [0, 1]) per step, 30 steps.
    assert 0.0 < value <= 30.0
    ham = TuningTarget(level="ham", workers_dir=str(tmp_path / "w"))
    with pytest.raises(ValueError, match="snake arm only"):
        ham.check()


def test_cli_tune_env_options(tmp_path, tiny):
    from tests.cli_batch import run_batch

    env_args = ["--env", "mo-mountaincarcontinuous-v0", "--terms", "time,fuel", "--episode-steps", "30"]
    fix = [arg for name, value in TUNE_FIXED.items() for arg in ("--fix", f"{name}={value}")]
    small = ["--n-trials", "1", "--timesteps", "100", "--n-evaluations", "1", "--eval-episodes", "1"]
    saved = tmp_path / "best.yml"
    ok, bad_worker, ham, lone_terms = run_batch(
        [
            [
                "tune",
                "--level",
                "flat",
                *env_args,
                "--config",
                str(tiny),
                *small,
                *fix,
                "--out",
                str(tmp_path / "t"),
                "--save-config",
                str(saved),
            ],
            ["tune", "--level", "worker", "--worker", "goal", *env_args, "--out", str(tmp_path / "b")],
            ["tune", "--level", "ham", "--workers", str(tmp_path), *env_args, "--out", str(tmp_path / "h")],
            ["tune", "--level", "flat", "--terms", "a,b", "--out", str(tmp_path / "l")],
        ]
    )
    assert ok.returncode == 0, ok.stderr
    # The best block is keyed by the adapted env, where train-flat --env reads it.
    assert "mo-mountaincarcontinuous-v0" in yaml_keys(saved)
    for result, option in ((bad_worker, "--worker"), (ham, "--env"), (lone_terms, "--env")):
        assert result.returncode == 2 and option in result.stderr and "Traceback" not in result.stderr
    assert "['time', 'fuel']" in bad_worker.stderr and "snake arm only" in ham.stderr


def yaml_keys(path) -> list[str]:
    import yaml

    return list(yaml.safe_load(path.read_text()))


# ------------------------------------------------------------------------ record on other envs
@pytest.fixture(scope="module")
def mountain_car_bundle(tmp_path_factory):
    """A tiny hierarchy over two workers of mo-mountaincarcontinuous-v0 (30-step episodes)."""
    folder = tmp_path_factory.mktemp("mc")
    config = folder / "tiny.yml"
    config.write_text(TINY_CONFIG)
    env = terms_env("mo-mountaincarcontinuous-v0", terms=["time", "fuel"], episode_steps=30)
    train_workers(folder / "w", config=config, seed=0, env=env, timesteps=100, eval_freq=0, eval_episodes=1)
    train_manager(
        folder / "w", folder / "m", config=config, seed=0, timesteps=100, eval_freq=0, eval_episodes=1
    )
    return folder / "m" / "hierarchy.zip"


def test_record_a_hierarchy_on_an_mo_gymnasium_env(mountain_car_bundle, tmp_path):
    import imageio.v3 as iio

    from tests.cli_batch import run_one

    out = tmp_path / "mc.gif"
    done = run_one(["record", str(mountain_car_bundle), "--out", str(out), "--fps", "20"])
    assert done["code"] == 0, done["stderr"]
    frames = iio.imread(out, index=None)
    # One frame per step of the 30-step episode: the env's own 600 x 400 render, padded to multiples of
    # 16, with the 80-pixel panel under it.
    assert frames.shape[:3] == (30, 400 + 80, 608)
    assert "time -30.0" in done["stdout"] and "goal touch" not in done["stdout"]
    # The mountain car's own scene (a white sky), not a blank frame.
    assert (frames[0, :400, :600] == 255).mean() > 0.5 and frames[0, :400, :600].std() > 10


def test_package_an_mo_bundle_reports_the_envs_own_metrics(mountain_car_bundle, tmp_path):
    from hddpg_zoo.packaging import package_policy
    from sb3_hddpg.hierarchy.loading import load_policy

    loaded = load_policy(mountain_car_bundle)
    done = package_policy(loaded, mountain_car_bundle, tmp_path / "pkg", n_eval_episodes=1, video_steps=5)
    card = (tmp_path / "pkg" / "README.md").read_text()
    assert "time reward" in card and "fuel reward" in card and "goal-touch" not in card
    assert "goal_touch_rate" not in done.results["metrics"]


def test_record_refuses_an_env_that_cannot_render(tmp_path, tiny):
    import functools

    from hddpg_zoo.media import make_recording_env
    from tests.cli_batch import run_one

    with pytest.raises(ValueError, match=r"test/ThreeTerms-v0 cannot render frames.*'rgb_array'"):
        make_recording_env(functools.partial(gym.make, "test/ThreeTerms-v0"), "test/ThreeTerms-v0")
    train_workers(tmp_path / "w", config=tiny, env=terms_env("test/ThreeTerms-v0"), workers=["near"], **TINY)
    worker = tmp_path / "w" / "workers" / "near.zip"
    done = run_one(["record", str(worker), "--env", "test/ThreeTerms-v0", "--out", str(tmp_path / "x.gif")])
    assert done["code"] == 2 and "cannot render frames" in done["stderr"]
    assert "Traceback" not in done["stderr"] and not (tmp_path / "x.gif").exists()


# ------------------------------------------------------------------------ the optional proximity capability
class WalledPointEnv(ThreeTermsEnv):
    """A user's env that declares proximity: the wall at x = -1 is its obstacle, the target its goal."""

    proximity = Proximity(sensor_range=1.0, touch_radius=0.05)

    def step(self, action):
        obs, reward, terminated, truncated, info = super().step(action)
        info |= {"min_clearance": self.x + 1.0, "distance_to_goal": abs(self.x - self.target)}
        return obs, reward, terminated, truncated, info


_register("test/WalledPoint-v0", WalledPointEnv)


def test_proximity_is_declared_not_guessed():
    from sb3_hddpg.evaluation import clearance_bands

    snake = gym.make("hddpg/SnakeReach-v0", sensor_range=0.4)
    assert proximity_of(snake) == Proximity(sensor_range=0.4, touch_radius=0.1)  # through gym.make's wrappers
    assert clearance_bands(snake, None, None) == (0.2, 0.4)
    walled = gym.make("test/WalledPoint-v0")
    assert clearance_bands(walled, None, None) == (0.5, 1.0)
    result = evaluate(RandomPolicy(walled.action_space, seed=0), walled, n_episodes=2)
    assert (result.near_clearance, result.clear_clearance) == (0.5, 1.0)
    assert 0.0 <= result.summary()["min_clearance"] <= 2.0
    # No proximity declared: no bands, and a band asked for is refused rather than counting nothing.
    mountain_car = terms_env("mo-mountaincarcontinuous-v0").make()
    assert proximity_of(mountain_car) is None and proximity_of(gym.make("test/ThreeTerms-v0")) is None
    assert clearance_bands(mountain_car, None, None) == (None, None)
    with pytest.raises(ValueError, match=r"`near_clearance` is not available for this env: 'hddpg/MultiObj"):
        clearance_bands(mountain_car, 0.1, None)
    with pytest.raises(ValueError, match="sensor_range"):
        Proximity(sensor_range=0.0)


def test_state_dependence_and_selection_figure_say_not_available(mountain_car_bundle, tmp_path):
    from sb3_hddpg.evaluation import state_dependence
    from tests.cli_batch import run_one

    loaded = Hierarchy.load(mountain_car_bundle)
    summary = evaluate(loaded, gym.make(loaded.env_id, **loaded.env_kwargs), n_episodes=1).summary()
    assert set(summary["selection_rate"]) <= {"time", "fuel"}
    assert summary["selections_near"] == dict.fromkeys(summary["selection_rate"], 0)
    assert state_dependence(summary, "fuel") is None  # not a ratio of empty bands
    shown = run_one(["evaluate", str(mountain_car_bundle), "--episodes", "1", "--state-worker", "fuel"])
    assert shown["code"] == 0 and "not available" in shown["stdout"] and "share ratio" not in shown["stdout"]
    refused = run_one(["evaluate", str(mountain_car_bundle), "--episodes", "1", "--near-clearance", "0.1"])
    assert refused["code"] == 2 and "not available for this env" in refused["stderr"]
    out = tmp_path / "s.png"
    plotted = run_one(["plot-selection", str(mountain_car_bundle), "--out", str(out)])
    assert plotted["code"] == 0, plotted["stderr"]
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and "not available" in plotted["stdout"]


# ------------------------------------------------------------------------ benchmark --env
def test_benchmark_on_an_mo_gymnasium_env(tmp_path):
    from hddpg_zoo.agent_settings import manager_option_steps
    from tests.cli_batch import run_batch

    env_args = ["--env", "mo-mountaincarcontinuous-v0", "--terms", "time,fuel", "--episode-steps", "30"]
    tiny = ["--seeds", "1", "--timesteps", "100", "--worker-timesteps", "50", "--eval-freq", "50"]
    tiny += ["--eval-episodes", "1", "--test-episodes", "1"]
    out = tmp_path / "bench"
    done, ham = run_batch(
        [
            ["benchmark", *env_args, *tiny, "--out", str(out)],
            ["benchmark", *env_args, "--methods", "hddpg,ham", "--out", str(tmp_path / "h")],
        ]
    )
    assert done.returncode == 0, done.stdout + done.stderr
    results = json.loads((out / "results.json").read_text())
    assert set(results["methods"]) == {"hddpg", "ddpg"}  # the default on another env
    assert results["settings"]["env"]["env_kwargs"]["env_id"] == "mo-mountaincarcontinuous-v0"
    assert results["methods"]["hddpg"]["worker_timesteps"] == 100  # two workers of 50 steps
    # As many env steps as the hierarchy: the manager's 100 decisions of option_steps env steps + 2 x 50.
    assert results["methods"]["ddpg"]["own_timesteps"] == 100 * manager_option_steps() + 100
    for entry in results["methods"].values():
        stats = entry["stats"]
        # Normalised time (0 short of the flag) + normalised fuel (in [0, 1]) per step, 30 steps.
        assert 0.0 < stats["mean_reach_reward"]["mean"] <= 30.0
        assert "goal_touch_rate" not in stats and "success_rate" not in stats
    assert set(results["methods"]["hddpg"]["selection_rate"]) <= {"time", "fuel"}
    assert "hddpg vs ddpg" not in results["comparisons"]  # one seed: no paired interval to report
    assert "['time', 'fuel']" in results["metric"]
    page = (out / "results.md").read_text()
    assert "| hddpg | 1 |" in page
    # The env's own words: its return and each term's part, none of the snake arm's columns.
    assert "| norm. return (test) | IQM | time part | fuel part | saturated actions |" in page
    assert "goal part" not in page and "reach reward" not in page and "min clearance" not in page
    assert ham.returncode == 2 and "snake arm only" in ham.stderr and "Traceback" not in ham.stderr


def test_the_front_scenario_on_an_mo_gymnasium_env(tmp_path):
    from tests.cli_batch import run_batch

    env_args = ["--env", "mo-mountaincarcontinuous-v0", "--terms", "time,fuel", "--episode-steps", "30"]
    tiny = ["--seeds", "2", "--timesteps", "40", "--worker-timesteps", "50", "--eval-freq", "40"]
    tiny += ["--eval-episodes", "1", "--test-episodes", "1"]
    # The conditioned manager alone: the snake's front tests train the per-preference references.
    tiny += ["--no-front-per-preference"]
    out = tmp_path / "front"
    export = tmp_path / "models"
    done, exported = run_batch(
        [
            ["benchmark", *env_args, "--scenario", "front", *tiny, "--out", str(out)],
            ["export-models", str(out), str(export)],
        ]
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert exported.returncode == 0, exported.stderr
    index = json.loads((export / "index.json").read_text())
    conditioned = [e for e in index if e["method"] == "hddpg-conditioned"]
    assert [e["seed"] for e in conditioned] == [0, 1]
    assert list(conditioned[0]["manager_preferences"]["points"][0]) == ["time", "fuel"]
    front = json.loads((out / "results.json").read_text())["front"]
    # No rule on this env: the managers, each worker alone and GPI over them, in the terms and the returns plane.
    assert front["members"] == ["conditioned", "time", "fuel", "gpi"]
    assert not list((out / "seed-0" / "hddpg-front").glob("manager-*"))
    assert front["manager"]["per_preference"] is False
    assert list(front["planes"]) == ["terms", "returns"]
    record = json.loads((out / "records" / "hddpg-front" / "seed-0.json").read_text())
    assert record["rule"] is None and record["rule_thresholds"] == []
    bounds = record["planes"]["returns"]
    assert [key for key, _ in bounds] == ["time_return", "fuel_return"]
    # The returns plane's reference: each term's least return over a 30-step episode.
    import mo_gymnasium

    low = mo_gymnasium.make("mo-mountaincarcontinuous-v0").unwrapped.reward_space.low
    assert record["references"]["returns"] == pytest.approx([30 * float(v) for v in low])
    points = record["front"]["conditioned"]["points"]
    assert len(points) == 7 and all(-30.0 <= p["time_return"] <= 0.0 for p in points)
    assert set(front["comparisons"]) == {
        *(f"conditioned vs {m}" for m in ("time", "fuel", "gpi")),
        "gpi vs time",
        "gpi vs fuel",
    }
    assert [e["seed"] for e in index if e["method"] == "hddpg-gpi"] == [0, 1]
    assert set(front["comparisons"]["conditioned vs time"]["planes"]) == {"terms", "returns"}
    assert (out / "fronts.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    page = (out / "results.md").read_text()
    assert "hypervolume, returns plane (time return, fuel return)" in page
    assert "The front's managers (conditioned only)" in page
    # How often they decide: the DDPG manager block's options, as the bundles hold them.
    from sb3_hddpg import Hierarchy

    bundle = out / "seed-0" / "hddpg-front" / "conditioned" / "hierarchy.zip"
    options = Hierarchy.load(bundle).config.option_steps
    assert front["manager"]["option_steps"] == options
    assert f"deciding every {options} env step" in page

"""The state-dependence figure: a hierarchy with fake managers on the real snake env."""

from __future__ import annotations

import json
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from sb3_hddpg.evaluation import clearance_bands, evaluate, state_dependence
from sb3_hddpg.hierarchy.hierarchy import Hierarchy, SelectionConfig
from tests.helpers import ConstantWorker

ENV_ID = "hddpg/SnakeReach-v0"


class FakeManager:
    """
    A manager whose choice is written by hand: ``choose(obs) -> "goal" | "avoid"``, output as the manager
    action that argmax selection maps to that worker.
    """

    def __init__(self, choose: Any) -> None:
        self.choose = choose

    def predict(
        self, observation: np.ndarray, state: Any = None, episode_start: Any = None, deterministic=True
    ):
        return np.array([1.0, -1.0] if self.choose(observation) == "goal" else [-1.0, 1.0], np.float32), None


def hierarchy(choose: Any, env: gym.Env) -> Hierarchy:
    # Random-looking but fixed joint commands, so that the arm sweeps through obstacles and free space.
    rng = np.random.default_rng(0)
    n = env.action_space.shape[0]
    workers = {
        "goal": ConstantWorker(rng.uniform(-1, 1, n)),
        "avoid": ConstantWorker(rng.uniform(-1, 1, n)),
    }
    config = SelectionConfig(preferences={"goal": 1.0, "avoid": 1.0}, selection="argmax", floor=0.0)
    return Hierarchy(FakeManager(choose), workers, config, env_id=ENV_ID)


def nearest_clearance(env: gym.Env, observation: np.ndarray) -> float:
    """The nearest obstacle's clearance as the observation shows it (clipped to the sensor range)."""
    unwrapped = env.unwrapped
    return float(
        observation[unwrapped.state_layout["joint_obstacle_distances"]].min() * unwrapped.sensor_range
    )


def test_a_manager_that_avoids_only_near_obstacles_has_a_large_ratio():
    env = gym.make(ENV_ID)
    near, clear = clearance_bands(env, None, None)
    assert (near, clear) == pytest.approx((0.5 * env.unwrapped.sensor_range, env.unwrapped.sensor_range))
    steps = {"n": 0}

    def choose(observation: np.ndarray) -> str:
        # Avoid near an obstacle; elsewhere goal, except every tenth decision (a small fixed rate).
        steps["n"] += 1
        if nearest_clearance(env, observation) <= 0.6 * env.unwrapped.sensor_range:
            return "avoid"
        return "avoid" if steps["n"] % 10 == 0 else "goal"

    summary = evaluate(hierarchy(choose, env), env, n_episodes=4, seed=3).summary()
    figure = state_dependence(summary)
    env.close()
    assert figure is not None and figure["worker"] == "avoid"
    assert figure["near_choices"] > 20 and figure["clear_choices"] > 50, figure
    # Every choice made within half the sensor range was the avoid worker; in free space about one in ten.
    assert figure["near_share"] == 1.0
    assert 0.03 < figure["clear_share"] < 0.2
    assert figure["ratio"] == pytest.approx(1.0 / figure["clear_share"]) and figure["ratio"] > 5
    # The bands partition no more choices than were made.
    assert figure["near_choices"] + figure["clear_choices"] <= summary["episodes"] * summary["mean_length"]


def test_a_fixed_mix_gives_a_ratio_near_one():
    env = gym.make(ENV_ID)
    rng = np.random.default_rng(1)
    summary = evaluate(
        hierarchy(lambda observation: "avoid" if rng.random() < 0.4 else "goal", env),
        env,
        n_episodes=4,
        seed=3,
    ).summary()
    figure = state_dependence(summary)
    env.close()
    assert figure is not None and figure["near_choices"] > 20
    assert figure["near_share"] == pytest.approx(0.4, abs=0.15)
    assert figure["clear_share"] == pytest.approx(0.4, abs=0.1)
    assert 0.6 < figure["ratio"] < 1.6
    # The generic form: the goal worker's figure is the complement's.
    goal = state_dependence(summary, worker="goal")
    assert goal["near_share"] == pytest.approx(1.0 - figure["near_share"])
    # Every contact step is counted once, under the worker that acted in it (these sweeping workers collide).
    contacts = summary["collisions_by_worker"]
    assert set(contacts) == {"goal", "avoid"} and summary["collisions_per_episode"] > 0
    assert sum(contacts.values()) == pytest.approx(summary["collisions_per_episode"])


def test_the_figure_is_absent_without_worker_choices_and_bands_are_checked():
    env = gym.make(ENV_ID)
    flat = evaluate(ConstantWorker(np.zeros(env.action_space.shape)), env, n_episodes=1).summary()
    assert state_dependence(flat) is None  # a flat policy reports no worker choices
    with pytest.raises(ValueError, match="near_clearance"):
        clearance_bands(env, -0.1, None)
    with pytest.raises(ValueError, match=r"near_clearance.*<=.*clear_clearance"):
        clearance_bands(env, 0.5, None)  # beyond the sensor range, where "none in range" starts
    env.close()


def test_evaluate_reports_the_figure_for_a_bundle(tmp_path):
    from stable_baselines3 import DDPG

    from sb3_hddpg.hierarchy import WorkerSelectionWrapper
    from tests.cli_batch import run_batch

    env = gym.make(ENV_ID)

    def ddpg(env: gym.Env, seed: int) -> DDPG:
        return DDPG("MlpPolicy", env, policy_kwargs={"net_arch": [16]}, seed=seed, device="cpu")

    workers = {"goal": ddpg(env, 1), "avoid": ddpg(env, 2)}
    config = SelectionConfig(preferences={"goal": 1.0, "avoid": 1.0}, selection="sample")
    manager = ddpg(WorkerSelectionWrapper(env, workers, **config.wrapper_kwargs()), 3)
    bundle = tmp_path / "hierarchy.zip"
    Hierarchy(manager, workers, config).save(bundle)
    env.close()
    report, bad = run_batch(
        [
            ["evaluate", str(bundle), "--episodes", "2", "--json", str(tmp_path / "eval.json")],
            ["evaluate", str(bundle), "--episodes", "1", "--near-clearance", "-1"],
        ]
    )
    assert report.returncode == 0, report.stderr
    written = json.loads((tmp_path / "eval.json").read_text())
    figure = written["state_dependence"]
    assert figure == state_dependence(written["summary"]) and figure["worker"] == "avoid"
    assert figure["near_choices"] + figure["clear_choices"] <= 2 * 200
    assert "avoid share ratio near / none in range" in report.stdout
    assert "selections_near" not in report.stdout  # counts behind the rows, not rows of their own
    assert bad.returncode == 2 and "near_clearance" in bad.stderr and "Traceback" not in bad.stderr

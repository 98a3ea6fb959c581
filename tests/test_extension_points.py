"""The extension points of docs/DESIGN.md through the real code paths: a new selection mode, a new benchmark method."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from hddpg_zoo.benchmark import (
    METHOD_REGISTRY,
    BenchmarkSettings,
    Method,
    Task,
    compute_results,
    plan_tasks,
    read_record,
    register_method,
    run_task,
)
from sb3_hddpg.baselines.random import RandomPolicy
from sb3_hddpg.evaluation import EVAL_SEED_BASE, evaluate
from sb3_hddpg.hierarchy import WorkerSelectionWrapper
from sb3_hddpg.hierarchy.hierarchy import Hierarchy
from sb3_hddpg.hierarchy.selection import (
    SELECTORS,
    SelectionConfig,
    Selector,
    check_selection_settings,
    get_selector,
    register_selector,
)
from tests.helpers import ActionRecorder, ConstantWorker

ENV_ID = "hddpg/SnakeReach-v0"
GOAL_ACTION = np.full(6, 0.5, np.float32)
AVOID_ACTION = np.full(6, -0.25, np.float32)


class LeastSelector(Selector):
    """A contrarian mode: the least probable worker acts (the worked example of docs/DESIGN.md)."""

    name = "least"

    def choose(self, probabilities: Sequence[float], rng: np.random.Generator, deterministic: bool) -> int:
        return int(np.argmin(probabilities))


class FixedManager:
    """A manager that always outputs the same action, which favours the first worker."""

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        return np.array([1.0, -1.0], np.float32), None


@pytest.fixture
def least_mode() -> Iterator[str]:
    register_selector(LeastSelector)
    try:
        yield LeastSelector.name
    finally:
        SELECTORS.pop(LeastSelector.name)


def test_a_registered_selection_mode_drives_the_wrapper(least_mode):
    inner = ActionRecorder(gym.make(ENV_ID))
    workers = {"goal": ConstantWorker(GOAL_ACTION), "avoid": ConstantWorker(AVOID_ACTION)}
    env = WorkerSelectionWrapper(inner, workers, selection=least_mode)
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([1.0, -1.0], np.float32))
    # The manager favours goal, so the contrarian mode runs avoid, and only avoid.
    assert info["selection_probabilities"]["goal"] > 0.5
    assert info["selected_worker"] == "avoid"
    np.testing.assert_array_equal(inner.actions[-1], AVOID_ACTION)
    assert workers["goal"].calls == 0 and workers["avoid"].calls == 1


def test_a_registered_selection_mode_drives_a_hierarchy_and_passes_the_file_checks(least_mode):
    workers = {"goal": ConstantWorker(GOAL_ACTION), "avoid": ConstantWorker(AVOID_ACTION)}
    config = SelectionConfig(preferences={"goal": 1.0, "avoid": 1.0}, selection=least_mode)
    hierarchy = Hierarchy(FixedManager(), workers, config, env_id=ENV_ID)
    obs, _ = gym.make(ENV_ID).reset(seed=0)
    action, _ = hierarchy.predict(obs, deterministic=True)
    np.testing.assert_array_equal(action, AVOID_ACTION)
    assert hierarchy.last_selection == "avoid"
    # A bundle's manifest naming the mode is accepted while it is registered, refused by name otherwise.
    assert check_selection_settings({"selection": least_mode}, ["goal", "avoid"], "m")["selection"] == "least"


def test_unregistered_and_duplicate_modes_are_refused_by_name():
    with pytest.raises(
        ValueError, match=r"one of \['sample', 'argmax', 'mix', 'discrete'\], actually: 'least'"
    ):
        get_selector("least")
    with pytest.raises(ValueError, match="'sample' is already registered"):

        @register_selector
        class AnotherSample(Selector):
            name = "sample"

    with pytest.raises(ValueError, match="least"):
        check_selection_settings({"selection": "least"}, ["goal", "avoid"], "m")
    assert list(SELECTORS) == ["sample", "argmax", "mix", "discrete"]


def run_random(task: Task, settings: BenchmarkSettings, folder: Path) -> dict[str, Any]:
    """A benchmark method that does not learn: uniform random actions, one curve point and the test."""
    env = gym.make(ENV_ID)
    try:
        policy = RandomPolicy(env.action_space, seed=task.seed)  # type: ignore[arg-type]
        curve = evaluate(policy, env, n_episodes=settings.eval_episodes, seed=EVAL_SEED_BASE).summary()
        test = evaluate(policy, env, n_episodes=settings.test_episodes, seed=EVAL_SEED_BASE + 1).summary()
    finally:
        env.close()
    return {"worker_timesteps": 0, "history": [{"timesteps": 0, "total_timesteps": 0, **curve}], "test": test}


def test_a_registered_benchmark_method_is_planned_run_and_compared(tmp_path):
    register_method(Method("random", run_random, lambda settings: 0, colour="black", baseline=True))
    try:
        settings = BenchmarkSettings(methods=["random"], seeds=[3], eval_episodes=1, test_episodes=1)
        tasks = plan_tasks(settings)
        assert [t.label for t in tasks] == ["random/seed-3"]  # needs no workers: none planned
        record = run_task(tasks[0], settings, tmp_path)
        assert read_record(tmp_path, tasks[0]) == record
        assert record["method"] == "random" and record["seed"] == 3 and record["test"]["episodes"] == 1
        results = compute_results(settings, [record])
        assert results["colours"]["random"] == "black"
    finally:
        METHOD_REGISTRY.pop("random")

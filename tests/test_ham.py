"""The HAM switch: switching on constructed observations, hysteresis, batches, saving, and use as a worker."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import sb3_hddpg  # noqa: F401  (registers the env ids)
from sb3_hddpg.baselines import HAMSwitch, load_ham, save_ham
from sb3_hddpg.baselines.ham import DEFAULT_MARGIN, THRESHOLD_STEP
from sb3_hddpg.evaluation import evaluate
from sb3_hddpg.hierarchy import WorkerSelectionWrapper
from sb3_hddpg.hierarchy.loading import load_policy

GOAL_ACTION = np.full(6, 0.5, dtype=np.float32)
AVOID_ACTION = np.full(6, -0.5, dtype=np.float32)


class Constant:
    """A worker that always returns one action (per row of a batch) and counts its calls."""

    def __init__(self, action: np.ndarray) -> None:
        self.action = action
        self.calls = 0
        self.resets = 0

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, None]:
        self.calls += 1
        shape = (*np.shape(observation)[:-1], self.action.shape[0])
        return np.broadcast_to(self.action, shape).copy(), None

    def reset_episode(self) -> None:
        self.resets += 1


@pytest.fixture(scope="module")
def env() -> gym.Env:
    return gym.make("hddpg/SnakeReach-v0")


def observation(env: gym.Env, summed: float) -> np.ndarray:
    """An observation whose joint_obstacle_distances sum to ``summed`` (spread evenly), zeros elsewhere."""
    layout = env.unwrapped.state_layout
    obs = np.zeros(env.observation_space.shape, dtype=np.float32)
    part = layout["joint_obstacle_distances"]
    obs[part] = summed / (part.stop - part.start)
    return obs


def switch(env: gym.Env, **kwargs: Any) -> HAMSwitch:
    return HAMSwitch(Constant(GOAL_ACTION), Constant(AVOID_ACTION), env.unwrapped.state_layout, **kwargs)


def test_default_threshold_is_one_half_link_inside_the_sensor_range(env):
    assert switch(env).threshold == pytest.approx(6 - DEFAULT_MARGIN)


@pytest.mark.parametrize("summed, expected", [(6.0, "goal"), (5.6, "goal"), (5.4, "avoid"), (0.0, "avoid")])
def test_switches_on_the_summed_distance(env, summed, expected):
    ham = switch(env, threshold=5.5)
    action, state = ham.predict(observation(env, summed))
    assert state is None
    assert ham.last_selection == expected
    np.testing.assert_array_equal(action, GOAL_ACTION if expected == "goal" else AVOID_ACTION)


def test_hysteresis_keeps_avoiding_until_clear_by_the_margin(env):
    ham = switch(env, threshold=5.0, hysteresis=0.5)
    sequence = [(5.2, "goal"), (4.9, "avoid"), (5.2, "avoid"), (5.45, "avoid"), (5.5, "goal"), (5.2, "goal")]
    for summed, expected in sequence:
        ham.predict(observation(env, summed))
        assert ham.last_selection == expected, summed


def test_without_hysteresis_every_step_decides_anew(env):
    ham = switch(env, threshold=5.0)
    for summed, expected in [(4.9, "avoid"), (5.2, "goal"), (4.9, "avoid")]:
        ham.predict(observation(env, summed))
        assert ham.last_selection == expected


def test_episode_start_forgets_the_hysteresis_state(env):
    ham = switch(env, threshold=5.0, hysteresis=0.5)
    ham.predict(observation(env, 4.0))
    ham.predict(observation(env, 5.2), episode_start=np.array([True]))
    assert ham.last_selection == "goal"
    assert all(w.resets == 1 for w in ham.workers.values())


def test_batched_observations_switch_row_by_row(env):
    ham = switch(env, threshold=5.0, hysteresis=0.5)
    batch = np.stack([observation(env, s) for s in (6.0, 4.0, 5.2)])
    actions, _ = ham.predict(batch)
    np.testing.assert_array_equal(actions, np.stack([GOAL_ACTION, AVOID_ACTION, GOAL_ACTION]))
    # Each row keeps its own hysteresis memory: row 1 stays with the avoid worker at 5.2.
    actions, _ = ham.predict(np.stack([observation(env, s) for s in (5.2, 5.2, 5.2)]))
    np.testing.assert_array_equal(actions, np.stack([GOAL_ACTION, AVOID_ACTION, GOAL_ACTION]))
    # Only the workers that act are asked: one call each per batch.
    assert ham.workers["goal"].calls == 2 and ham.workers["avoid"].calls == 2


@pytest.mark.parametrize("kwargs", [{"threshold": -0.1}, {"threshold": 6.5}, {"hysteresis": -1.0}])
def test_rejects_bad_settings(env, kwargs):
    with pytest.raises(ValueError, match="Expected"):
        switch(env, **kwargs)


def test_reward_spec_mixes_both_objectives(env):
    assert switch(env).reward_spec == {"goal": 1.0, "avoid": 1.0}


def test_ham_is_a_worker_of_a_selection_wrapper(env):
    ham = switch(env, threshold=5.5)
    other = Constant(np.zeros(6, dtype=np.float32))
    wrapped = WorkerSelectionWrapper(
        gym.make("hddpg/SnakeReach-v0"), {"ham": ham, "goal": other}, selection="argmax"
    )
    assert wrapped.reward_specs["ham"] == {"goal": 0.5, "avoid": 0.5}
    wrapped.reset(seed=3)
    _, reward, _, _, info = wrapped.step(np.array([1.0, -1.0], dtype=np.float32))
    assert info["selected_worker"] == "ham"
    assert ham.last_selection in ("goal", "avoid")
    normalised = info["normalised_terms"]
    assert reward == pytest.approx(0.5 * normalised["goal"] + 0.5 * normalised["avoid"] + normalised["goal"])


@pytest.fixture(scope="module")
def workers_dir(tmp_path_factory) -> Path:
    from sb3_hddpg.training.workers import train_workers

    out = tmp_path_factory.mktemp("ham-workers")
    train_workers(out, timesteps=50, eval_freq=0, eval_episodes=1)
    return out


def test_save_and_load_round_trip(workers_dir, tmp_path):
    path = save_ham(
        tmp_path / "ham" / "ham.json",
        workers_dir / "workers" / "manifest.json",
        threshold=5.2,
        hysteresis=0.3,
    )
    meta = json.loads(path.read_text())
    assert not Path(meta["workers_manifest"]).is_absolute()  # relative, so the folder can move
    ham, loaded_meta = load_ham(path)
    assert (ham.threshold, ham.hysteresis, ham.names) == (5.2, 0.3, ["goal", "avoid"])
    assert loaded_meta["env_id"] == "hddpg/SnakeReach-v0"

    # The CLI's loader opens it too, and evaluate counts its choices.
    loaded = load_policy(path)
    assert loaded.kind == "ham"
    summary = evaluate(loaded.policy, loaded.make_env(), n_episodes=1).summary()
    assert sum(summary["selection_rate"].values()) == pytest.approx(1.0)


def test_load_refuses_a_tampered_worker(workers_dir, tmp_path):
    import shutil

    copy = tmp_path / "run"
    shutil.copytree(workers_dir / "workers", copy / "workers")
    with open(copy / "workers" / "avoid.zip", "ab") as handle:
        handle.write(b"tampered")
    path = save_ham(copy / "ham.json", copy / "workers" / "manifest.json", threshold=5.5)
    with pytest.raises(ValueError, match="sha256"):
        load_ham(path)


def test_load_refuses_other_json(tmp_path):
    path = tmp_path / "other.json"
    path.write_text(json.dumps({"kind": "something-else"}))
    with pytest.raises(ValueError, match="not an sb3-hddpg HAM file"):
        load_ham(path)


def test_threshold_grid_spans_the_summed_distances_range(env):
    grid = switch(env).threshold_grid()
    assert grid[0] == THRESHOLD_STEP and grid[-1] == 6.0 and len(grid) == round(6 / THRESHOLD_STEP)
    assert switch(env).threshold_grid(from_zero=True) == [0.0, *grid]
    # Every threshold of the grid is one the switch accepts.
    for threshold in grid:
        assert switch(env, threshold=threshold).threshold == threshold

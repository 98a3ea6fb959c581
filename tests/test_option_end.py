"""Options that end by state: the rule, the wrapper's shorter options, the same rule in a loaded bundle."""

import json
import zipfile

import gymnasium as gym
import numpy as np
import pytest

from sb3_hddpg.artifacts.limits import LimitError
from sb3_hddpg.envs.contract import state_layout_of
from sb3_hddpg.hierarchy import WorkerSelectionWrapper
from sb3_hddpg.hierarchy.hierarchy import Hierarchy
from sb3_hddpg.hierarchy.option_end import OptionEnd
from sb3_hddpg.training.manager import train_manager
from sb3_hddpg.training.workers import train_workers
from tests.cli_runner import run_cli
from tests.helpers import ConstantWorker

EDGES = "distance=0.2/0.4/0.6/0.8,touch"


def test_the_rule_parses_round_trips_and_refuses_bad_input():
    rule = OptionEnd.parse(EDGES)
    assert rule == OptionEnd((0.2, 0.4, 0.6, 0.8), True)
    assert OptionEnd.from_json(rule.to_json()) == rule
    assert OptionEnd.parse("touch") == OptionEnd((), True)
    for text in ("distance=0.5/0.2", "distance=1.5", "distance=x", "near", ""):
        with pytest.raises(ValueError):
            OptionEnd.parse(text)
    for data in ([0.5], {"distance_edges": "0.5"}, {"distance_edges": [2.0]}, {"edges": [0.5]}):
        with pytest.raises(LimitError):
            OptionEnd.from_json(data)


def test_an_option_ends_when_the_state_leaves_its_band():
    env = gym.make("hddpg/SnakeReach-v0")
    band = OptionEnd.parse(EDGES).bind(state_layout_of(env))
    wrapper = WorkerSelectionWrapper(
        env,
        {"goal": ConstantWorker(np.full(6, 1.0)), "avoid": ConstantWorker(np.full(6, -1.0))},
        option_steps=40,
        option_end=OptionEnd.parse(EDGES),
    )
    lengths = []
    for episode in range(3):
        obs, _ = wrapper.reset(seed=episode)
        done = False
        while not done:
            start = band(wrapper._last_obs)
            obs, _, terminated, truncated, info = wrapper.step(np.array([1.0, -1.0], np.float32))
            done = terminated or truncated
            lengths.append(info["option_length"])
            if info["option_length"] < 40 and not done:
                assert band(wrapper._last_obs) != start  # it ended because the band changed
            else:
                assert band(wrapper._last_obs) == start or done or info["option_length"] == 40
    assert min(lengths) < 40  # some options ended by state
    plain = WorkerSelectionWrapper(
        env,
        {"goal": ConstantWorker(np.full(6, 1.0)), "avoid": ConstantWorker(np.full(6, -1.0))},
        option_steps=40,
    )
    plain.reset(seed=0)
    assert plain.step(np.array([1.0, -1.0], np.float32))[-1]["option_length"] == 40


@pytest.fixture(scope="module")
def workers(tmp_path_factory):
    root = tmp_path_factory.mktemp("option-end")
    train_workers(root / "w", seed=4, timesteps=200, eval_freq=0, eval_episodes=1)
    return root / "w"


def test_a_bundle_keeps_the_rule_and_decides_when_the_band_changes(workers, tmp_path):
    train_manager(workers, tmp_path / "m", option_steps=20, option_end=EDGES, seed=4,
                  timesteps=60, eval_freq=30, eval_episodes=1)  # fmt: skip
    with zipfile.ZipFile(tmp_path / "m" / "hierarchy.zip") as archive:
        manifest = json.loads(archive.read("manifest.json"))
    assert manifest["selection"]["option_end"] == OptionEnd.parse(EDGES).to_json()
    loaded = Hierarchy.load(tmp_path / "m" / "hierarchy.zip")
    env = loaded.make_env()
    band = OptionEnd.parse(EDGES).bind(state_layout_of(env))
    obs, _ = env.reset(seed=1)
    loaded.reset_episode()
    previous, since = None, 0
    for _ in range(100):
        action, _ = loaded.predict(obs, deterministic=True)
        current = band(obs)
        if previous is not None and current != previous:
            assert loaded.last_decided  # a new decision as soon as the band changes
        since = 0 if loaded.last_decided else since + 1
        assert since < 20
        previous = current if loaded.last_decided else previous
        obs, *_ = env.step(action)


def test_the_cli_refuses_a_bad_rule_in_one_line(workers, tmp_path):
    result = run_cli(
        "train-manager", "--workers", workers, "--out", tmp_path / "m", "--option-end", "distance=2"
    )
    output = result.stdout + result.stderr
    assert result.returncode == 2 and "distance edges" in output and "Traceback" not in output

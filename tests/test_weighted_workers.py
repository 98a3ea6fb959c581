"""Workers on a weighting of the reward terms: the weighted view, the checks, training and the manager over them."""

import gymnasium as gym
import numpy as np
import pytest

from sb3_hddpg.artifacts.manifests import load_workers
from sb3_hddpg.envs.contract import env_contract
from sb3_hddpg.envs.weighted import check_term_weights, make_weighted_view, parse_term_weights, weighted_name
from sb3_hddpg.hierarchy import WorkerSelectionWrapper
from sb3_hddpg.training.workers import plan_workers, train_workers

TINY = {"timesteps": 300, "eval_freq": 0, "eval_episodes": 1}


def test_the_weighted_view_pays_the_weighted_normalised_sum():
    env = make_weighted_view("hddpg/SnakeReach-v0", {}, {"goal": 3.0, "avoid": 1.0})
    normalise = env_contract(env).normalise_terms
    env.reset(seed=0)
    for _ in range(5):
        _, reward, _, _, info = env.step(env.action_space.sample())
        normalised = normalise(info["reward_terms"])
        assert reward == pytest.approx(0.75 * normalised["goal"] + 0.25 * normalised["avoid"])


@pytest.mark.parametrize(
    ("weights", "message"),
    [
        ({"goal": float("nan")}, "finite number >= 0"),
        ({"goal": -0.1, "avoid": 1.0}, "finite number >= 0"),
        ({"speed": 1.0}, "unknown terms ['speed']"),
        ({"goal": 0.0, "avoid": 0.0}, "positive sum"),
        ({"goal": True}, "finite number >= 0"),
    ],
)
def test_weights_are_checked_like_preferences(weights, message):
    with pytest.raises(ValueError, match=message.replace("[", r"\[").replace("]", r"\]")):
        check_term_weights(weights, ["goal", "avoid"])


def test_names_and_parsing():
    assert parse_term_weights("goal=0.7, avoid=0.3") == {"goal": 0.7, "avoid": 0.3}
    assert (
        weighted_name(check_term_weights({"goal": 0.7, "avoid": 0.3}, ["goal", "avoid"]))
        == "mix-goal70-avoid30"
    )
    assert (
        weighted_name(check_term_weights({"goal": 1, "avoid": 7}, ["goal", "avoid"]))
        == "mix-goal12p5-avoid87p5"
    )
    assert weighted_name(check_term_weights({"avoid": 2.0}, ["goal", "avoid"])) == "avoid"
    for bad in ("goal", "goal=x", "goal=1,goal=2", ""):
        with pytest.raises(ValueError):
            parse_term_weights(bad)
    # A corner weight is the per-term worker; two weightings of one name are refused.
    assert [w.name for w in plan_workers(None, [{"goal": 1.0}])] == ["goal"]
    with pytest.raises(ValueError, match="twice"):
        plan_workers(None, [{"goal": 0.5, "avoid": 0.5}, {"goal": 2, "avoid": 2}])


def test_a_weighted_worker_trains_and_serves_a_manager(tmp_path):
    manifest = train_workers(
        tmp_path, workers=["avoid"], weights=[{"goal": 0.7, "avoid": 0.3}], seed=1, **TINY
    ).manifest
    entry = manifest["workers"]["mix-goal70-avoid30"]
    assert entry["reward_weights"] == pytest.approx({"goal": 0.7, "avoid": 0.3})
    assert entry["reward_bounds"] == [0.0, 1.0]
    assert entry["env_id"] == "hddpg/SnakeReach-v0"
    assert "reward_term" not in entry and manifest["workers"]["avoid"]["reward_term"] == "avoid"
    workers = load_workers(tmp_path)
    env = WorkerSelectionWrapper(
        workers.make_env(), workers, preferences={"avoid": 1.0, "mix-goal70-avoid30": 2.0}
    )
    # The manager is paid each worker's own reward (the weighted worker's weights), mixed by the preference.
    assert env.reward_specs["mix-goal70-avoid30"] == pytest.approx({"goal": 0.7, "avoid": 0.3})
    assert env.selection_config().reward_terms["mix-goal70-avoid30"] == pytest.approx(
        {"goal": 0.7, "avoid": 0.3}
    )
    env.reset(seed=0)
    _, reward, _, _, info = env.step(np.array([-1.0, 1.0], dtype=np.float32))
    normalised = info["normalised_terms"]
    expected = normalised["avoid"] + 2.0 * (0.7 * normalised["goal"] + 0.3 * normalised["avoid"])
    assert reward == pytest.approx(expected, rel=1e-5)
    assert isinstance(gym.make("hddpg/SnakeReach-v0").observation_space, gym.spaces.Box)


def test_the_command_line_trains_a_weighted_worker_and_refuses_bad_weights(tmp_path):
    from tests.cli_batch import run_batch

    tiny = ("--timesteps", "120", "--eval-freq", "0", "--eval-episodes", "1", "--no-progress")
    refusals = (("goal=-1,avoid=1", "finite number >= 0"), ("speed=1", "unknown terms"))
    # The three command lines in one interpreter (tests/cli_batch.py), each with its own exit code and output.
    trained, *refused = run_batch(
        [
            ["train-workers", "--weights", "goal=0.6,avoid=0.4", "--out", str(tmp_path), *tiny],
            *(
                ["train-workers", "--weights", bad, "--out", str(tmp_path / "bad"), *tiny]
                for bad, _ in refusals
            ),
        ]
    )
    assert trained.returncode == 0, trained.stdout + trained.stderr
    assert list(load_workers(tmp_path)) == ["mix-goal60-avoid40"]
    for result, (_, message) in zip(refused, refusals, strict=True):
        assert result.returncode == 2 and message in result.stderr and "Traceback" not in result.stderr
    assert not (tmp_path / "bad").exists()

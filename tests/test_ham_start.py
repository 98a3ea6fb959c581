"""A manager's start from the hand-written rule: behaviour cloning on HAM's choices before RL."""

import json
import zipfile

import numpy as np
import pytest
from stable_baselines3 import DDPG, DQN

from sb3_hddpg.training.imitation_start import HamStart, collect_start_decisions, imitate
from sb3_hddpg.training.manager import train_manager
from sb3_hddpg.training.manager_setup import prepare_manager
from sb3_hddpg.training.workers import train_workers
from tests.cli_batch import run_batch


@pytest.fixture(scope="module")
def workers(tmp_path_factory):
    root = tmp_path_factory.mktemp("ham-start")
    train_workers(root / "w", seed=2, timesteps=200, eval_freq=0, eval_episodes=1)
    return root


@pytest.mark.parametrize(("algo", "cls"), [("ddpg", DDPG), ("dqn", DQN)])
def test_the_fitted_manager_agrees_with_ham_and_its_buffer_holds_hams_decisions(workers, algo, cls):
    setup = prepare_manager(workers / "w", algo=algo)
    env = setup.env_factory()()
    model = cls("MlpPolicy", env, learning_starts=10_000, seed=0, device="cpu")
    # A threshold at which HAM uses both workers on these episodes.
    start = HamStart(threshold=5.0, decisions=300, epochs=100)
    observations, choices = collect_start_decisions(env, start, model)
    assert len(choices) == 300 and model.replay_buffer.size() == 300
    assert 0 < choices.mean() < 1 or len(set(choices.tolist())) == 1
    untrained = imitate(model, observations, choices, HamStart(threshold=5.0, epochs=1, learning_rate=1e-9))
    agreement = imitate(model, observations, choices, start)
    assert agreement >= 0.9 and agreement >= untrained
    if algo == "ddpg":  # the target actor is the fitted one
        for a, b in zip(model.actor.parameters(), model.actor_target.parameters()):
            assert np.allclose(a.detach().numpy(), b.detach().numpy())


def test_train_manager_starts_from_ham_and_records_it(workers, tmp_path):
    hierarchy = train_manager(workers / "w", tmp_path / "m", init_from_ham=HamStart(5.0, decisions=200, epochs=20),
                                 seed=2, timesteps=100, eval_freq=50, eval_episodes=1).hierarchy  # fmt: skip
    report = hierarchy.metadata["init_from_ham"]
    assert report["threshold"] == 5.0 and report["decisions"] == 200 and report["agreement"] >= 0.8
    with zipfile.ZipFile(tmp_path / "m" / "hierarchy.zip") as archive:
        manifest = json.loads(archive.read("manifest.json"))
    assert manifest["manager"]["init_from_ham"]["agreement"] == report["agreement"]


def test_the_cli_option_and_its_refusals(workers, tmp_path):
    # Both command lines in one interpreter (tests/cli_batch.py), each with its own exit code and output.
    ok, bad = run_batch(
        [
            ["train-manager", "--workers", str(workers / "w"), "--out", str(tmp_path / "m"), "--init-from-ham",
             "5", "--timesteps", "60", "--eval-freq", "30", "--eval-episodes", "1", "--no-progress"],
            ["train-manager", "--workers", str(workers / "w"), "--out", str(tmp_path / "n"), "--init-from-ham",
             "-1"],
        ]
    )  # fmt: skip
    assert ok.returncode == 0, ok.stdout + ok.stderr
    assert "imitated HAM" in ok.stdout
    assert bad.returncode == 2 and "Traceback" not in bad.stdout + bad.stderr

"""``hddpg-cli quickstart --budget tiny`` end to end, in a subprocess, as a user runs it."""

import importlib.util
import json
import re
import subprocess
import sys

import imageio.v3 as iio
import pytest
from PIL import Image
from stable_baselines3 import DDPG

from hddpg_zoo.agent_settings import manager_option_steps
from hddpg_zoo.quickstart import BUDGETS, STAGES
from sb3_hddpg.artifacts.records import QUICKSTART_RESULTS_VERSION
from sb3_hddpg.hierarchy.hierarchy import Hierarchy
from sb3_hddpg.training.config import load_hyperparams
from tests.cli_batch import run_batch
from tests.cli_runner import run_cli


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("qs") / "run"
    result = run_cli("quickstart", "--budget", "tiny", "--out", out, "--seed", "1", timeout=900, check=True)
    return out, result


def test_prints_the_table_and_the_run_folder(run):
    out, result = run
    assert "HDDPG" in result.stdout and "flat DDPG" in result.stdout and "reach reward" in result.stdout
    assert str(out) in result.stdout
    # Every agent's budget in env steps, the manager's too (its SB3 steps are decisions of several).
    assert re.search(r"manager: [\d,]+ env steps", result.stdout), result.stdout


def test_results_json_schema(run):
    out, _ = run
    results = json.loads((out / "results.json").read_text())
    assert (
        results["schema_version"] == QUICKSTART_RESULTS_VERSION and results["kind"] == "sb3-hddpg-quickstart"
    )
    assert results["budget"]["name"] == "tiny" and results["seed"] == 1
    assert results["eval_seeds"] == list(range(10_000, 10_000 + BUDGETS["tiny"].compare_episodes))
    expected = {"HDDPG", "HAM", "flat DDPG", "goal worker", "avoid worker", "scripted", "random"}
    assert expected <= set(results["methods"]) and "ham_available" not in results
    for method in results["methods"].values():
        summary = method["summary"]
        assert summary["episodes"] == BUDGETS["tiny"].compare_episodes
        assert len(method["episodes"]) == summary["episodes"]
        for key in ("mean_reach_reward", "std_reach_reward", "goal_touch_rate", "collisions_per_episode"):
            assert isinstance(summary[key], float)
    # Avoid worker 300 + goal worker 304 (it trains in blocks of train_freq = 8 steps) + the manager's env
    # steps: 300 // k decisions of k = option_steps env steps each, which SB3 rounds up to whole blocks of
    # the manager's train_freq decisions.
    k = manager_option_steps(out / "config.yml")
    every = load_hyperparams("manager", DDPG, out / "config.yml", manager=True).algo_kwargs["train_freq"]
    decisions = -(-(300 // k) // every) * every
    assert results["methods"]["HDDPG"]["train_timesteps"] == 604 + decisions * k
    # The flat DDPG gets the hierarchy's planned total: two workers' 300 steps and the manager's 300.
    assert results["methods"]["flat DDPG"]["train_timesteps"] == results["budget"]["flat_timesteps"] == 900
    assert set(results["stage_seconds"]) == set(STAGES) == set(results["stage_cpu_seconds"])
    for label, path in results["files"].items():
        assert (out / path).exists(), label


def test_media_decode(run):
    out, _ = run
    for name in ("comparison.png", "learning_curves.png", "selection.png"):
        with Image.open(out / name) as image:
            image.verify()
    frames = iio.imread(out / "hierarchy.gif", index=None)
    assert frames.shape[0] == BUDGETS["tiny"].gif_max_steps


def test_bundle_and_models_load(run):
    out, _ = run
    assert Hierarchy.load(out / "hierarchy.zip").names == ["goal", "avoid"]
    manifest = json.loads((out / "workers" / "manifest.json").read_text())
    assert set(manifest["workers"]) == {"goal", "avoid"}  # merged from the two processes
    assert DDPG.load(out / "zoo" / "ddpg" / "hddpg-SnakeReach-v0_1" / "hddpg-SnakeReach-v0.zip")


def test_the_main_hierarchy_answers_a_preference_and_the_papers_stands_beside(run):
    out, result = run
    main_bundle = Hierarchy.load(out / "hierarchy.zip")
    assert main_bundle.preference_space is not None  # told the preference at run time
    # It started from HAM's switch, whose decisions are part of its budget of env steps.
    start = main_bundle.metadata["init_from_ham"]
    assert start["decisions"] == BUDGETS["tiny"].ham_start_decisions and 0 <= start["agreement"] <= 1
    k = manager_option_steps(out / "config-dqn.yml", "dqn")
    trained = json.loads((out / "results.json").read_text())["methods"]["hierarchy"]["train_timesteps"]
    assert trained == 604 + (start["decisions"] + main_bundle.metadata["timesteps_trained"]) * k
    assert Hierarchy.load(out / "simplex" / "hierarchy.zip").preference_space is None
    results = json.loads((out / "results.json").read_text())
    assert {"hierarchy", "HDDPG"} <= set(results["methods"])
    assert results["methods"]["hierarchy"]["source"] == "hierarchy.zip"
    assert results["methods"]["HDDPG"]["source"] == "simplex/hierarchy.zip"
    main, paper = run_batch(
        [
            ["evaluate", str(out / bundle), "--episodes", "1", "--preference", "goal=1,avoid=3"]
            for bundle in ("hierarchy.zip", "simplex/hierarchy.zip")
        ]
    )
    assert main.returncode == 0, main.stderr
    assert "Preference: goal=0.5,avoid=1.5 (given with --preference" in main.stdout
    assert "each term's raw sum" in main.stdout  # how the reward rows relate
    assert paper.returncode == 2 and "trained for the preference" in paper.stderr


def test_a_finished_run_keeps_models_and_drops_replay_buffers(run):
    out, _ = run
    assert list(out.rglob("*.pkl")) == []
    for agent in ("goal", "avoid", "manager", "flat-ddpg"):
        state = json.loads((out / "checkpoints" / agent / "state.json").read_text())
        assert state["replay_buffer"] is None and (out / "checkpoints" / agent / state["model"]).is_file()


def test_refuses_to_overwrite(run):
    out, _ = run
    again = run_cli("quickstart", "--budget", "tiny", "--out", out)
    assert again.returncode == 2 and "--force" in again.stderr


@pytest.mark.skipif(importlib.util.find_spec("requests") is None, reason="rl_zoo3.enjoy imports requests")
def test_rl_zoo_enjoy_runs_the_quickstart_workers(run, tmp_path):
    out, _ = run
    args = ["--algo", "ddpg", "--env", "hddpg/SnakeGoal-v0", "--gym-packages", "sb3_hddpg", "-n", "200"]
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "rl_zoo3.enjoy",
            *args,
            "-f",
            str(out / "zoo"),
            "--exp-id",
            "1",
            "--no-render",
        ],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert "Mean reward" in result.stdout

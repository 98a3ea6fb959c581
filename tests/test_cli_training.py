"""The training commands end to end through the CLI, in subprocesses, on tiny budgets."""

import json
import os
import subprocess
import sys

import pytest
from stable_baselines3 import DDPG

from tests.cli_batch import run_batch
from tests.cli_runner import CLI, run_cli
from tests.helpers import sigterm_once_written

TINY = ("--timesteps", "400", "--eval-freq", "200", "--eval-episodes", "1", "--no-progress")


def _succeeded(result: subprocess.CompletedProcess) -> subprocess.CompletedProcess:
    """``result``, once checked to have exited 0 (its output in the failure message)."""
    assert result.returncode == 0, f"{result.args} failed:\n{result.stdout}\n{result.stderr}"
    return result


def test_version_and_help():
    version, help_ = map(_succeeded, run_batch([["--version"], ["--help"]]))
    assert version.stdout.startswith("sb3-hddpg ")
    for command in ("train-workers", "train-manager", "evaluate"):
        assert command in help_.stdout


def test_workers_manager_evaluate_end_to_end(tmp_path):
    # One interpreter runs the five command lines in turn (tests/cli_batch.py): each still gets its own exit
    # code and output, and none starts torch again.
    w, m = str(tmp_path / "w"), str(tmp_path / "m")
    workers, manager, evaluated, worker_evaluated, refused = run_batch(
        [
            ["train-workers", *TINY, "--out", w, "--seed", "1"],
            ["train-manager", "--workers", w, *TINY, "--out", m, "--prefer", "avoid"],
            ["evaluate", f"{m}/hierarchy.zip", "--episodes", "2", "--json", str(tmp_path / "eval.json")],
            # A worker zip evaluates through the manifest beside it (safe load, no --trust needed).
            ["evaluate", str(tmp_path / "w" / "workers" / "goal.zip"), "--episodes", "1"],
            # An output folder with results is refused without --force/--resume.
            ["train-workers", *TINY, "--out", w],
        ]
    )
    for result in (workers, manager, evaluated, worker_evaluated):
        _succeeded(result)
    assert DDPG.load(tmp_path / "w" / "workers" / "goal.zip").num_timesteps > 0
    assert (tmp_path / "w" / "tensorboard" / "goal").is_dir()
    assert "Worker choices" in manager.stdout
    report = json.loads((tmp_path / "eval.json").read_text())
    assert report["kind"] == "hierarchy" and report["summary"]["episodes"] == 2
    assert sum(report["summary"]["selection_rate"].values()) == pytest.approx(1.0)
    # Words and one unit per quantity, not raw keys and fractions mixed with percentages.
    assert "steps run by the goal worker" in evaluated.stdout and "% of steps" in evaluated.stdout
    assert "selection_rate" not in evaluated.stdout and "goal_touch_rate" not in evaluated.stdout
    assert refused.returncode == 2 and "already holds results" in refused.stderr
    assert "Traceback" not in refused.stderr


#: The goal worker alone, evaluated often on one episode: what the interrupted run and its resume share.
_GOAL_WORKER = (
    "train-workers",
    "--workers",
    "goal",
    "--eval-freq",
    "500",
    "--eval-episodes",
    "1",
    "--no-progress",
)


def test_interrupt_saves_a_checkpoint_and_resume_reaches_the_total(tmp_path):
    out = tmp_path / "run"
    env = {**os.environ, "SDL_VIDEODRIVER": "dummy"}
    process = subprocess.Popen(
        [
            *CLI,
            *_GOAL_WORKER,
            "--timesteps",
            "20000",
            "--out",
            str(out),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    stdout, stderr = sigterm_once_written(process, out / "evaluations" / "goal.json", "the first evaluation")
    assert process.returncode == 143, stderr  # 128 + SIGTERM
    assert "--resume" in stdout and "Traceback" not in stderr
    state = json.loads((out / "checkpoints" / "goal" / "state.json").read_text())
    assert 0 < state["num_timesteps"] < 20000
    DDPG.load(out / "checkpoints" / "goal" / state["model"])
    resumed = run_cli(
        *_GOAL_WORKER,
        "--timesteps",
        str(state["num_timesteps"] + 304),  # the goal worker trains in blocks of train_freq = 8 steps
        "--out",
        out,
        "--resume",
        check=True,
    )
    manifest = json.loads((out / "workers" / "manifest.json").read_text())
    assert manifest["workers"]["goal"]["timesteps_trained"] == state["num_timesteps"] + 304
    assert "goal" in resumed.stdout


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("default:\n  n_timesteps: 100\n  learning_rat: 0.001\n", "Unknown keys"),
        ("default: [unclosed\n", "Invalid YAML"),
        ("default:\n  n_timesteps: -5\n", "n_timesteps"),
        (
            "default:\n  n_timesteps: 100\n  policy_kwargs: \"dict(net_arch=__import__('os').system('true'))\"\n",
            "Unsupported expression",
        ),
    ],
)
def test_config_errors_are_one_line(tmp_path, content, message):
    config = tmp_path / "bad.yml"
    config.write_text(content)
    result = run_cli("train-workers", "--config", config, "--out", tmp_path / "out", "--timesteps", "100")
    assert result.returncode != 0
    lines = [line for line in result.stderr.strip().splitlines() if line]
    assert len(lines) == 1 and message in lines[0], result.stderr


def test_missing_config_file_is_a_usage_error(tmp_path):
    result = run_cli("train-workers", "--config", tmp_path / "nope.yml", "--out", tmp_path / "o")
    assert result.returncode == 2 and "nope.yml" in result.stderr and "Traceback" not in result.stderr


def test_rl_zoo_trains_with_our_config_unchanged(tmp_path, repo_root):
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "rl_zoo3.train",
            "--algo",
            "ddpg",
            "--env",
            "hddpg/SnakeGoal-v0",
            "--gym-packages",
            "sb3_hddpg",
            "--conf-file",
            os.path.join(repo_root, "zoo_configs", "ddpg.yml"),
            # RL Zoo evaluates replay_buffer_class as Python; the goal block names ours (docs/RL_ZOO.md).
            "--hyperparams",
            "replay_buffer_class:None",
            "replay_buffer_kwargs:None",
            "-n",
            "304",  # a multiple of the goal block's train_freq (8): SB3 trains in blocks of 8 steps
            "--eval-freq",
            "-1",
            "-f",
            str(tmp_path / "logs"),
        ],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    model = DDPG.load(tmp_path / "logs" / "ddpg" / "hddpg-SnakeGoal-v0_1" / "hddpg-SnakeGoal-v0.zip")
    assert model.num_timesteps == 304
    assert model.observation_space.shape == (15,)  # the block's env_kwargs (observe) reached the env

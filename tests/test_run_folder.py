"""A finished run keeps its models and drops its replay buffers, unless asked to keep them."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import typer
from stable_baselines3 import DDPG

from sb3_hddpg.artifacts.io import HELD_FOLDERS_ENV
from sb3_hddpg.training.workers import train_workers
from tests.test_bad_input import TINY_CONFIG

RUN = {"workers": ["goal"], "eval_freq": 0, "eval_episodes": 1, "checkpoint_freq": 100}


def _checkpoint(out):
    folder = out / "checkpoints" / "goal"
    return json.loads((folder / "state.json").read_text()), sorted(p.name for p in folder.iterdir())


def test_a_finished_run_drops_the_buffer_and_still_resumes_to_a_larger_budget(tmp_path):
    config = tmp_path / "tiny.yml"
    config.write_text(TINY_CONFIG)
    train_workers(tmp_path / "run", config=config, timesteps=300, **RUN)
    state, files = _checkpoint(tmp_path / "run")
    assert state["num_timesteps"] == 300 and state["replay_buffer"] is None
    assert files == ["model_300.zip", "state.json"]  # the 100- and 200-step checkpoints' buffers are gone too
    assert (tmp_path / "run" / "workers" / "goal.zip").is_file()

    # Resuming the finished run with a larger budget continues from its model, refilling the buffer
    # (learning_starts fresh steps) before the first update.
    manifest = train_workers(tmp_path / "run", config=config, timesteps=450, resume=True, **RUN).manifest
    assert manifest["workers"]["goal"]["timesteps_trained"] == 450
    resumed = DDPG.load(tmp_path / "run" / "checkpoints" / "goal" / "model_450.zip", device="cpu")
    assert resumed.learning_starts == 300 + 100


def test_keep_checkpoints_keeps_the_buffer(tmp_path):
    config = tmp_path / "tiny.yml"
    config.write_text(TINY_CONFIG)
    train_workers(tmp_path / "run", config=config, timesteps=300, keep_checkpoints=True, **RUN)
    state, files = _checkpoint(tmp_path / "run")
    assert files == ["model_300.zip", "replay_buffer_300.pkl", "state.json"]
    model = DDPG.load(tmp_path / "run" / "checkpoints" / "goal" / state["model"], device="cpu")
    model.load_replay_buffer(tmp_path / "run" / "checkpoints" / "goal" / state["replay_buffer"])
    assert model.replay_buffer.size() == 300


def _locked_for_another_process(folder: Path) -> bool:
    """Whether a separate process (not one this process started for the run) finds ``folder`` locked."""
    env = {k: v for k, v in os.environ.items() if k != HELD_FOLDERS_ENV}
    code = (
        "import sys\nfrom sb3_hddpg.artifacts.io import FolderLockedError, locked_folder\n"
        "try:\n    locked_folder(sys.argv[1]).__enter__()\nexcept FolderLockedError:\n    sys.exit(3)\n"
    )
    return subprocess.run([sys.executable, "-c", code, str(folder)], env=env, timeout=60).returncode == 3


def test_a_command_holds_its_folder_lock_until_it_ends_in_process(tmp_path):
    # The lock lives as long as the command's own context: typer keeps its own copy of click, so a lock
    # tied to click's current context was never tied to anything, and was released as soon as it was
    # garbage (at once), leaving a running command's folder open to a second run.
    from typer.testing import CliRunner

    from sb3_hddpg.cli.options import prepare_out_dir

    app = typer.Typer()
    seen: list[bool] = []

    @app.command()
    def take(context: typer.Context, out: Path) -> None:
        prepare_out_dir(context, out, resume=False, force=False)
        seen.append(_locked_for_another_process(out))

    out = tmp_path / "run"
    for _ in range(2):  # and released when the command ends: the second takes it again
        result = CliRunner().invoke(app, [str(out)])
        assert result.exit_code == 0, result.output
    assert seen == [True, True]
    assert not _locked_for_another_process(out)


def test_a_run_resumed_between_evaluations_keeps_evaluating_on_the_same_grid(tmp_path):
    # A run stopped between two evaluations (Ctrl-C) used to count its evaluation period from the resume,
    # so its points fell between every other seed's and the benchmark's mean curve dropped them.
    config = tmp_path / "tiny.yml"
    config.write_text(TINY_CONFIG)
    run = {**RUN, "eval_freq": 100}
    train_workers(tmp_path / "run", config=config, timesteps=250, **run)
    manifest = train_workers(tmp_path / "run", config=config, timesteps=450, resume=True, **run).manifest
    assert manifest["workers"]["goal"]["timesteps_trained"] == 450
    history = json.loads((tmp_path / "run" / "evaluations" / "goal.json").read_text())
    # Every 100 steps from the run's start, plus the final evaluation each call ends with.
    assert [point["timesteps"] for point in history] == [100, 200, 250, 300, 400, 450]


def test_a_resumed_manager_must_act_on_the_same_mdp(tmp_path):
    """A manager resumed with another option length (or env, workers, algorithm) is refused in one line."""
    from sb3_hddpg.artifacts.manifests import ResumeMismatch
    from sb3_hddpg.training.manager import train_manager

    config = tmp_path / "tiny.yml"
    config.write_text(TINY_CONFIG)
    run = tmp_path / "run"
    train_workers(run, config=config, timesteps=150, workers=["goal", "avoid"], eval_freq=0, eval_episodes=1)
    tiny = {"config": config, "eval_freq": 0, "eval_episodes": 1, "checkpoint_freq": 50}
    train_manager(run, run, option_steps=2, timesteps=100, **tiny)
    with pytest.raises(ResumeMismatch, match=r"selection was .* in the run"):
        train_manager(run, run, option_steps=3, timesteps=150, resume=True, **tiny)
    # The same settings resume.
    outcome = train_manager(run, run, option_steps=2, timesteps=150, resume=True, **tiny).outcome
    assert outcome.num_timesteps == 150


def test_a_resumed_manager_must_keep_its_learner_and_a_folder_without_that_record_still_resumes(tmp_path):
    """A resumed model keeps the discount it was saved with: another ``gamma`` is refused, not ignored."""
    from sb3_hddpg.artifacts.manifests import ResumeMismatch
    from sb3_hddpg.training.manager import MANAGER_SETTINGS_FILE, train_manager

    config = tmp_path / "tiny.yml"
    config.write_text(TINY_CONFIG)
    run = tmp_path / "run"
    train_workers(run, config=config, timesteps=150, workers=["goal", "avoid"], eval_freq=0, eval_episodes=1)
    tiny = {"config": config, "option_steps": 2, "eval_freq": 0, "eval_episodes": 1, "checkpoint_freq": 50}
    train_manager(run, run, gamma=0.9, timesteps=100, **tiny)
    with pytest.raises(ResumeMismatch, match=r"learner was .*0\.9.* in the run, now .*0\.5"):
        train_manager(run, run, gamma=0.5, timesteps=150, resume=True, **tiny)
    settings = run / "manager" / MANAGER_SETTINGS_FILE
    recorded = json.loads(settings.read_text())
    del recorded["env_kwargs"]["learner"]
    settings.write_text(json.dumps(recorded))
    # Without the learner's record the MDP alone is compared: such a folder resumes as it did.
    outcome = train_manager(run, run, gamma=0.9, timesteps=150, resume=True, **tiny).outcome
    assert outcome.num_timesteps == 150


def test_a_marker_half_written_by_another_process_is_the_tools_not_the_users(tmp_path):
    """Two commands sharing a folder (two tune processes on one study): one's marker being written is no user file."""
    from sb3_hddpg.artifacts.run_folder import RunFolderError, check_out_folder

    shared = tmp_path / "shared"
    shared.mkdir()
    (shared / "..hddpg-run.k2x9a.tmp").write_text("{")
    assert check_out_folder(shared) == shared
    (shared / "notes.tmp").write_text("mine")
    with pytest.raises(RunFolderError, match=r"notes\.tmp"):
        check_out_folder(shared)

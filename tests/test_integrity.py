"""
Nothing a user made is lost or silently rewound: one writer per run folder, manifests updated under its
lock, checkpoints that never go backwards (docs/ROBUSTNESS.md, "Integrity").
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from sb3_hddpg.io import LOCK_FILE, FolderLockedError, locked_folder

ROOT = Path(__file__).resolve().parents[1]

TINY = """\
default: &tiny
  n_timesteps: 200
  policy: 'MlpPolicy'
  buffer_size: 1000
  learning_starts: 50
  batch_size: 16
  noise_type: 'normal'
  noise_std: 0.2
  policy_kwargs: "dict(net_arch=[16])"
manager:
  <<: *tiny
"""


def _state(folder: Path) -> dict:
    return json.loads((folder / "state.json").read_text())


def test_resume_after_a_kill_right_after_the_final_checkpoint_does_not_rewind(tmp_path: Path) -> None:
    """
    The issue's sequence: a run whose last checkpoint is at the final step but whose manifest is missing
    (SIGKILL right after that checkpoint), then --resume. It used to rewrite state.json as step 0, delete
    the step-200 files, and add an evaluation labelled step 0.
    """
    from sb3_hddpg.training import train_manager, train_workers

    config = tmp_path / "tiny.yml"
    config.write_text(TINY)
    out = tmp_path / "w"
    quick = {"eval_freq": 100, "eval_episodes": 1, "checkpoint_freq": 100, "config": config}
    train_workers(out, workers=["goal"], **quick)
    checkpoints = out / "checkpoints" / "goal"
    assert _state(checkpoints)["num_timesteps"] == 200
    # What a SIGKILL right after the final checkpoint leaves: no manifest, no final zip.
    (out / "workers" / "manifest.json").unlink()
    (out / "workers" / "goal.zip").unlink()
    history_before = json.loads((out / "evaluations" / "goal.json").read_text())

    manifest = train_workers(out, workers=["goal"], resume=True, **quick)

    state = _state(checkpoints)
    assert state["num_timesteps"] == 200 and state["model"] == "model_200.zip"
    assert (checkpoints / "model_200.zip").is_file()
    assert not (checkpoints / "model_0.zip").exists()
    history = json.loads((out / "evaluations" / "goal.json").read_text())
    assert [h["timesteps"] for h in history] == [h["timesteps"] for h in history_before]
    assert all(h["timesteps"] > 0 for h in history)
    assert manifest["workers"]["goal"]["timesteps_trained"] == 200

    # train-manager: the same sequence (no hierarchy.zip after the kill).
    train_workers(out, workers=["avoid"], **quick)
    m_out = tmp_path / "m"
    train_manager(out, m_out, timesteps=200, **quick)
    manager_checkpoints = m_out / "checkpoints" / "manager"
    (m_out / "hierarchy.zip").unlink()
    train_manager(out, m_out, timesteps=200, resume=True, **quick)
    state = _state(manager_checkpoints)
    assert state["num_timesteps"] == 200 and state["model"] == "model_200.zip"
    history = json.loads((m_out / "evaluations" / "manager.json").read_text())
    assert all(h["timesteps"] > 0 for h in history)
    assert (m_out / "hierarchy.zip").is_file()

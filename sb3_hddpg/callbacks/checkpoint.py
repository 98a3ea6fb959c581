"""Resumable checkpoints: model, replay buffer and run state, written so that a kill at any moment is safe."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

from sb3_hddpg.artifacts.io import atomic_write, atomic_write_json, remove_stale_temporaries
from sb3_hddpg.artifacts.limits import read_json_file

STATE_FILE = "state.json"


class ResumableCheckpointCallback(BaseCallback):
    """
    Save a resumable checkpoint every ``save_freq`` environment steps (and on demand, e.g. at Ctrl-C):
    ``model_<t>.zip`` and ``replay_buffer_<t>.pkl``, then ``state.json`` naming them, each atomically, so a
    run killed at any moment leaves the previous checkpoint loadable; older files go after.

    :param checkpoint_dir: the folder for this agent's checkpoints.
    :param save_freq: environment steps between checkpoints (0: only on demand).
    :param extra_state: a callable returning JSON-able run state to store too (e.g. the evaluation history).
    :param min_timesteps: the step count of the checkpoint a resumed run started from: a checkpoint is
        never written at fewer steps (checkpoints never go backwards).
    """

    def __init__(
        self,
        checkpoint_dir: str | Path,
        save_freq: int = 10_000,
        extra_state: Any = None,
        min_timesteps: int = 0,
    ) -> None:
        super().__init__()
        self.checkpoint_dir = Path(checkpoint_dir)
        self.save_freq = save_freq
        self.extra_state = extra_state
        self.min_timesteps = int(min_timesteps)
        self._last_saved = 0

    def _on_training_start(self) -> None:
        self._last_saved = self.num_timesteps

    def _on_step(self) -> bool:
        if self.save_freq > 0 and self.num_timesteps - self._last_saved >= self.save_freq:
            self.save()
        return True

    def save(self, replay_buffer: bool = True) -> Path:
        """
        Write a checkpoint of the current model and replay buffer now; return the state file's path.

        :param replay_buffer: also write the replay buffer; without it the checkpoint resumes with an empty
            one (how a finished run drops it).
        """
        # The model's own count: the callback's copy is only updated inside learn().
        steps = int(self.model.num_timesteps)
        if steps < self.min_timesteps:
            raise RuntimeError(
                f"Refusing to write a checkpoint at step {steps} over the one at step {self.min_timesteps} "
                f"in {str(self.checkpoint_dir)!r}: checkpoints never go backwards"
            )
        self.checkpoint_dir.mkdir(parents=True, exist_ok=True)
        model = self.model
        model_name = f"model_{steps}.zip"
        atomic_write(self.checkpoint_dir / model_name, lambda tmp: model.save(tmp))
        buffer_name: str | None = None
        if replay_buffer and isinstance(model, OffPolicyAlgorithm) and model.replay_buffer is not None:
            buffer_name = f"replay_buffer_{steps}.pkl"
            atomic_write(self.checkpoint_dir / buffer_name, model.save_replay_buffer)
        state = {"num_timesteps": steps, "model": model_name, "replay_buffer": buffer_name}
        if self.extra_state is not None:
            state.update(self.extra_state())
        path = atomic_write_json(self.checkpoint_dir / STATE_FILE, state)
        keep = {model_name, buffer_name, STATE_FILE}
        for old in self.checkpoint_dir.glob("*"):
            if old.name not in keep and not old.name.startswith("."):
                old.unlink(missing_ok=True)
        # Temporaries of a run killed mid-write (this agent is the folder's only writer, so none is live).
        remove_stale_temporaries(self.checkpoint_dir)
        self._last_saved = steps
        return path


def read_checkpoint_state(checkpoint_dir: str | Path) -> dict[str, Any] | None:
    """The last complete checkpoint's state (with absolute file paths), or ``None`` if there is none."""
    path = Path(checkpoint_dir) / STATE_FILE
    if not path.exists():
        return None
    try:
        state = read_json_file(path)
        model, buffer = state["model"], state["replay_buffer"]
    except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError):
        # state.json is written atomically, so this is damage from outside, not from a kill.
        raise ValueError(f"Not a valid checkpoint state file: {str(path)!r}") from None
    state["model_path"] = Path(checkpoint_dir) / model
    state["replay_buffer_path"] = Path(checkpoint_dir) / buffer if buffer else None
    for key in ("model_path", "replay_buffer_path"):
        if state[key] is not None and not state[key].is_file():
            raise FileNotFoundError(f"Checkpoint {str(path)!r} names a missing file: {str(state[key])!r}")
    return state


def checkpoint_record(checkpoint_dir: str | Path) -> dict[str, Any] | None:
    """
    What an agent's last checkpoint records it was trained with (``algo``, ``seed``, ``config``, as a
    manifest entry would), for an agent killed before its manifest entry was written; ``None`` without one.
    """
    state = read_checkpoint_state(checkpoint_dir)
    if state is None:
        return None
    return {key: state[key] for key in ("algo", "seed", "config") if key in state}

"""
Nothing lost, nothing half-written: ``train-workers`` really killed with SIGKILL, at random moments and in
the middle of checkpoint writes, always leaves a loadable checkpoint, and ``--resume`` finishes the run.
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import time
from pathlib import Path

from stable_baselines3 import DDPG

from sb3_hddpg.artifacts.run_folder import mark_run_folder
from tests.cli_runner import CLI, run_cli

# A large replay buffer on purpose: its checkpoint takes long enough to write that a kill lands mid-write.
CONFIG = """\
default:
  n_timesteps: 1200
  policy: 'MlpPolicy'
  buffer_size: 60000
  learning_starts: 100
  batch_size: 16
  noise_type: 'normal'
  noise_std: 0.2
  policy_kwargs: "dict(net_arch=[16])"
"""
TOTAL = 1200


def command(config: Path, out: Path, resume: bool) -> list[str]:
    args = ["train-workers", "--workers", "goal", "--config", str(config), "--timesteps", str(TOTAL)]
    args += ["--checkpoint-freq", "100", "--eval-freq", "0", "--eval-episodes", "1", "--no-progress"]
    return [*args, "--out", str(out), *(["--resume"] if resume else [])]


def temporaries(folder: Path) -> list[Path]:
    return [p for p in folder.rglob(".*.tmp") if p.is_file()] if folder.exists() else []


def state_mtime(state: Path) -> int:
    try:
        return state.stat().st_mtime_ns
    except FileNotFoundError:
        return 0


def check_checkpoint(checkpoints: Path, finished: bool = False) -> int:
    """
    The state file names complete, loadable files; returns the steps it records. A finished run's
    checkpoint holds the model only (its replay buffer is dropped); an interrupted one's holds both.
    """
    state_path = checkpoints / "state.json"
    if not state_path.exists():
        return 0
    state = json.loads(state_path.read_text())
    model = DDPG.load(checkpoints / state["model"], device="cpu")  # our own file: the full loader is fine
    assert model.num_timesteps == state["num_timesteps"]
    if finished:
        assert state["replay_buffer"] is None and not list(checkpoints.glob("*.pkl"))
    else:
        model.load_replay_buffer(checkpoints / state["replay_buffer"])
        assert model.replay_buffer.size() > 0
    return state["num_timesteps"]


def kill_when(process: subprocess.Popen, ready, timeout: float = 120.0) -> bool:
    """Poll ``ready()`` every few milliseconds and SIGKILL the process the moment it holds; False if it ended first."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if process.poll() is not None:
            return False
        if ready():
            process.send_signal(signal.SIGKILL)
            process.wait(timeout=60)
            return True
        time.sleep(0.003)  # fast enough to land inside a replay-buffer write of ~20 MB
    process.send_signal(signal.SIGKILL)
    process.wait(timeout=60)
    return True


def trigger(moment: str, checkpoints: Path, before: int, old_debris: set[Path], pause: float):
    """When to kill: a callable that turns true at the chosen moment of a run."""
    state = checkpoints / "state.json"
    if moment == "mid-write":  # a temporary file of this run exists: a checkpoint is being written
        return lambda: bool(set(temporaries(checkpoints)) - old_debris)
    if moment == "after-state":  # the state file was just replaced; old files are not yet removed
        return lambda: state_mtime(state) != before
    seen: list[float] = []  # random: a random pause after this run's first checkpoint

    def ready() -> bool:
        if not seen and state_mtime(state) != before:
            seen.append(time.monotonic())
        return bool(seen) and time.monotonic() - seen[0] >= pause

    return ready


def test_sigkill_at_any_moment_leaves_a_loadable_checkpoint_and_resume_finishes(tmp_path):
    config = tmp_path / "kill.yml"
    config.write_text(CONFIG)
    out = tmp_path / "run"
    checkpoints = out / "checkpoints" / "goal"
    state = checkpoints / "state.json"
    rng = random.Random(0)
    env = {**os.environ, "SDL_VIDEODRIVER": "dummy"}
    # The moments: during a checkpoint write (a temporary file exists), just after a state file was
    # replaced (before old files are cleaned), and at random times between checkpoints.
    moments = ["mid-write", "after-state", "random", "mid-write"]
    killed_mid_write = 0
    progress = [0]
    for round_number, moment in enumerate(moments):
        before, old_debris = state_mtime(state), set(temporaries(checkpoints))
        process = subprocess.Popen(
            [*CLI, *command(config, out, resume=round_number > 0)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            env=env,
        )
        ready = trigger(moment, checkpoints, before, old_debris, pause=rng.uniform(0.0, 0.4))
        if not kill_when(process, ready):
            break  # finished before the moment came: nothing left to kill
        killed_mid_write += moment == "mid-write" and bool(set(temporaries(checkpoints)) - old_debris)
        progress.append(check_checkpoint(checkpoints))
    assert progress[-1] < TOTAL, "the run finished before it could be killed; raise TOTAL"
    assert progress == sorted(progress), f"a kill lost a checkpoint: {progress}"
    assert killed_mid_write >= 1, "no kill landed during a checkpoint write"

    # Debris of the kills, and some planted junk that looks like it, must not break the resumed run.
    (checkpoints / ".model_999999.zip.junk.tmp").write_bytes(b"half a zip")
    (out / "workers").mkdir(exist_ok=True)
    (out / "workers" / ".goal.zip.junk.tmp").write_bytes(b"half a zip")
    result = run_cli(*command(config, out, resume=True), check=True)
    assert "goal" in result.stdout
    manifest = json.loads((out / "workers" / "manifest.json").read_text())
    assert manifest["workers"]["goal"]["timesteps_trained"] == TOTAL
    assert check_checkpoint(checkpoints, finished=True) == TOTAL
    assert temporaries(out) == [], temporaries(out)
    # And the result is usable: the worker evaluates through its manifest.
    run_cli("evaluate", out / "workers" / "goal.zip", "--episodes", "1", check=True)


def test_a_crash_before_the_first_checkpoint_needs_no_cleanup(tmp_path):
    # Killed during start-up or the first steps: no state file yet. --resume starts afresh, and stale
    # temporaries in every folder the run writes are cleared.
    config = tmp_path / "kill.yml"
    config.write_text(CONFIG.replace("n_timesteps: 1200", "n_timesteps: 300"))
    out = tmp_path / "run"
    mark_run_folder(out, "train-workers")  # the first thing the command writes, before any of these
    for folder in ("checkpoints/goal", "best/goal", "workers", "evaluations"):
        (out / folder).mkdir(parents=True)
    junk = [
        out / "checkpoints" / "goal" / ".replay_buffer_100.pkl.x1.tmp",
        out / "best" / "goal" / ".best_model.zip.x2.tmp",
        out / "workers" / ".goal.zip.x3.tmp",
        out / "evaluations" / ".goal.json.x4.tmp",
    ]
    for path in junk:
        path.write_bytes(b"\0" * 10)
    args = command(config, out, resume=True)
    args[args.index("--timesteps") + 1] = "300"
    run_cli(*args, check=True)
    assert (
        json.loads((out / "workers" / "manifest.json").read_text())["workers"]["goal"]["timesteps_trained"]
        == 300
    )
    assert temporaries(out) == []


def test_train_manager_survives_sigkill_and_resume_writes_a_verified_bundle(tmp_path):
    # The manager goes through the same checkpoint code as the workers, but with its own env (the
    # selection wrapper over loaded workers) and its own outputs (the bundle): kill it for real too.
    from sb3_hddpg import Hierarchy
    from sb3_hddpg.training.workers import train_workers

    config = tmp_path / "kill.yml"
    config.write_text(CONFIG + "manager:\n" + CONFIG.split("\n", 1)[1])
    train_workers(tmp_path / "w", config=config, timesteps=150, eval_freq=0, eval_episodes=1)
    out = tmp_path / "m"
    checkpoints = out / "checkpoints" / "manager"
    state = checkpoints / "state.json"
    args = ["train-manager", "--workers", str(tmp_path / "w"), "--config", str(config)]
    args += ["--timesteps", str(TOTAL), "--checkpoint-freq", "100", "--eval-freq", "0"]
    args += ["--eval-episodes", "1", "--no-progress", "--out", str(out)]
    progress = [0]
    for round_number, moment in enumerate(["mid-write", "random"]):
        before, old_debris = state_mtime(state), set(temporaries(checkpoints))
        process = subprocess.Popen(
            [*CLI, *args, *(["--resume"] if round_number else [])],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
        )
        assert kill_when(process, trigger(moment, checkpoints, before, old_debris, pause=0.2))
        progress.append(check_checkpoint(checkpoints))
    assert 0 < progress[-1] < TOTAL and progress == sorted(progress), progress
    assert not (out / "hierarchy.zip").exists()  # nothing final was written by a killed run

    run_cli(*args, "--resume", check=True)
    assert check_checkpoint(checkpoints, finished=True) == TOTAL
    assert temporaries(out) == []
    hierarchy = Hierarchy.load(out / "hierarchy.zip")  # every member's sha256 verified
    # The bundle holds the resumed run's final manager: the weights of the last checkpoint.
    final = DDPG.load(checkpoints / json.loads(state.read_text())["model"], device="cpu")
    for name, tensor in final.policy.state_dict().items():
        assert (hierarchy.manager.policy.state_dict()[name] == tensor).all(), name

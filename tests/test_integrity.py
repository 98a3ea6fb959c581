"""
Nothing a user made is lost or silently rewound: one writer per run folder, manifests updated under its
lock, checkpoints that never go backwards (docs/ROBUSTNESS.md, "Integrity").
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from stable_baselines3 import DDPG

from sb3_hddpg.artifacts.io import LOCK_FILE, FolderLockedError, atomic_write, locked_folder
from sb3_hddpg.training.agent import sigterm_as_interrupt
from tests.cli_runner import CLI

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
    from sb3_hddpg.training.manager import train_manager
    from sb3_hddpg.training.workers import train_workers

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

    manifest = train_workers(out, workers=["goal"], resume=True, **quick).manifest

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


def _train_workers_cli(out: Path, config: Path, worker: str) -> subprocess.Popen:
    args = ["train-workers", "--no-progress", "--workers", worker, "--config", str(config), "--out", str(out)]
    args += ["--timesteps", "300", "--eval-freq", "0", "--eval-episodes", "1", "--checkpoint-freq", "0"]
    env = {**os.environ, "SDL_VIDEODRIVER": "dummy", "COLUMNS": "200", "PYTHONPATH": str(ROOT)}
    env.pop("HDDPG_HELD_FOLDERS", None)
    return subprocess.Popen(
        [*CLI, *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )


def test_a_second_run_into_a_locked_folder_is_refused_with_the_holders_pid(tmp_path: Path) -> None:
    from sb3_hddpg.training.workers import train_workers

    config = tmp_path / "tiny.yml"
    config.write_text(TINY)
    out = tmp_path / "out"
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            textwrap.dedent(
                f"""
                import time
                from sb3_hddpg.artifacts.io import locked_folder
                with locked_folder({str(out)!r}):
                    print("locked", flush=True)
                    time.sleep(300)
                """
            ),
        ],
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "locked"
        assert (out / LOCK_FILE).read_text().strip() == str(holder.pid)
        cli = _train_workers_cli(out, config, "goal")
        _, stderr = cli.communicate(timeout=300)
        lines = [line for line in stderr.splitlines() if line.strip()]
        assert cli.returncode == 2 and len(lines) == 1, stderr
        assert lines[0].startswith("error: ") and "--out" in lines[0] and f"pid {holder.pid}" in lines[0]
        with pytest.raises(FolderLockedError, match=f"pid {holder.pid}"):
            train_workers(out, workers=["goal"], config=config, timesteps=50, eval_freq=0)
        assert not (out / "workers").exists()
    finally:
        holder.kill()  # SIGKILL: the operating system releases the lock
        holder.wait()
    with locked_folder(out), locked_folder(out):  # re-entrant within a process
        pass


@pytest.mark.slow  # two training processes at once: ~35 s on a shared machine
def test_two_runs_started_together_into_one_folder_lose_nothing(tmp_path: Path) -> None:
    """The issue's race: both used to exit 0 while the manifest listed only one worker."""
    config = tmp_path / "tiny.yml"
    config.write_text(TINY)
    out = tmp_path / "shared"
    runs = {worker: _train_workers_cli(out, config, worker) for worker in ("goal", "avoid")}
    results = {worker: (run.wait(timeout=600), run.stderr.read()) for worker, run in runs.items()}  # type: ignore[union-attr]
    assert sorted(code for code, _ in results.values()) == [0, 2], results
    winner = next(worker for worker, (code, _) in results.items() if code == 0)
    loser_message = next(err for code, err in results.values() if code == 2)
    assert "in use by another run" in loser_message or "already holds results" in loser_message
    manifest = json.loads((out / "workers" / "manifest.json").read_text())
    assert list(manifest["workers"]) == [winner]
    assert sorted(p.name for p in (out / "workers").glob("*.zip")) == [f"{winner}.zip"]


def test_manifests_are_read_modify_write(tmp_path: Path) -> None:
    """Two runs one after the other into one folder (the Python API): both workers stay listed."""
    from sb3_hddpg.artifacts.manifests import load_workers
    from sb3_hddpg.training.workers import train_workers

    config = tmp_path / "tiny.yml"
    config.write_text(TINY)
    quick = {"config": config, "timesteps": 60, "eval_freq": 0, "eval_episodes": 1, "checkpoint_freq": 0}
    train_workers(tmp_path / "w", workers=["goal"], **quick)
    manifest = train_workers(tmp_path / "w", workers=["avoid"], **quick).manifest
    on_disk = json.loads((tmp_path / "w" / "workers" / "manifest.json").read_text())
    assert set(on_disk["workers"]) == {"goal", "avoid"} and set(manifest["workers"]) >= {"avoid"}
    workers = load_workers(tmp_path / "w")
    assert set(workers) == {"goal", "avoid"}


def test_a_full_disk_names_the_file(tmp_path: Path) -> None:
    """A write that runs out of space (a file-size limit stands in for a full disk) names its file."""
    target = tmp_path / "out" / "results.json"
    code = textwrap.dedent(
        f"""
        import resource, signal
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # EFBIG instead of being killed
        resource.setrlimit(resource.RLIMIT_FSIZE, (1 << 16, 1 << 16))
        from sb3_hddpg.artifacts.io import atomic_write_bytes
        try:
            atomic_write_bytes({str(target)!r}, bytes(1 << 20))
        except OSError as error:
            print(error)
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    assert done.returncode == 0, done.stderr
    assert str(target) in done.stdout and "Errno" in done.stdout, done.stdout
    assert not target.exists() and not list(target.parent.glob(".*.tmp"))


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_stop_signal_during_a_save_waits_for_the_file_then_interrupts(tmp_path: Path, signum: int) -> None:
    """
    Ctrl-C or SIGTERM arriving while a model is being saved: the save completes, then the interrupt
    takes its usual path. (Raised inside torch's zip writer, it came out as ``RuntimeError: unexpected
    pos`` and a stopped run failed instead of saving its checkpoint.)
    """
    model = DDPG("MlpPolicy", "Pendulum-v1", policy_kwargs={"net_arch": [16]}, device="cpu")
    target = tmp_path / "model.zip"

    def save_while_signalled(tmp: Path) -> None:
        os.kill(os.getpid(), signum)
        model.save(tmp)

    # Python's own Ctrl-C handler, whatever this process inherited: a shell starts a background job with
    # SIGINT ignored, and Python then installs no handler of its own.
    inherited = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with sigterm_as_interrupt(), pytest.raises(KeyboardInterrupt):
            atomic_write(target, save_while_signalled)
        DDPG.load(target, device="cpu")  # complete
        assert not list(tmp_path.glob(".*.tmp"))
        # The handlers in place before are back.
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, inherited)


def test_released_locks_leave_no_lock_files(tmp_path):
    from sb3_hddpg.artifacts.io import locked_file

    with locked_folder(tmp_path / "run"):
        with locked_file(tmp_path / "run" / "manifest.json"):
            assert (tmp_path / "run" / ".manifest.json.lock").exists()
        assert (tmp_path / "run" / LOCK_FILE).exists()
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == []
    with locked_folder(tmp_path / "run"):  # and the folder can be locked again
        pass

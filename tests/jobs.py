"""
The job functions of the process runner's tests, for every executor: module-level, so that a spawned process
imports them by name; the Ray cluster fixture (tests/conftest.py) ships them to Ray's workers by value.
"""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

from hddpg_zoo.runner import report_progress


def square(x: int) -> int:
    report_progress(x)
    return x * x


def broken(message: str) -> int:
    raise ValueError(message)


def die() -> int:
    """Kills its own process, as a crash, the out-of-memory killer or a lost node would."""
    os.kill(os.getpid(), signal.SIGKILL)
    return 0


def die_once(folder: str) -> str:
    """Kills its own process the first time (as a lost node would), returns on the retry."""
    marker = Path(folder) / "died-once"
    if not marker.exists():
        marker.write_text(str(os.getpid()))
        die()
    return f"retried after {marker.read_text()}"


def pid_after(seconds: float) -> int:
    time.sleep(seconds)
    return os.getpid()


def where(name: str) -> tuple[int, int, str]:
    """Writes a file by a relative path (it lands in the driver's working directory) and says who ran it."""
    import ray

    Path(name).write_text(str(os.getpid()))
    return os.getpid(), int(ray.get_runtime_context().get_assigned_resources()["CPU"]), os.getcwd()


#: How long the long jobs run unless stopped: far beyond what a stop may take on a loaded machine, so a
#: test that bounds the stop by :data:`STOP_BOUND` tells a stop from a wait for the job's end.
LONG_JOB_SECONDS = 600
STOP_BOUND = LONG_JOB_SECONDS / 2


def checkpoint_on_interrupt(folder: str) -> int:
    """
    A long job that, like ``train_agent``, turns SIGTERM (the local executor's stop) or a ``KeyboardInterrupt``
    (Ray's non-forced cancel) into saving a checkpoint and stopping.
    """
    from sb3_hddpg.training.agent import sigterm_as_interrupt

    with sigterm_as_interrupt():
        try:
            (Path(folder) / f"started-{os.getpid()}").touch()
            for _ in range(
                10 * LONG_JOB_SECONDS
            ):  # short sleeps, like training steps: Ray's interrupt lands between them
                time.sleep(0.1)
        except KeyboardInterrupt:
            (Path(folder) / f"checkpoint-{os.getpid()}").touch()
            raise
    return 0


def blocked_in_c(folder: str) -> int:
    """A long job blocked in C code (one long sleep), which Ray's non-forced cancel cannot interrupt."""
    (Path(folder) / f"started-{os.getpid()}").touch()
    time.sleep(LONG_JOB_SECONDS)
    return 0


def started_pids(folder: Path) -> set[str]:
    """The processes that started one of the jobs above in ``folder``."""
    return {p.name.split("-")[1] for p in folder.glob("started-*")}


def checkpointed_pids(folder: Path) -> set[str]:
    """The processes that saved a checkpoint in ``folder`` when interrupted."""
    return {p.name.split("-")[1] for p in folder.glob("checkpoint-*")}


def sigterm_once_started(folder: Path, count: int, timeout: float = 120) -> None:
    """SIGTERM this process (the driver), from a thread, once ``count`` of the jobs above started in ``folder``."""

    def send() -> None:
        deadline = time.monotonic() + timeout
        while len(started_pids(folder)) < count and time.monotonic() < deadline:
            time.sleep(0.1)
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=send, daemon=True).start()

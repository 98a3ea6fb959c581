"""
:func:`local_ray_head`: a throw-away Ray head on loopback, as ``ray start --head`` makes one, for tests and
benchmarks that point ``--executor ray`` at a real cluster.

    >>> with local_ray_head(num_cpus=2, log=Path("head.log")) as head:  # doctest: +SKIP
    ...     subprocess.run(["hddpg-cli", "benchmark", "--executor", "ray", "--ray-address", head.address],
    ...                    env={**os.environ, **LOOPBACK_ENV})

The head runs without Ray's token authentication (:data:`LOOPBACK_ENV`), which is safe on loopback only; a
driver that connects to it needs the same variable. A real cluster keeps authentication (docs/CLUSTER.md).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

from hddpg_zoo.ray_executor import INSTALL_HINT, ClusterError

#: The environment of a loopback head and of the drivers that connect to it: no token to hand around
#: (Ray turns token authentication on by default since 2.5x; keep it on any network).
LOOPBACK_ENV: Mapping[str, str] = {"RAY_AUTH_MODE": "disabled"}
#: Seconds ``ray start`` may take to come up (minutes on a busy 2-core machine).
START_TIMEOUT = 300.0
#: Seconds ``ray start --block`` may take to stop what it started before it is killed.
STOP_TIMEOUT = 120.0
#: What ``ray start --block`` prints once every process of the head is up (its port opens well before).
_READY_LINE = "block forever"


@dataclass(frozen=True)
class LocalHead:
    """
    A running head of :func:`local_ray_head`.

    :param address: its ``127.0.0.1:PORT``, for ``--ray-address``.
    :param process: the ``ray start --block`` process.
    :param log: the file holding its output.
    """

    address: str
    process: subprocess.Popen[bytes]
    log: Path

    def describe(self) -> str:
        """Whether it is still running, and its output (for a failing test's message)."""
        state = "running" if self.process.poll() is None else f"exited with {self.process.returncode}"
        return f"Ray head at {self.address}: {state}\n{self.log.read_text()}"


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def _ray_command() -> str:
    """The ``ray`` command of this interpreter's environment (a venv's ``bin/``), else the one on ``PATH``."""
    beside = Path(sys.executable).parent / "ray"
    found = str(beside) if beside.exists() else shutil.which("ray")
    if found is None:
        raise ClusterError(f"the `ray` command is not installed: {INSTALL_HINT}")
    return found


@contextlib.contextmanager
def local_ray_head(
    num_cpus: int,
    log: Path,
    env: Mapping[str, str] | None = None,
    start_timeout: float = START_TIMEOUT,
) -> Iterator[LocalHead]:
    """
    Start ``ray start --head --block`` on a free loopback port, wait until it is up, and stop it after
    (only the processes it started: not ``ray stop``, which would stop every cluster of this machine).

    :param num_cpus: the CPUs the head offers to tasks.
    :param log: where its output goes (read to know when it is up).
    :param env: the environment of the ``ray start`` process (default: this one), with :data:`LOOPBACK_ENV`.
    :param start_timeout: seconds it may take to come up.
    :return: the running head.
    :raises ClusterError: Ray is not installed, or the head exits or is not up within ``start_timeout``.
    """
    port = _free_port()
    command = [
        _ray_command(),
        "start",
        "--head",
        "--block",
        f"--port={port}",
        "--node-ip-address=127.0.0.1",
        f"--num-cpus={num_cpus}",
        "--include-dashboard=false",
        "--disable-usage-stats",
    ]
    # Short (under /tmp): Ray's socket paths live in it and have a length limit.
    temp_dir = tempfile.mkdtemp(prefix="ray-", dir="/tmp")
    try:
        with log.open("w") as output:
            process = subprocess.Popen(
                [*command, f"--temp-dir={temp_dir}"],
                env={**(os.environ if env is None else env), **LOOPBACK_ENV},
                stdout=output,
                stderr=subprocess.STDOUT,
            )
        head = LocalHead(f"127.0.0.1:{port}", process, log)
        try:
            deadline = time.monotonic() + start_timeout
            while _READY_LINE not in log.read_text():
                if process.poll() is not None or time.monotonic() > deadline:
                    raise ClusterError(f"`ray start --head` did not come up: {head.describe()[-2000:]}")
                time.sleep(0.5)
            yield head
        finally:
            process.terminate()  # `ray start --block` stops the processes it started on SIGTERM
            try:
                process.wait(timeout=STOP_TIMEOUT)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
    finally:
        shutil.rmtree(temp_dir, ignore_errors=True)

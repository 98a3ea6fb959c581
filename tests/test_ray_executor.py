"""
What only the Ray executor does, on a real local Ray cluster: CPUs and working directory,
retries, killing tasks a cancel does not stop, the cluster's address, the CLI on a ``ray start`` head. What
every executor does (results, failures, progress, interrupts) is in tests/test_runner.py, for both.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

pytest.importorskip("ray")

from hddpg_zoo.ray_executor import CONNECT_TIMEOUT, ClusterError, RayExecutor, check_address, parse_address
from hddpg_zoo.runner import Job, run_jobs
from tests.cli_runner import CLI
from tests.jobs import (
    STOP_BOUND,
    blocked_in_c,
    checkpoint_on_interrupt,
    checkpointed_pids,
    die_once,
    sigterm_once_started,
    started_pids,
    where,
)
from tests.ray_head import LOOPBACK_ENV, local_ray_head


def test_a_task_gets_its_threads_as_cpus_in_the_drivers_working_directory(ray_cluster, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    executor = RayExecutor()
    outcome = run_jobs([Job("two-cpus", where, ("written-here.txt",), threads=2)], executor)
    assert executor.slots == 2  # the cluster's CPUs
    # Another process, given num_cpus = threads, in this process's working directory.
    pid, cpus, cwd = outcome.results["two-cpus"]
    assert pid != os.getpid() and cpus == 2 and Path(cwd) == tmp_path
    assert (tmp_path / "written-here.txt").read_text() == str(pid)


def test_a_task_whose_process_dies_is_retried(ray_cluster, tmp_path):
    outcome = run_jobs([Job("dies", die_once, (str(tmp_path),))], RayExecutor(max_retries=1))
    first_pid = (tmp_path / "died-once").read_text()
    assert outcome.results == {"dies": f"retried after {first_pid}"}


def test_a_task_a_cancel_does_not_stop_is_killed_after_the_grace_with_one_warning(
    ray_cluster, tmp_path, caplog
):
    # One task stops the resumable way when cancelled; the other, blocked in C code, does not.
    jobs = [
        Job("resumable", checkpoint_on_interrupt, (str(tmp_path),)),
        Job("blocked", blocked_in_c, (str(tmp_path),)),
    ]
    sigterm_once_started(tmp_path, 2)
    started = time.monotonic()
    with (
        caplog.at_level(logging.WARNING, logger="hddpg_zoo.ray_executor"),
        pytest.raises(KeyboardInterrupt),
    ):
        run_jobs(jobs, RayExecutor(cancel_grace=2.0))
    interrupted = time.monotonic()
    assert interrupted - started < STOP_BOUND  # nobody waited for the long jobs
    assert len(started_pids(tmp_path)) == 2
    (resumable_pid,) = checkpointed_pids(tmp_path)  # the resumable one saved its checkpoint...
    (blocked_pid,) = started_pids(tmp_path) - {resumable_pid}
    # ...the blocked one was killed (its process is gone, not left sleeping), and said so once.
    while psutil_alive(int(blocked_pid)) and time.monotonic() - interrupted < 30:
        time.sleep(0.1)
    assert not psutil_alive(int(blocked_pid))
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1, warnings
    assert "1 Ray task(s)" in warnings[0] and "(blocked)" in warnings[0] and "--resume" in warnings[0]


def psutil_alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie awaiting its parent's wait counts as gone)."""
    import psutil

    with contextlib.suppress(psutil.Error):
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    return False


def test_an_unreachable_or_malformed_address_is_one_clear_error():
    with socket.socket() as free:  # a port nobody listens on
        free.bind(("127.0.0.1", 0))
        port = free.getsockname()[1]
    started = time.monotonic()
    with pytest.raises(ClusterError, match=f"cannot reach a Ray cluster at '127.0.0.1:{port}'"):
        check_address(f"127.0.0.1:{port}")
    assert time.monotonic() - started < 10  # not ray.init's minutes of retries
    with pytest.raises(ClusterError, match="expected 'auto' or HOST:PORT"):
        check_address("no-port")


# ------------------------------------------------------------------------------------------- the CLI
REPO = Path(__file__).resolve().parents[1]


def cli_env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(REPO), "COLUMNS": "200", "SDL_VIDEODRIVER": "dummy"}


def test_without_ray_the_cli_says_how_to_install_it(tmp_path):
    # Ray hidden from a fresh interpreter, as on a machine without the cluster extra.
    code = (
        "import sys; sys.modules['ray'] = None; from sb3_hddpg.cli import main; "
        f"sys.argv = ['hddpg-cli', 'benchmark', '--executor', 'ray', '--out', {str(tmp_path / 'o')!r}]; main()"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=cli_env(), timeout=300
    )
    assert done.returncode == 2, done.stderr
    assert 'pip install "sb3-hddpg[cluster]"' in done.stderr and "Traceback" not in done.stderr
    assert not (tmp_path / "o").exists()  # refused before anything was made


@contextlib.contextmanager
def silent_server() -> Iterator[tuple[int, threading.Event]]:
    """A loopback port that accepts connections and never says a word (not Ray); the event: one came."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)
    accepted = threading.Event()
    held: list[socket.socket] = []

    def serve() -> None:
        with contextlib.suppress(OSError):
            while True:
                held.append(server.accept()[0])
                accepted.set()

    threading.Thread(target=serve, daemon=True).start()
    try:
        yield server.getsockname()[1], accepted
    finally:
        server.close()
        for connection in held:
            connection.close()


@pytest.mark.parametrize(
    "address",
    [
        "127.0.0.1:\u00b2",
        "127.0.0.1:\u0663",
        "127.0.0.1:0",
        "127.0.0.1:65536",
        "h\u00e9st:1",
        ":80",
        "a:b:c",
        "x" * 400,
    ],
)
def test_malformed_addresses_are_refused_by_the_one_parser(address):
    with pytest.raises(ClusterError, match="expected 'auto' or HOST:PORT") as refused:
        parse_address(address)
    assert len(str(refused.value)) < 200


def test_a_port_that_accepts_but_is_not_ray_is_refused_within_the_timeout():
    with silent_server() as (port, _):
        started = time.monotonic()
        with pytest.raises(ClusterError, match="accepts connections but is not a Ray head"):
            check_address(f"127.0.0.1:{port}", timeout=1.0)
        assert time.monotonic() - started < 3


def test_the_cli_refuses_a_non_ray_port_in_one_line_and_honours_sigterm(tmp_path):
    command = [
        *CLI,
        "benchmark",
        "--executor",
        "ray",
        "--out",
        str(tmp_path / "o"),
    ]
    with silent_server() as (port, _):
        done = subprocess.run(
            [*command, "--ray-address", f"127.0.0.1:{port}"],
            capture_output=True,
            text=True,
            env=cli_env(),
            timeout=120,
        )
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and "is not a Ray head" in done.stderr
    done = subprocess.run(
        [*command, "--ray-address", "127.0.0.1:\u00b2"],
        capture_output=True,
        text=True,
        env=cli_env(),
        timeout=120,
    )
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and "HOST:PORT" in done.stderr, done.stderr
    # SIGTERM while the CLI waits for the silent port's answer ends it at once.
    with silent_server() as (port, accepted):
        process = subprocess.Popen(
            [*command, "--ray-address", f"127.0.0.1:{port}"],
            env=cli_env(),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
        )
        try:
            assert accepted.wait(120), "the CLI never connected"
            process.send_signal(signal.SIGTERM)
            started = time.monotonic()
            process.wait(timeout=10)
            # Well inside the answer's wait (CONNECT_TIMEOUT), with room for a loaded machine's start-up.
            assert time.monotonic() - started < CONNECT_TIMEOUT / 2
        finally:
            process.kill()
            process.wait()
    assert not (tmp_path / "o").exists()


@pytest.fixture
def ray_head(tmp_path):
    """A Ray head of 2 CPUs on loopback, as `ray start --head` makes one; stopped after."""
    with local_ray_head(num_cpus=2, log=tmp_path / "ray-head.log", env=cli_env()) as head:
        yield head


# The tiny budgets of tests/test_benchmark.py.
TINY = (
    "--seeds", "2", "--methods", "hddpg,ham,ddpg", "--timesteps", "200", "--worker-timesteps", "100",
    "--eval-freq", "100", "--eval-episodes", "1", "--test-episodes", "1", "--n-jobs", "2",
)  # fmt: skip


def kill_one_task(label: str, seen_for: float = 1.0, timeout: float = 300) -> int:
    """SIGKILL the Ray worker process running the task ``label`` (its title: ``ray::LABEL``) once seen."""
    import psutil

    deadline = time.monotonic() + timeout
    first_seen: dict[int, float] = {}
    while time.monotonic() < deadline:
        for process in psutil.process_iter(["pid", "cmdline"]):
            with contextlib.suppress(psutil.Error):
                if (process.info["cmdline"] or [""])[0].startswith(f"ray::{label}"):
                    seen = first_seen.setdefault(process.pid, time.monotonic())
                    if time.monotonic() - seen >= seen_for:
                        process.kill()
                        return process.pid
        time.sleep(0.1)
    raise AssertionError(f"no Ray task {label} seen in {timeout} s")


def records(out: Path) -> dict[str, dict]:
    """Every task's record, without its wall times (this invocation's and every invocation's)."""
    found = {}
    for path in sorted((out / "records").glob("*/seed-*.json")):
        record = json.loads(path.read_text())
        record.pop("wall_time_s")
        record.pop("wall_time_s_total")
        found[f"{path.parent.name}/{path.stem}"] = record
    return found


@pytest.mark.slow  # two tiny benchmarks (local, then Ray with a worker killed): minutes
def test_benchmark_on_a_ray_cluster_survives_a_killed_worker_and_matches_local(ray_head, tmp_path):
    command = [
        *CLI, "benchmark", *TINY, "--out", str(tmp_path / "ray"),
        "--executor", "ray", "--ray-address", ray_head.address,
    ]  # fmt: skip
    env = {**cli_env(), **LOOPBACK_ENV}
    with subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=REPO
    ) as run:
        killed = kill_one_task("workers/seed-0")  # mid-training: its retry must finish the seed's workers
        stdout, stderr = run.communicate(timeout=900)
    assert run.returncode == 0, f"{stdout}\n{stderr}\n{ray_head.describe()}"
    assert killed > 0

    local = subprocess.run(
        [*CLI, "benchmark", *TINY, "--out", str(tmp_path / "local")],
        capture_output=True, text=True, env=cli_env(), timeout=900, cwd=REPO,
    )  # fmt: skip
    assert local.returncode == 0, local.stdout + local.stderr

    # The same results file, key for key, and the same numbers: every run is seeded and deterministic.
    ours, theirs = (json.loads((tmp_path / n / "results.json").read_text()) for n in ("ray", "local"))
    assert ours.keys() == theirs.keys() and ours["methods"].keys() == theirs["methods"].keys()
    assert records(tmp_path / "ray") == records(tmp_path / "local")
    for method, entry in theirs["methods"].items():
        assert ours["methods"][method]["stats"] == entry["stats"], method

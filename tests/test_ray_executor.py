"""The Ray executor (issue 17) on a real local Ray cluster: results, dependencies, failures, retries, interrupts."""

from __future__ import annotations

import os
import signal
import socket
import sys
import threading
import time
from pathlib import Path

import pytest

ray = pytest.importorskip("ray")

from sb3_hddpg.experiments.ray_executor import ClusterError, RayExecutor, check_address  # noqa: E402
from sb3_hddpg.experiments.runner import Job, report_progress, run_jobs  # noqa: E402

# The job functions below live in this test module, which Ray's worker processes cannot import by name.
ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])


def square(x: int) -> int:
    report_progress(x)
    return x * x


def broken(message: str) -> int:
    raise ValueError(message)


def where(name: str) -> tuple[int, int, str]:
    """Writes a file by a relative path (it lands in the driver's working directory) and says who ran it."""
    Path(name).write_text(str(os.getpid()))
    return os.getpid(), int(ray.get_runtime_context().get_assigned_resources()["CPU"]), os.getcwd()


def die_once(folder: str) -> str:
    """Kills its own process the first time (as a lost node would), returns on the retry."""
    marker = Path(folder) / "died-once"
    if not marker.exists():
        marker.write_text(str(os.getpid()))
        os.kill(os.getpid(), signal.SIGKILL)
    return f"retried after {marker.read_text()}"


def checkpoint_on_interrupt(folder: str) -> int:
    """A long job that, like ``train_agent``, turns an interrupt into saving a checkpoint and stopping."""
    try:
        (Path(folder) / f"started-{os.getpid()}").touch()
        for _ in range(1200):  # short sleeps, like training steps: Ray's interrupt lands between them
            time.sleep(0.1)
    except KeyboardInterrupt:
        (Path(folder) / f"checkpoint-{os.getpid()}").touch()
        raise
    return 0


@pytest.fixture(scope="module")
def cluster():
    """A local Ray cluster of 2 CPUs in this process, no dashboard (a few seconds to start)."""
    ray.init(num_cpus=2, include_dashboard=False, logging_level="WARNING")
    yield
    ray.shutdown()


def test_results_dependencies_failures_and_progress_through_ray(cluster, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    progress: dict[str, float] = {}
    order: list[str] = []
    jobs = [
        Job("base", square, (3,)),
        Job("after-base", square, (4,), after=("base",)),
        Job("bad", broken, ("on a Ray worker",)),
        Job("needs-bad", square, (5,), after=("bad",)),
        Job("two-cpus", where, ("written-here.txt",), threads=2),
    ]
    executor = RayExecutor()
    outcome = run_jobs(
        jobs,
        executor,
        on_event=lambda kind, job, value: order.append(f"{kind} {job.key}"),
        on_progress=progress.__setitem__,
    )
    assert executor.slots == 2  # the cluster's CPUs
    assert outcome.results["base"] == 9 and outcome.results["after-base"] == 16
    assert order.index("done base") < order.index("start after-base")
    assert progress == {"base": 3, "after-base": 4}  # relayed from the tasks to this process
    # The job's own error, re-created here, fails it and its dependant only.
    assert outcome.failure_message("bad") == "ValueError: on a Ray worker"
    assert outcome.failure_message("needs-bad").startswith("RuntimeError: bad failed: ValueError")
    # Another process, given num_cpus = threads, in this process's working directory.
    pid, cpus, cwd = outcome.results["two-cpus"]
    assert pid != os.getpid() and cpus == 2 and Path(cwd) == tmp_path
    assert (tmp_path / "written-here.txt").read_text() == str(pid)


def test_a_task_whose_process_dies_is_retried_and_without_retries_fails_alone(cluster, tmp_path):
    retried = tmp_path / "retried"
    retried.mkdir()
    outcome = run_jobs([Job("dies", die_once, (str(retried),))], RayExecutor(max_retries=1))
    first_pid = (retried / "died-once").read_text()
    assert outcome.results == {"dies": f"retried after {first_pid}"}

    lost = tmp_path / "lost"
    lost.mkdir()
    jobs = [Job("dies", die_once, (str(lost),)), Job("fine", square, (2,))]
    outcome = run_jobs(jobs, RayExecutor(max_retries=0))
    assert outcome.results == {"fine": 4}
    assert type(outcome.failures["dies"]).__name__ == "WorkerCrashedError"


def test_sigterm_to_the_driver_cancels_running_tasks_the_resumable_way(cluster, tmp_path):
    jobs = [Job(f"long-{i}", checkpoint_on_interrupt, (str(tmp_path),)) for i in range(3)]

    def sigterm_once_two_started() -> None:
        deadline = time.monotonic() + 60
        while len(list(tmp_path.glob("started-*"))) < 2 and time.monotonic() < deadline:
            time.sleep(0.1)
        os.kill(os.getpid(), signal.SIGTERM)

    handler = signal.getsignal(signal.SIGTERM)
    threading.Thread(target=sigterm_once_two_started, daemon=True).start()
    started = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        run_jobs(jobs, RayExecutor(interrupt_grace=0.5))
    assert time.monotonic() - started < 60  # nobody waited for the 120 s jobs
    # The two running tasks got the interrupt and saved their checkpoints; the third never started.
    started_pids = {p.name.split("-")[1] for p in tmp_path.glob("started-*")}
    assert len(started_pids) == 2
    assert {p.name.split("-")[1] for p in tmp_path.glob("checkpoint-*")} == started_pids
    assert signal.getsignal(signal.SIGTERM) is handler


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

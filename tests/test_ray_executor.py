"""The Ray executor (issue 17) on a real local Ray cluster: results, dependencies, failures, retries, interrupts."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
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


# Slow, and out of the default run: in one fresh-clone CI run (2026-11-30) the driver waited 124 s, about the
# jobs' own length, as if a non-forced ray.cancel had not reached a running task; cause not found yet.
@pytest.mark.slow
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


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def head_env() -> dict[str, str]:
    # A loopback test cluster: without Ray's token authentication (on by default since Ray 2.5x), which
    # a real cluster keeps (docs/CLUSTER.md).
    return {**cli_env(), "RAY_AUTH_MODE": "disabled"}


@pytest.fixture
def ray_head(tmp_path):
    """A Ray head of 2 CPUs on loopback, as `ray start --head` makes one; its address. Stopped after."""
    port = free_port()
    temp_dir = tempfile.mkdtemp(prefix="ray-", dir="/tmp")  # short: Ray's socket paths have a length limit
    log = tmp_path / "ray-head.log"
    with log.open("w") as output:
        head = subprocess.Popen(
            [
                str(Path(sys.executable).parent / "ray"),
                "start",
                "--head",
                "--block",
                f"--port={port}",
                "--node-ip-address=127.0.0.1",
                "--num-cpus=2",
                "--include-dashboard=false",
                "--disable-usage-stats",
                f"--temp-dir={temp_dir}",
            ],
            env=head_env(),
            stdout=output,
            stderr=subprocess.STDOUT,
        )
    try:
        # Up once `ray start` says it blocks (its GCS port opens well before the rest is ready).
        deadline = time.monotonic() + 180
        while "block forever" not in log.read_text() and time.monotonic() < deadline:
            assert head.poll() is None, f"ray start exited:\n{log.read_text()}"
            time.sleep(0.5)
        yield f"127.0.0.1:{port}", head, log
    finally:
        head.terminate()  # `ray start --block` stops the processes it started (only ours: not `ray stop`)
        head.wait(timeout=90)
        shutil.rmtree(temp_dir, ignore_errors=True)


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
    """Every task's record, without its wall time."""
    found = {}
    for path in sorted((out / "records").glob("*/seed-*.json")):
        record = json.loads(path.read_text())
        record.pop("wall_time_s")
        found[f"{path.parent.name}/{path.stem}"] = record
    return found


@pytest.mark.slow  # two tiny benchmarks (local, then Ray with a worker killed): minutes
def test_benchmark_on_a_ray_cluster_survives_a_killed_worker_and_matches_local(ray_head, tmp_path):
    address, head, log = ray_head
    command = [
        sys.executable, str(REPO / "cli.py"), "benchmark", *TINY, "--out", str(tmp_path / "ray"),
        "--executor", "ray", "--ray-address", address,
    ]  # fmt: skip
    with subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=head_env(), cwd=REPO
    ) as run:
        killed = kill_one_task("workers/seed-0")  # mid-training: its retry must finish the seed's workers
        stdout, stderr = run.communicate(timeout=900)
    assert run.returncode == 0, f"{stdout}\n{stderr}\nhead alive: {head.poll() is None}\n{log.read_text()}"
    assert killed > 0

    local = subprocess.run(
        [sys.executable, str(REPO / "cli.py"), "benchmark", *TINY, "--out", str(tmp_path / "local")],
        capture_output=True, text=True, env=cli_env(), timeout=900, cwd=REPO,
    )  # fmt: skip
    assert local.returncode == 0, local.stdout + local.stderr

    # The same results file, key for key, and the same numbers: every run is seeded and deterministic.
    ours, theirs = (json.loads((tmp_path / n / "results.json").read_text()) for n in ("ray", "local"))
    assert ours.keys() == theirs.keys() and ours["methods"].keys() == theirs["methods"].keys()
    assert records(tmp_path / "ray") == records(tmp_path / "local")
    for method, entry in theirs["methods"].items():
        assert ours["methods"][method]["stats"] == entry["stats"], method

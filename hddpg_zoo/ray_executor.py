"""
:class:`RayExecutor`: the process runner's jobs as Ray tasks on an existing Ray cluster.

The same four methods as :class:`~hddpg_zoo.runner.LocalProcessExecutor` (``open``, ``submit``,
``wait``, ``stop``), so :func:`~hddpg_zoo.runner.run_jobs` schedules cluster jobs exactly as local
ones (dependencies, groups, longest first, per-job failures). Ray is imported only here, and only when an
executor is opened: the package and every ``--help`` work without it (``pip install "sb3-hddpg[cluster]"``).

**What runs where.** The driver (the ``hddpg-cli`` process) schedules, relays progress and writes the
results; each job is one Ray task with ``num_cpus`` = its ``threads`` (Ray then sets its torch/OpenMP
threads to match), on whichever node has room.

**Shared filesystem assumed.** A task runs in the driver's working directory, on its node, and writes its
own folder under ``--out`` as a local job would; every node must therefore see the driver's working
directory and ``--out`` at the same paths (NFS, a cluster filesystem, or one machine). A node that does not
fails the task with a message saying so.

**Retries.** A task whose worker process or node dies is run again (``max_retries`` times, Ray's own task
retry); the benchmark's tasks resume from their last training checkpoint (see
:func:`~hddpg_zoo.benchmark.run.run_task`), so a retry loses at most ``checkpoint_freq`` steps.
An error the job raises itself is not retried: it fails that job only, as locally.

**Progress.** :func:`~hddpg_zoo.runner.report_progress` inside a task goes to a small Ray actor
on the driver's node (fire and forget: a task never waits for it), which the driver drains while it waits.

**Interruption.** Ctrl-C or SIGTERM on the driver: running tasks get ``interrupt_grace`` seconds to end,
then are cancelled with ``ray.cancel`` (a ``KeyboardInterrupt`` in the task, which
:func:`~sb3_hddpg.training.agent.train_agent` turns into a checkpoint and exit). Those still running
``cancel_grace`` seconds later (blocked in C code, or past the interrupt's reach) are killed with
``ray.cancel(force=True)``, with one warning: they resume from their last periodic checkpoint (every write
is atomic, so a kill mid-write leaves the previous one whole). ``--resume`` then continues from the
checkpoints. A second Ctrl-C while the driver waits kills them at once.

A task's ``KeyboardInterrupt`` is Python's simulated SIGINT (``_thread.interrupt_main``), which does nothing
in a process where SIGINT is ignored, and Ray's worker processes inherit that from whatever started the
cluster: a driver or ``ray start`` launched in the background by a non-interactive shell (``nohup``,
``cmd &``, many CI runners) ignores SIGINT. So each task restores Python's SIGINT handler while it runs
(:func:`_interruptible`); without that, a non-forced cancel silently let such tasks run to their end.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import secrets
import shutil
import signal
import socket
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import torch

from hddpg_zoo.runner import POLL_INTERVAL, Finished, Job, _call, describe, reporting_to
from sb3_hddpg.artifacts.io import HELD_FOLDERS_ENV

logger = logging.getLogger(__name__)

#: How the cluster extra is installed (named in the error when Ray is missing).
INSTALL_HINT = 'pip install "sb3-hddpg[cluster]"'
#: Times a task lost with its worker process or node is run again.
DEFAULT_MAX_RETRIES = 2
#: Seconds to wait for a HOST:PORT address to accept a connection (``ray.init`` itself retries for minutes).
CONNECT_TIMEOUT = 5.0
#: Seconds to wait for the last progress reports of a job that ended.
SETTLE_TIMEOUT = 2.0
#: Seconds to wait for the progress actor to start.
SINK_START_TIMEOUT = 60.0
#: Seconds cancelled tasks get to stop the resumable way (a checkpoint with its replay buffer, tens of MB,
#: written on a possibly busy node) before they are killed: a kill loses at most ``checkpoint_freq`` steps
#: (the last complete checkpoint stays), while an unbounded wait lets one stuck task hold the driver forever.
CANCEL_GRACE = 10.0
#: Seconds to wait for killed tasks to be reported gone (Ray's owner learns of a killed worker quickly).
KILL_TIMEOUT = 30.0


class ClusterError(ValueError):
    """Ray is not installed, or the cluster's address cannot be reached (a usage error: exit code 2)."""


def import_ray() -> Any:
    """The ``ray`` module, or :class:`ClusterError` saying how to install it."""
    try:
        import ray
    except ImportError:
        raise ClusterError(f"the Ray executor needs Ray, which is not installed: {INSTALL_HINT}") from None
    return ray


#: A Ray address: ``[ray://]HOST:PORT``, HOST a DNS name, an IPv4 address or a bracketed IPv6 address, all
#: ASCII (``str.isdigit`` would take ``²`` as a digit, which ``int`` then refuses).
_ADDRESS = re.compile(
    r"\A(?P<scheme>ray://)?(?P<host>[A-Za-z0-9](?:[A-Za-z0-9.-]{0,252})|\[[0-9A-Fa-f:.]{2,45}\])"
    r":(?P<port>[0-9]{1,5})\Z",
    re.ASCII,
)
#: The first bytes every HTTP/2 client sends (RFC 9113, 3.4); Ray's head answers them with a SETTINGS frame.
_HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])
#: The frame type of SETTINGS (the 4th byte of a frame header).
_HTTP2_SETTINGS = 4
#: A request every Ray head's GCS answers at once, with or without a job running.
_GCS_CLUSTER_ID = "/ray.rpc.NodeInfoGcsService/GetClusterId"


def parse_address(address: str) -> tuple[str, int]:
    """
    The host and port of a Ray address, read by one strict rule.

    :param address: ``HOST:PORT`` or ``ray://HOST:PORT``.
    :return: ``(host, port)``; :class:`ClusterError` naming the address when it is not one.
    """
    match = _ADDRESS.match(address) if isinstance(address, str) and len(address) <= 300 else None
    port = int(match["port"]) if match else 0
    if match is None or not 1 <= port <= 65535:
        shown = repr(address) if len(repr(address)) <= 80 else repr(address)[:79] + "…"
        raise ClusterError(f"expected 'auto' or HOST:PORT (port 1-65535) for the Ray address, got {shown}")
    return match["host"].strip("[]"), port


def check_address(address: str, timeout: float = CONNECT_TIMEOUT) -> None:
    """
    Fail fast (rather than after ``ray.init``'s minutes of retries, or never) when ``HOST:PORT`` is not a Ray
    head: nothing listens there, or what listens does not speak gRPC's HTTP/2 (any other server: ``ray.init``
    would wait on it without end). The whole check takes at most about ``2 * timeout`` seconds.

    :param address: ``HOST:PORT`` (or ``ray://HOST:PORT``).
    :param timeout: seconds for the connection and for the answer.
    :raises ClusterError: it is malformed, nothing listens there, or it does not answer as a Ray head.
    """
    host, port = parse_address(address)
    try:
        connection = socket.create_connection((host, port), timeout=timeout)
    except OSError as error:
        reason = "no answer" if isinstance(error, TimeoutError) else (error.strerror or str(error))
        raise ClusterError(
            f"cannot reach a Ray cluster at {address!r} ({reason}); start one with `ray start --head` or "
            "check the address"
        ) from None
    with connection:
        peer = connection.getpeername()[0]
        try:
            connection.settimeout(timeout)
            connection.sendall(_HTTP2_PREFACE)
            header = connection.recv(9)
        except OSError:  # reset, or silent for `timeout` seconds
            header = b""
    answer = "no gRPC" if len(header) < 9 or header[3] != _HTTP2_SETTINGS else None
    if answer is None and not address.startswith("ray://"):  # Ray Client's server has no GCS to ask
        answer = _gcs_answer(peer, port, timeout)
    if answer is not None:
        raise ClusterError(
            f"{address!r} accepts connections but is not a Ray head ({answer}); check the address and port "
            "(`ray status` on the head prints it)"
        )


def _gcs_answer(host: str, port: int, timeout: float) -> str | None:
    """
    ``None`` when ``host:port`` answers a Ray head's cluster-id request (or refuses it for want of the
    cluster's token, which only a Ray head does), else what it answered: any other gRPC server, or a proxy
    that speaks HTTP/2 for every address, would keep ``ray.init`` waiting.
    """
    try:
        import grpc  # Ray's own dependency: missing only when Ray is, which connect reports
    except ImportError:
        return None
    target = f"ipv6:[{host}]:{port}" if ":" in host else f"ipv4:{host}:{port}"
    with grpc.insecure_channel(target) as channel:
        call = channel.unary_unary(_GCS_CLUSTER_ID, request_serializer=bytes, response_deserializer=bytes)
        try:
            call(b"", timeout=timeout)  # an empty request message is a valid protobuf
        except grpc.RpcError as error:
            if error.code() != grpc.StatusCode.UNAUTHENTICATED:
                return f"its answer to a Ray head's request: {error.code().name}"
    return None


def connect(address: str = "auto") -> bool:
    """
    Connect this process to the Ray cluster at ``address`` (nothing to do when already connected).

    :param address: ``auto`` (the cluster started on this machine with ``ray start``, or ``RAY_ADDRESS``)
        or ``HOST:PORT`` of its head (``ray://HOST:PORT`` for Ray Client).
    :return: whether this call connected (and the caller should disconnect with ``ray.shutdown``).
    :raises ClusterError: Ray is not installed or the cluster cannot be reached.
    """
    named = os.environ.get("RAY_ADDRESS") if address == "auto" else address
    if named and named != "auto":
        check_address(named)  # a usage error whether Ray is installed or not
    ray = import_ray()
    if ray.is_initialized():
        return False
    try:
        # Never start a cluster of our own here: the executor is for an existing one.
        ray.init(address=address, logging_level=logging.WARNING, log_to_driver=True)
    except ConnectionError as error:
        raise ClusterError(f"cannot connect to a Ray cluster at {address!r}: {error}") from None
    return True


#: Longest folder a private Ray's temporary folder may be made in: Ray's socket paths live below it, and a
#: Unix socket path is limited to 107 bytes, of which its session and socket names take about 80.
MAX_RAY_PARENT_CHARS = 24


@contextlib.contextmanager
def private_ray(folder: str | os.PathLike[str] | None = None, num_cpus: int | None = None) -> Iterator[None]:
    """
    A Ray of this process's own for the duration, that leaves nothing in the user's home folder and joins no
    other cluster: its temporary folder (sessions, logs, sockets) is a new folder inside ``folder`` (the
    system's temporary folder when ``folder`` is ``None`` or too long a path for Ray's sockets), removed
    after; its token authentication uses a token generated here and handed to Ray's processes in their
    environment only (Ray would otherwise write one to ``~/.ray/auth_token``, which from then on makes Ray
    expect that token from every driver of the machine).

    :param folder: where its temporary folder goes (one the caller controls: the run's folder, a tempdir).
    :param num_cpus: the CPUs it offers (default: the machine's).
    """
    ray = import_ray()
    parent = None if folder is None or len(str(Path(folder).resolve())) > MAX_RAY_PARENT_CHARS else folder
    if parent is not None:
        Path(parent).mkdir(parents=True, exist_ok=True)
    temp_dir = tempfile.mkdtemp(prefix="ray-", dir=parent)
    saved = {name: os.environ.get(name) for name in _PRIVATE_RAY_ENV}
    os.environ.update({"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": secrets.token_hex(32)})
    _reload_ray_auth()
    try:
        ray.init(
            num_cpus=num_cpus,
            include_dashboard=False,
            logging_level=logging.WARNING,
            _temp_dir=temp_dir,
            configure_logging=True,
        )
        try:
            yield
        finally:
            ray.shutdown()
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
        _reload_ray_auth()
        shutil.rmtree(temp_dir, ignore_errors=True)


def _reload_ray_auth() -> None:
    """
    Make Ray read its authentication settings from the environment again: it caches them when imported,
    and re-reads them this way itself when it turns token authentication on for a new local cluster.
    """
    from ray._raylet import AuthenticationTokenLoader, Config  # type: ignore[attr-defined]  # compiled, untyped

    Config.initialize("")
    AuthenticationTokenLoader.instance().reset_cache()


#: The environment variables :func:`private_ray` sets while it runs (and restores after).
_PRIVATE_RAY_ENV = ("RAY_AUTH_MODE", "RAY_AUTH_TOKEN")


def _progress_sink_class() -> type:
    """
    The progress actor's class: the latest :func:`report_progress` value of each job, until the driver
    drains them. Defined in a function so that Ray ships it by value: its process then imports only Ray,
    not torch and this package (seconds saved each time an executor opens).
    """

    class ProgressSink:
        def __init__(self) -> None:
            self._latest: dict[str, float] = {}

        def put(self, key: str, value: float) -> None:
            self._latest[key] = value

        def drain(self) -> dict[str, float]:
            latest, self._latest = self._latest, {}
            return latest

    return ProgressSink


@contextlib.contextmanager
def _driver_context(cwd: str, held_folders: str) -> Iterator[None]:
    """Run in the driver's working directory, sharing its folder locks as a local job would, then restore."""
    previous_cwd = os.getcwd()
    previous_held = os.environ.get(HELD_FOLDERS_ENV)
    try:
        os.chdir(cwd)
    except OSError:
        raise RuntimeError(
            f"the driver's working directory {cwd!r} does not exist on node {socket.gethostname()!r}: "
            "the Ray executor assumes a filesystem shared by every node at the same paths"
        ) from None
    os.environ[HELD_FOLDERS_ENV] = held_folders
    try:
        yield
    finally:
        os.chdir(previous_cwd)
        if previous_held is None:
            os.environ.pop(HELD_FOLDERS_ENV, None)
        else:
            os.environ[HELD_FOLDERS_ENV] = previous_held


@contextlib.contextmanager
def _interruptible() -> Iterator[None]:
    """
    Python's SIGINT handler for the duration, so that ``ray.cancel`` raises ``KeyboardInterrupt`` here even
    in a worker that inherited an ignored SIGINT (see the module docstring); the previous handler after.
    """
    if threading.current_thread() is not threading.main_thread():  # only the main thread sets handlers
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _run_task(job: Job, sink: Any, cwd: str, held_folders: str) -> Finished:
    """A Ray task: run ``job`` as a local process would, its progress sent to ``sink``."""
    import ray

    sent: list[object] = []

    def report(value: float) -> None:
        sent[:] = [sink.put.remote(job.key, value)]  # fire and forget: training never waits for it

    torch.set_num_threads(job.threads)
    with _interruptible(), _driver_context(cwd, held_folders), reporting_to(report):
        end = _call(job)
    if sent:  # the last report reaches the sink before the driver sees the end (a job's progress comes first)
        ray.wait(sent, timeout=SETTLE_TIMEOUT)
    try:
        ray.cloudpickle.dumps(end)
    except Exception as error:  # a result or error that does not pickle: say so rather than lose the task
        return Finished(job.key, False, RuntimeError(describe(error)), end.details)
    return end


class RayExecutor:
    """
    Runs each job as a Ray task on an existing cluster (see the module docstring).

    :param address: the cluster: ``auto`` or ``HOST:PORT`` of its head (see :func:`connect`); ``None``: a
        Ray of this process's own (:func:`private_ray`, in ``local_dir``). Ignored when this process is
        already connected.
    :param slots: jobs submitted at a time (``None``: the cluster's CPUs when opened, at least 1).
    :param max_retries: times a task lost with its worker process or node is run again.
    :param interrupt_grace: on an interrupt, seconds running tasks get to end before they are cancelled
        (``None``: wait for them however long they take).
    :param cancel_grace: seconds cancelled tasks get to stop the resumable way before they are killed.
    :param local_dir: with ``address=None``, the folder the private Ray keeps its files in while it runs
        (default: the system's temporary folder); nothing goes to the home folder either way.
    """

    def __init__(
        self,
        address: str | None = None,
        slots: int | None = None,
        max_retries: int = DEFAULT_MAX_RETRIES,
        interrupt_grace: float | None = 0.0,
        cancel_grace: float = CANCEL_GRACE,
        local_dir: str | os.PathLike[str] | None = None,
    ) -> None:
        if slots is not None and slots < 1:
            raise ValueError(f"Expected `slots` >= 1, actually: {slots}")
        if max_retries < 0:
            raise ValueError(f"Expected `max_retries` >= 0, actually: {max_retries}")
        if cancel_grace < 0:
            raise ValueError(f"Expected `cancel_grace` >= 0, actually: {cancel_grace}")
        self.address = address
        self.slots = slots or 1
        self._wanted_slots = slots
        self.max_retries = max_retries
        self.interrupt_grace = interrupt_grace
        self.cancel_grace = cancel_grace
        self.local_dir = local_dir
        self._running: dict[object, str] = {}  # object ref -> job key
        self._connected = False
        self._private: contextlib.ExitStack | None = None

    def open(self, on_progress: Callable[[str, float], None]) -> None:
        self._ray = ray = import_ray()
        if self.address is None and not ray.is_initialized():
            self._private = contextlib.ExitStack()
            self._private.enter_context(private_ray(self.local_dir))
        elif self.address is not None:
            self._connected = connect(self.address)
        if self._wanted_slots is None:
            self.slots = max(1, int(ray.cluster_resources().get("CPU", 1)))
        self._on_progress = on_progress
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

        # On the driver's node (soft: anywhere if it cannot be), so progress lives and dies with the driver.
        here = NodeAffinitySchedulingStrategy(ray.get_runtime_context().get_node_id(), soft=True)
        sink = ray.remote(num_cpus=0)(_progress_sink_class()).options(scheduling_strategy=here)
        self._sink = sink.remote()
        # Started before any job, so that no early report is lost (seconds on a busy machine, once).
        self._drained: Any = self._sink.drain.remote()  # the pending drain call
        if not ray.wait([self._drained], timeout=SINK_START_TIMEOUT)[0]:
            logger.warning(
                "the progress actor did not start in %.0f s; progress may be late", SINK_START_TIMEOUT
            )
        self._task = ray.remote(_run_task)
        self._cwd = os.getcwd()

    def submit(self, job: Job) -> None:
        ref = self._task.options(num_cpus=job.threads, max_retries=self.max_retries, name=job.key).remote(
            job, self._sink, self._cwd, os.environ.get(HELD_FOLDERS_ENV, "")
        )
        self._running[ref] = job.key

    def wait(self, timeout: float) -> list[Finished]:
        ray = self._ray
        refs = list(self._running)
        ready: list[object] = []
        if refs:
            ready, rest = ray.wait(refs, num_returns=1, timeout=timeout)
            if rest:  # others that ended meanwhile, without waiting again
                ready += ray.wait(rest, num_returns=len(rest), timeout=0)[0]
        else:
            time.sleep(timeout)
        self._relay_progress(settle=bool(ready))
        return [self._result(ref) for ref in ready]

    def _result(self, ref: object) -> Finished:
        key = self._running.pop(ref)
        try:
            return self._ray.get(ref)
        except self._ray.exceptions.RayError as error:  # retries used up, node lost, cancelled...
            return Finished(key, False, error)

    def _relay_progress(self, settle: bool) -> None:
        """
        Relay what the sink holds for running jobs. While jobs run, never wait for it (it may still be
        starting, or be lost with its node); when some ended (``settle``), wait a moment for their last
        reports, so that a job's progress comes before its end, as locally.
        """
        ray = self._ray
        running = set(self._running.values())
        for _ in range(2 if settle else 1):
            if self._drained is not None:
                if not ray.wait([self._drained], timeout=SETTLE_TIMEOUT if settle else 0)[0]:
                    return
                with contextlib.suppress(ray.exceptions.RayError):  # progress is optional; results are not
                    for key, value in ray.get(self._drained).items():
                        if key in running:
                            self._on_progress(key, value)
            self._drained = self._sink.drain.remote()

    def stop(self, interrupted: bool) -> None:
        ray = self._ray
        try:
            if interrupted and self._running:
                self._stop_running()
        except KeyboardInterrupt:  # a second Ctrl-C while waiting: no more waiting
            for ref in self._running:
                ray.cancel(ref, force=True)
            raise
        finally:
            self._running = {}
            with contextlib.suppress(Exception):
                ray.kill(self._sink)
            if self._connected:
                ray.shutdown()
                self._connected = False
            if self._private is not None:
                self._private.close()
                self._private = None

    def _stop_running(self) -> None:
        """
        Give running tasks ``interrupt_grace`` seconds, cancel the rest the resumable way, give them
        ``cancel_grace`` seconds, kill what is left (one warning) and wait for them to leave.
        """
        ray = self._ray
        refs = list(self._running)
        if self.interrupt_grace is None:
            logger.info("waiting for %d Ray task(s) to end", len(refs))
            while refs:
                refs = self._still_running(refs, POLL_INTERVAL)
            return
        refs = self._still_running(refs, self.interrupt_grace)
        for ref in refs:
            ray.cancel(ref, force=False)  # a KeyboardInterrupt in the task: checkpoint and stop
        logger.info("waiting up to %.0f s for %d cancelled Ray task(s) to stop", self.cancel_grace, len(refs))
        refs = self._still_running(refs, self.cancel_grace)
        if not refs:
            return
        for ref in refs:
            ray.cancel(ref, force=True)  # kills its worker process
        logger.warning(
            "%d Ray task(s) did not stop within %.0f s of being cancelled and were killed (%s); "
            "--resume continues them from their last checkpoint",
            len(refs),
            self.cancel_grace,
            ", ".join(sorted(self._running[ref] for ref in refs)),
        )
        self._still_running(refs, KILL_TIMEOUT)

    def _still_running(self, refs: list[object], timeout: float) -> list[object]:
        """Those of ``refs`` that have not ended within ``timeout`` seconds (all ended: at once)."""
        if not refs:
            return refs
        return self._ray.wait(refs, num_returns=len(refs), timeout=timeout)[1]

"""A throw-away PostgreSQL server for tests: :func:`running_postgres` and the ``postgres_url`` fixture.

The server is started from the local PostgreSQL binaries (newest version under
``/usr/lib/postgresql/*/bin`` first, then ``PATH``); the test is skipped with a printed reason if they
are missing. PostgreSQL refuses to run as root, so as root the binaries run via ``runuser`` (or ``su``)
as an unprivileged user: ``postgres`` if it exists, else a system user ``hddpg-pg`` created on demand.
The server listens on 127.0.0.1 only, on a free port, with trust authentication for loopback and the
Unix socket (kept inside the private data directory). It is stopped with ``pg_ctl stop -m fast`` and its
directory removed on exit. Usage in a test module or conftest::

    from postgres_server import postgres_url  # noqa: F401  (fixture)

    def test_something(postgres_url):
        optuna.create_study(storage=postgres_url)
"""

from __future__ import annotations

import contextlib
import os
import pwd
import re
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import NoReturn

import pytest

#: Binaries needed to run the server and create the test database.
REQUIRED_BINARIES = ("initdb", "pg_ctl", "postgres", "createdb")
#: Unprivileged user created when running as root and no ``postgres`` user exists.
SERVICE_USER = "hddpg-pg"
#: Database superuser created by initdb and used in the URL.
DB_SUPERUSER = "hddpg"
DB_NAME = "hddpg_test"
HOST = "127.0.0.1"
#: Upper bounds (seconds) for every step, so a broken server never hangs the test suite.
INITDB_TIMEOUT = 120.0
START_TIMEOUT = 60
STOP_TIMEOUT = 30
COMMAND_TIMEOUT = 60.0


def _skip(reason: str) -> NoReturn:
    print(f"[postgres_server] skipping: {reason}", file=sys.stderr)
    pytest.skip(reason)


def _version_key(path: Path) -> tuple[int, ...]:
    # /usr/lib/postgresql/<version>/bin: sort "15" < "16" numerically, "9.6" as (9, 6).
    return tuple(int(part) for part in re.findall(r"\d+", path.parent.name)) or (-1,)


def find_postgres_bindir() -> Path | None:
    """
    Directory holding all of :data:`REQUIRED_BINARIES`: the newest ``/usr/lib/postgresql/*/bin``
    first, then the directory of ``initdb`` on ``PATH``.

    :return: The directory, or ``None`` if no complete installation was found.
    """
    candidates = sorted(Path("/usr/lib/postgresql").glob("*/bin"), key=_version_key, reverse=True)
    on_path = shutil.which("initdb")
    if on_path:
        candidates.append(Path(on_path).resolve().parent)
    for directory in candidates:
        if all(os.access(directory / name, os.X_OK) for name in REQUIRED_BINARIES):
            return directory
    return None


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind((HOST, 0))
        return sock.getsockname()[1]


def _port_accepts(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.settimeout(1.0)
        return sock.connect_ex((HOST, port)) == 0


def _service_user() -> str:
    """Name of an unprivileged user to run the server as (root only); creates one if needed."""
    for name in ("postgres", SERVICE_USER):
        with contextlib.suppress(KeyError):
            if pwd.getpwnam(name).pw_uid != 0:
                return name
    useradd = shutil.which("useradd")
    if useradd is None:
        _skip("running as root, no 'postgres' user and no useradd to create an unprivileged one")
    result = subprocess.run(
        [useradd, "--system", "--no-create-home", "--shell", "/usr/sbin/nologin", SERVICE_USER],
        capture_output=True,
        text=True,
        timeout=COMMAND_TIMEOUT,
        check=False,
    )
    if result.returncode != 0 and not _user_exists(SERVICE_USER):
        _skip(f"could not create user {SERVICE_USER}: {result.stderr.strip()}")
    return SERVICE_USER


def _user_exists(name: str) -> bool:
    try:
        pwd.getpwnam(name)
    except KeyError:
        return False
    return True


def _as_user_prefix(user: str | None) -> list[str]:
    """Command prefix that runs a command as ``user`` (``[]`` when not root)."""
    if user is None:
        return []
    runuser = shutil.which("runuser")
    if runuser:
        return [runuser, "-u", user, "--"]
    su = shutil.which("su")
    if su:
        # su takes one shell command string; the caller's argv is appended as one quoted string.
        return [su, "-s", "/bin/sh", user, "-c"]
    _skip("running as root but neither runuser nor su is available to drop privileges")


def _run(prefix: list[str], argv: list[str], cwd: Path, timeout: float) -> subprocess.CompletedProcess:
    command = [*prefix, shlex.join(argv)] if prefix and prefix[-1] == "-c" else [*prefix, *argv]
    env = {**os.environ, "LC_ALL": "C", "LANG": "C"}
    for variable in ("PGHOST", "PGPORT", "PGDATABASE", "PGUSER", "PGPASSWORD", "PGSERVICE"):
        env.pop(variable, None)
    result = subprocess.run(
        command, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout, check=False
    )
    if result.returncode != 0:
        raise RuntimeError(
            f"{argv[0]} failed with exit code {result.returncode}:\n{result.stdout}\n{result.stderr}"
        )
    return result


def _read_log(log_file: Path) -> str:
    try:
        return log_file.read_text(errors="replace")[-4000:]
    except OSError:
        return "(no server log)"


def _wait_until_accepting(port: int, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if _port_accepts(port):
            return
        time.sleep(0.1)
    raise TimeoutError(f"PostgreSQL did not accept connections on {HOST}:{port} within {timeout} s")


def _kill_postmaster(data_dir: Path) -> None:
    """Last resort when ``pg_ctl stop`` fails: signal the postmaster whose PID pg_ctl recorded."""
    try:
        pid = int((data_dir / "postmaster.pid").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return
    for sig in (signal.SIGQUIT, signal.SIGKILL):
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, sig)
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline:
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                return
            time.sleep(0.1)


@contextlib.contextmanager
def running_postgres(tmp_path: Path | str | None = None, database: str = DB_NAME) -> Iterator[str]:
    """
    Start a private PostgreSQL server and yield a storage URL for SQLAlchemy / Optuna.

    :param tmp_path: Optional directory (e.g. pytest's ``tmp_path``) into which the server log is
        copied as ``postgres.log`` on exit. The server's own files live in a fresh ``/tmp/hddpg-pg-*``
        directory instead, since ``tmp_path``'s parents may not be traversable by the server's user.
    :param database: Name of the database to create.
    :return: ``postgresql+psycopg://hddpg@127.0.0.1:PORT/DATABASE`` (trust authentication).
    """
    bindir = find_postgres_bindir()
    if bindir is None:
        _skip(
            "PostgreSQL server binaries (initdb, pg_ctl, postgres, createdb) not found "
            "in /usr/lib/postgresql/*/bin or on PATH"
        )
    user = _service_user() if os.geteuid() == 0 else None
    prefix = _as_user_prefix(user)

    base = Path(tempfile.mkdtemp(prefix="hddpg-pg-", dir="/tmp"))
    data_dir = base / "data"
    log_file = base / "server.log"
    started = False
    try:
        if user is not None:
            entry = pwd.getpwnam(user)
            os.chown(base, entry.pw_uid, entry.pw_gid)
        os.chmod(base, 0o700)
        _run(
            prefix,
            [
                str(bindir / "initdb"),
                "-D",
                str(data_dir),
                "-U",
                DB_SUPERUSER,
                "-E",
                "UTF8",
                "--no-locale",
                "--auth=trust",
                "--no-sync",
            ],
            cwd=base,
            timeout=INITDB_TIMEOUT,
        )
        (data_dir / "pg_hba.conf").write_text(
            "# Test server: trust on the private Unix socket and on IPv4 loopback only.\n"
            "local all all trust\n"
            f"host all all {HOST}/32 trust\n"
        )
        last_error: Exception | None = None
        for _attempt in range(3):  # the free port may be taken between probing and binding
            port = _free_port()
            settings = (
                f"\nlisten_addresses = '{HOST}'\n"
                f"port = {port}\n"
                f"unix_socket_directories = '{data_dir}'\n"
                "max_connections = 50\n"
                "fsync = off\n"
                "synchronous_commit = off\n"
                "full_page_writes = off\n"
            )
            with open(data_dir / "postgresql.conf", "a") as conf:
                conf.write(settings)
            try:
                _run(
                    prefix,
                    [
                        str(bindir / "pg_ctl"),
                        "-D",
                        str(data_dir),
                        "-l",
                        str(log_file),
                        "-w",
                        "-t",
                        str(START_TIMEOUT),
                        "start",
                    ],
                    cwd=base,
                    timeout=START_TIMEOUT + 10,
                )
            except (RuntimeError, subprocess.TimeoutExpired) as error:
                last_error = error
                _kill_postmaster(data_dir)
                continue
            started = True
            break
        if not started:
            raise RuntimeError(f"PostgreSQL did not start: {last_error}\nserver log:\n{_read_log(log_file)}")
        _wait_until_accepting(port, timeout=START_TIMEOUT)
        _run(
            prefix,
            [str(bindir / "createdb"), "-h", HOST, "-p", str(port), "-U", DB_SUPERUSER, database],
            cwd=base,
            timeout=COMMAND_TIMEOUT,
        )
        yield f"postgresql+psycopg://{DB_SUPERUSER}@{HOST}:{port}/{database}"
    finally:
        try:
            if started:
                try:
                    _run(
                        prefix,
                        [
                            str(bindir / "pg_ctl"),
                            "-D",
                            str(data_dir),
                            "-m",
                            "fast",
                            "-w",
                            "-t",
                            str(STOP_TIMEOUT),
                            "stop",
                        ],
                        cwd=base,
                        timeout=STOP_TIMEOUT + 10,
                    )
                except (RuntimeError, subprocess.TimeoutExpired):
                    _kill_postmaster(data_dir)
            if tmp_path is not None and log_file.exists():
                with contextlib.suppress(OSError):
                    shutil.copyfile(log_file, Path(tmp_path) / "postgres.log")
        finally:
            shutil.rmtree(base, ignore_errors=True)


@pytest.fixture
def postgres_url(tmp_path: Path) -> Iterator[str]:
    """A fresh PostgreSQL server for one test; yields its SQLAlchemy/Optuna storage URL."""
    with running_postgres(tmp_path) as url:
        yield url

"""
Where an Optuna study lives, shared safely by several processes: the storage and the trial-claim lock.

**The embedded default is SQLite** (``sqlite:///RUN/study.db``), not Optuna's journal file, because in
Optuna 5 only the RDB storage has heartbeats: a trial whose process is killed (SIGKILL, power loss) is
marked failed once its heartbeat is ``grace_period`` seconds old and re-queued with the same parameters by
``RetryHeartbeatStaleTrialCallback`` (``RetryFailedTrialCallback`` before Optuna 4.9), so a re-run completes the study; a journal file would keep the dead trial
``RUNNING`` for ever. SQLite is safe for several processes *on one machine*: its transactions are
serialisable under file locks, so trial numbers cannot be duplicated. We turn on write-ahead logging so
that readers (other processes, optuna-dashboard) do not block the writer, and a long busy timeout so that a
process waits for the lock instead of failing with "database is locked". Its locks are unreliable on
network file systems: for several machines use PostgreSQL (``postgresql+psycopg://...``).

**The trial-claim lock** makes "finish N trials" exact with several processes: counting the finished and
running trials and creating the next one happen under one lock (a file lock next to a SQLite file, a
PostgreSQL advisory lock on the study's server), so two processes cannot both claim the last trial.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import logging
import sqlite3
import time
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

import optuna

if TYPE_CHECKING:  # sqlalchemy (optuna's) is imported only when a PostgreSQL lock is taken
    from sqlalchemy.engine import Connection, Engine

logger = logging.getLogger(__name__)

#: The study file of the embedded default storage, inside the run folder.
STUDY_FILE = "study.db"
#: Seconds a SQLite connection waits for another process's write lock before failing.
SQLITE_BUSY_TIMEOUT = 60.0
#: Failed trials of dead processes are re-queued at most this many times (then left failed).
MAX_RETRY = 3


def default_storage_url(out_dir: str | Path) -> str:
    """The embedded storage of a run folder: ``sqlite:////abs/path/OUT/study.db``."""
    return f"sqlite:///{(Path(out_dir) / STUDY_FILE).resolve()}"


@contextlib.contextmanager
def quiet_experimental() -> Iterator[None]:
    """Silence Optuna's notices that heartbeats and friends are experimental: we chose them knowingly."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        yield


def sqlite_path(url: str) -> Path | None:
    """The database file of a ``sqlite:///`` URL (``None`` for other URLs and in-memory databases)."""
    from sqlalchemy.engine import make_url  # lazily: slow to import, only for a storage URL

    parsed = make_url(url)
    if parsed.get_backend_name() != "sqlite" or parsed.database in (None, "", ":memory:"):
        return None
    return Path(parsed.database)


def check_storage_url(url: str) -> None:
    """
    Check an Optuna storage URL's form and that its database driver is installed, without connecting: a
    typo in the scheme fails here with the URL named, not inside SQLAlchemy after the run has started.

    :raises ValueError: for a malformed URL, an unknown dialect or a missing driver (e.g. the
        ``distributed`` extra's psycopg for ``postgresql+psycopg://``).
    """
    import sqlalchemy.engine  # lazily: slow to import, only for a storage URL

    try:
        parsed = sqlalchemy.engine.make_url(url)
    except Exception as error:  # sqlalchemy's ArgumentError
        raise ValueError(f"Not a usable storage URL {url.split('@')[-1]!r}: {error}") from None
    if parsed.get_backend_name() == "sqlite" and parsed.query.get("uri") not in (None, "false", "0"):
        # SQLite's URI filenames ("file:...?mode=memory", "file::memory:") name no file to share, or name
        # one in a syntax the file checks below do not read: a study needs a plain path.
        raise ValueError(
            f"SQLite URI filenames (uri=true) cannot hold a study: {_shown(url)}; give a path, e.g. "
            "sqlite:///study.db, or leave --storage out"
        )
    if parsed.get_backend_name() == "sqlite" and (parsed.database or "").endswith(("/", "\\")):
        # A path ending in a separator names a folder; SQLite would still open a file beside it, whose
        # journal files then land where nobody asked for them.
        raise ValueError(f"Expected a SQLite database file, actually a folder path: {_shown(url)}")
    if parsed.get_backend_name() == "sqlite" and (
        parsed.database in (None, "", ":memory:") or parsed.query.get("mode") == "memory"
    ):
        # Optuna's RDB storage opens new connections, each with its own empty in-memory database: trials
        # fail with tracebacks and the study is gone with the process. A study must outlive it.
        raise ValueError(
            f"In-memory SQLite storage {url!r} cannot hold a study (each connection gets a new empty "
            "database); give a file, e.g. sqlite:///study.db, or leave --storage out"
        )
    try:
        parsed.get_dialect().import_dbapi()
    except ImportError as error:
        raise ValueError(
            f"The driver for {parsed.drivername!r} in {url.split('@')[-1]!r} is not installed ({error}); "
            "for PostgreSQL install the 'distributed' extra"
        ) from None
    except Exception as error:  # sqlalchemy's ArgumentError / NoSuchModuleError
        raise ValueError(f"Not a usable storage URL {url.split('@')[-1]!r}: {error}") from None


#: Seconds a connection to a database server may take before the storage counts as unreachable.
CONNECT_TIMEOUT = 10


class StorageError(ValueError):
    """The study storage a URL names cannot be opened; the message names the URL without its password."""


def _shown(url: str) -> str:
    """``url`` without its password, for messages."""
    from sqlalchemy.engine import make_url  # lazily: slow to import, only for a storage URL

    try:
        return repr(make_url(url).render_as_string(hide_password=True))
    except Exception:  # a URL make_url cannot read shows only its part after the credentials
        return repr(url.split("@")[-1])


def _first_line(error: BaseException) -> str:
    """The driver's own message without SQLAlchemy's SQL echo and background link."""
    origin = getattr(error, "orig", None) or error
    return " ".join(str(origin).split("\n")[0].split())[:300]


def _set_wal(path: Path) -> None:
    """
    Put the database at ``path`` in WAL mode, once. Switching the mode needs the database to itself, which
    SQLite's busy timeout does not wait for: a second process opening the study at the same moment gets
    "database is locked". So the mode is read first (no lock needed), and a switch that meets a lock is
    tried again while another process may be making the same switch.
    """
    for attempt in range(20):
        with contextlib.closing(sqlite3.connect(path, timeout=SQLITE_BUSY_TIMEOUT)) as connection:
            if connection.execute("PRAGMA journal_mode").fetchone()[0].lower() == "wal":
                return
            try:
                connection.execute("PRAGMA journal_mode=WAL")
                return
            except sqlite3.OperationalError as error:
                if "locked" not in str(error) or attempt == 19:
                    raise
        time.sleep(0.05 * (attempt + 1))


def make_storage(
    url: str, heartbeat_interval: int | None = 30, max_retry: int = MAX_RETRY, create: bool = True
) -> Any:
    """
    An Optuna storage for ``url`` with heartbeats and retry of trials whose process died.

    :param url: any SQLAlchemy URL Optuna accepts (``sqlite:///...``, ``postgresql+psycopg://...``,
        ``mysql+pymysql://...``).
    :param heartbeat_interval: seconds between a running trial's heartbeats (``None``: no heartbeat, so a
        killed trial stays ``RUNNING``); a trial is declared dead after twice this without one.
    :param max_retry: how often a dead trial is re-queued.
    :param create: make a SQLite database file that does not exist yet (``False`` for a reader: a missing
        file is a :class:`StorageError`, and no empty database is left behind).
    :return: an ``optuna.storages.RDBStorage``.
    """
    import sqlalchemy.exc  # lazily: slow to import, only for a storage URL
    from sqlalchemy.engine import make_url

    check_storage_url(url)  # refuses in-memory SQLite, which cannot hold a study

    engine_kwargs: dict[str, Any] = {}
    path = sqlite_path(url)
    if path is not None:
        if path.exists() and not path.is_file():
            raise StorageError(f"Cannot hold a study in {_shown(url)}: {str(path)!r} is not a regular file")
        if not create and not path.is_file():
            raise StorageError(f"No study database at {_shown(url)}: {str(path)!r} does not exist")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            # WAL is a property of the file, set once; it must be set outside SQLAlchemy's transactions.
            _set_wal(path)
        except (OSError, sqlite3.Error) as error:
            raise StorageError(f"Cannot open the study storage {_shown(url)}: {error}") from None
        engine_kwargs["connect_args"] = {"timeout": SQLITE_BUSY_TIMEOUT}
    elif make_url(url).get_backend_name() == "postgresql":
        # A host that drops packets would otherwise hold the command for the system's TCP timeout.
        engine_kwargs["connect_args"] = {"connect_timeout": CONNECT_TIMEOUT}
    # Optuna 4.9 renamed RetryFailedTrialCallback; take the new name where it exists.
    retry_class = getattr(
        optuna.storages, "RetryHeartbeatStaleTrialCallback", optuna.storages.RetryFailedTrialCallback
    )
    with quiet_experimental():
        callback = retry_class(max_retry=max_retry) if heartbeat_interval else None
    attempts = 5
    for attempt in range(attempts):
        try:
            with quiet_experimental():
                return optuna.storages.RDBStorage(
                    url,
                    engine_kwargs=engine_kwargs,
                    heartbeat_interval=heartbeat_interval,
                    grace_period=2 * heartbeat_interval if heartbeat_interval else None,
                    heartbeat_stale_trial_callback=callback,
                )
        except (
            sqlalchemy.exc.OperationalError,
            sqlalchemy.exc.IntegrityError,
            sqlalchemy.exc.ProgrammingError,
        ) as error:
            # Processes started together race to create the tables of a new database (PostgreSQL reports
            # the loser's CREATE TABLE as a ProgrammingError, DuplicateTable); the loser retries and finds
            # them. Any other error of these kinds comes back after the last attempt.
            if attempt == attempts - 1:
                raise StorageError(
                    f"Cannot open the study storage {_shown(url)}: {_first_line(error)}"
                ) from None
            time.sleep(0.2 * (attempt + 1))
        except (sqlalchemy.exc.DBAPIError, optuna.exceptions.StorageInternalError) as error:  # sslmode=bogus
            raise StorageError(f"Cannot open the study storage {_shown(url)}: {_first_line(error)}") from None
    raise AssertionError("unreachable")


class TrialClaimLock:
    """
    A lock shared by every process of a study, held while a process decides whether to start a trial and
    creates it. Re-entrant-safe to release: :meth:`release` does nothing when not held.

    File lock (``fcntl``) next to a SQLite database; PostgreSQL session-level advisory lock keyed by the
    study name; for other storages no lock (a warning says that the trial count may then overshoot by
    up to one per process). Either lock is freed by the operating system or the server if its process dies.

    :param url: the study's storage URL.
    :param study_name: the study's name (PostgreSQL locks are per name).
    """

    def __init__(self, url: str, study_name: str) -> None:
        from sqlalchemy.engine import make_url  # lazily: slow to import, only for a storage URL

        self.url = url
        self._file: TextIO | None = None
        self._connection: Connection | None = None
        self._engine: Engine | None = None
        path = sqlite_path(url)
        backend = make_url(url).get_backend_name()
        self._lock_path = path.with_name(path.name + ".lock") if path is not None else None
        digest = hashlib.sha256(study_name.encode()).digest()
        self._key = int.from_bytes(digest[:8], "big", signed=True)
        self._postgres = backend == "postgresql"
        if self._lock_path is None and not self._postgres and backend != "sqlite":
            logger.warning(
                "No cross-process trial lock for %r storages: with several processes the study may "
                "finish up to one extra trial per process.",
                backend,
            )

    def acquire(self) -> None:
        """Block until this process holds the lock."""
        if self._lock_path is not None and self._file is None:
            handle = open(self._lock_path, "a")  # noqa: SIM115  (held across calls, closed in release)
            fcntl.flock(handle, fcntl.LOCK_EX)
            self._file = handle
        elif self._postgres and self._connection is None:
            # Lazily: slow to import, only for a PostgreSQL lock.
            import sqlalchemy
            from sqlalchemy.pool import NullPool

            if self._engine is None:
                # Its own connection: an advisory lock belongs to the session that took it.
                self._engine = sqlalchemy.create_engine(self.url, poolclass=NullPool)
            connection = self._engine.connect()
            connection.execute(sqlalchemy.text("SELECT pg_advisory_lock(:key)"), {"key": self._key})
            self._connection = connection

    def release(self) -> None:
        """Release the lock if held."""
        if self._file is not None:
            handle, self._file = self._file, None
            fcntl.flock(handle, fcntl.LOCK_UN)
            handle.close()
        if self._connection is not None:
            import sqlalchemy  # lazily: only for a PostgreSQL lock

            connection, self._connection = self._connection, None
            try:
                connection.execute(sqlalchemy.text("SELECT pg_advisory_unlock(:key)"), {"key": self._key})
            finally:
                connection.close()

    def close(self) -> None:
        """Release and drop the lock's database engine."""
        self.release()
        if self._engine is not None:
            self._engine.dispose()
            self._engine = None

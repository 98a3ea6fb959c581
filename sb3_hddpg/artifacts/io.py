"""Atomic file writes (a temporary file in the same folder, flushed, renamed over the target) and folder locks."""

from __future__ import annotations

import contextlib
import fcntl
import functools
import inspect
import json
import math
import os
import signal
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, TypeVar

F = TypeVar("F", bound=Callable[..., Any])

#: Suffix of the temporary files :func:`atomic_write` makes (hidden: their names start with a dot).
TMP_SUFFIX = ".tmp"


# os.umask can only be read by setting it: once, at import, before threads create files meanwhile.
UMASK = os.umask(0)
os.umask(UMASK)

#: The signals that stop a run cleanly (Ctrl-C, and SIGTERM turned into Ctrl-C while training).
_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
#: The last signal turned into ``KeyboardInterrupt`` in this process (empty: none, or Ctrl-C itself).
_STOPPED_BY: list[int] = []


def note_stop_signal(signum: int) -> None:
    """Record that ``signum`` (SIGTERM) is what stops this process, for its exit code (128 + the signal)."""
    _STOPPED_BY[:] = [signum]


def forget_stop_signal() -> None:
    """Forget the recorded stop signal (a command starting in a process that ran one before)."""
    _STOPPED_BY.clear()


def stop_signal() -> int:
    """The signal that stopped this process: the last one :func:`note_stop_signal` recorded, else SIGINT."""
    return _STOPPED_BY[-1] if _STOPPED_BY else int(signal.SIGINT)


@contextlib.contextmanager
def deferred_stop_signals() -> Iterator[None]:
    """
    Hold Ctrl-C and SIGTERM until the block ends, then deliver them: torch's zip writer, interrupted between
    two writes, reports a ``RuntimeError`` instead of the signal's exception.
    """
    received: list[signal.Signals] = []

    def hold(signum: int, frame: object) -> None:
        if signum not in received:
            received.append(signal.Signals(signum))

    previous: dict[int, Any] = {}
    # A handler set outside Python (None) cannot be restored; outside the main thread none can be set.
    if all(signal.getsignal(signum) is not None for signum in _STOP_SIGNALS):
        with contextlib.suppress(ValueError):
            previous = {signum: signal.signal(signum, hold) for signum in _STOP_SIGNALS}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        for signum in received:
            signal.raise_signal(signum)


def atomic_write(
    path: str | os.PathLike[str], write: Callable[[Path], object], hold_signals: bool = True
) -> Path:
    """
    Produce ``path`` atomically: ``write`` fills a temporary path in the same folder, which is then renamed
    over ``path``, so that a reader (or a run killed at any moment) sees the old file or the new one, never
    half. A kill can leave a hidden ``.NAME.*.tmp`` file behind (:func:`remove_stale_temporaries`).

    :param path: the final file.
    :param write: called with the temporary path; must create that file.
    :param hold_signals: hold Ctrl-C and SIGTERM while ``write`` runs (:func:`deferred_stop_signals`);
        ``False`` for a long ``write`` (a video) that must stay interruptible.
    :return: the final path.
    """
    path = Path(path)
    if path.is_dir():
        # Checked first so that the error names the target rather than a temporary file.
        raise IsADirectoryError(f"Cannot write {str(path)!r}: it is a folder")
    blocking = next((p for p in path.parents if p.exists() and not p.is_dir()), None)
    if blocking is not None:  # mkdir would say "[Errno 17] File exists", which names no file
        raise NotADirectoryError(f"Cannot write {str(path)!r}: {str(blocking)!r} is a file, not a folder")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=TMP_SUFFIX, dir=path.parent)
    except OSError as error:
        # A read-only folder's error names the hidden temporary, which means nothing to a user.
        raise type(error)(error.errno, f"Cannot write {str(path)!r}: {error.strerror or error}") from None
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        if not hold_signals:
            write(tmp)
        with deferred_stop_signals():
            if hold_signals:
                write(tmp)
            with open(tmp, "rb+") as handle:
                os.fsync(handle.fileno())
            # mkstemp makes it readable by its owner only: give it a new file's usual permissions.
            os.chmod(tmp, 0o666 & ~UMASK)
            os.replace(tmp, path)
    except OSError as error:
        tmp.unlink(missing_ok=True)
        if error.errno is None:
            raise
        # "No space left on device" names no file, and the temporary's name means nothing to a user.
        raise type(error)(error.errno, f"Cannot write {str(path)!r}: {error.strerror or error}") from error
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_folder(path.parent)
    return path


def _fsync_folder(folder: Path) -> None:
    """Make a rename durable across a power cut too (POSIX only; a no-op where folders cannot be opened)."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def remove_stale_temporaries(folder: str | os.PathLike[str], target: str | None = None) -> list[Path]:
    """
    Delete the temporary files a killed :func:`atomic_write` left in ``folder`` (not recursive), only when no
    other process writes the same files: a live writer's temporary looks the same.

    :param folder: the folder to clean (missing folders are fine).
    :param target: only the temporaries of this final file name (default: all), for shared folders.
    :return: the files removed.
    """
    folder = Path(folder)
    if not folder.is_dir():
        return []
    removed = []
    pattern = f".{target}.*{TMP_SUFFIX}" if target is not None else f".*{TMP_SUFFIX}"
    for stale in folder.glob(pattern):
        if stale.is_file():
            stale.unlink(missing_ok=True)
            removed.append(stale)
    return removed


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically."""
    return atomic_write(path, lambda tmp: tmp.write_bytes(data))


class NotFiniteError(ValueError):
    """A value about to be written to a JSON file is NaN or infinite (JSON has no such numbers)."""


def atomic_write_json(path: str | os.PathLike[str], obj: object) -> Path:
    """Write ``obj`` as indented strict JSON to ``path`` atomically (:func:`json_text`)."""
    return atomic_write_bytes(path, (json_text(obj, Path(path).name) + "\n").encode())


def json_text(obj: object, what: str) -> str:
    """
    ``obj`` as indented strict JSON: the one serialiser of every JSON file we write (also inside zips).

    :param obj: plain JSON values, or records (objects with ``to_json()``) at any depth.
    :param what: the file, for the message.
    :return: the text; raises :class:`NotFiniteError` naming the first NaN or infinite value's place.
    """
    obj = _as_json(obj)
    try:
        return json.dumps(obj, indent=2, sort_keys=False, allow_nan=False)
    except ValueError:
        where = first_not_finite(obj) or "a value"
        raise NotFiniteError(f"{what}: {where} is not a finite number; not written") from None


def _as_json(value: object) -> object:
    """``value`` with every record (an object with ``to_json``) replaced by its JSON, at any depth."""
    to_json = getattr(value, "to_json", None)
    if callable(to_json):
        return _as_json(to_json())
    if isinstance(value, dict):
        return {key: _as_json(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_as_json(item) for item in value]
    return value


def first_not_finite(value: object, where: str = "") -> str | None:
    """The path (``a.b[2]``) of the first NaN or infinite float in ``value``, else ``None``."""
    if isinstance(value, float) and not math.isfinite(value):
        return where or "the value"
    items = (
        value.items()
        if isinstance(value, dict)
        else enumerate(value)
        if isinstance(value, (list, tuple))
        else ()
    )
    for key, item in items:
        found = first_not_finite(
            item, f"{where}[{key}]" if isinstance(key, int) else f"{where}.{key}".lstrip(".")
        )
        if found:
            return found
    return None


#: The lock file every writer of a run folder holds (hidden; removed when the run releases it).
LOCK_FILE = ".hddpg.lock"
#: Folders locked by this process or an ancestor of it (the pool processes of one run share its folder).
HELD_FOLDERS_ENV = "HDDPG_HELD_FOLDERS"


class FolderLockedError(RuntimeError):
    """Another process holds a run folder's lock; the message names the folder and the holder's pid."""


@dataclass
class _HeldLock:
    """A folder lock this process holds: its open lock file and how many nested callers hold it."""

    handle: IO[str]
    depth: int


# Locks this process holds, by folder: two flocks of one folder would deadlock even inside one process.
_HELD: dict[Path, _HeldLock] = {}


def _held_by_ancestor(key: Path) -> bool:
    return str(key) in os.environ.get(HELD_FOLDERS_ENV, "").split(os.pathsep)


def holds_lock(folder: str | os.PathLike[str]) -> bool:
    """Whether this process (or the run that started it) holds ``folder``'s run lock."""
    key = Path(folder).resolve()
    return key in _HELD or _held_by_ancestor(key)


def _open_locked(path: Path, blocking: bool) -> IO[str]:
    """
    Open ``path`` and ``flock`` it, the file that is at ``path`` once locked: a releasing holder removes
    the file, so a lock taken on a file that was removed meanwhile guards nothing and is taken again.

    :raises BlockingIOError: ``blocking=False`` and another process holds the lock.
    """
    while True:
        handle = open(path, "a+")  # noqa: SIM115  (returned open, the caller holds it)
        try:
            fcntl.flock(handle.fileno(), fcntl.LOCK_EX | (0 if blocking else fcntl.LOCK_NB))
            current = os.stat(path).st_ino
        except (BlockingIOError, FileNotFoundError) as error:
            if isinstance(error, BlockingIOError):
                handle.seek(0)
                holder = handle.read(32).strip()
                handle.close()
                raise BlockingIOError(holder) from None
            current = -1
        if current == os.fstat(handle.fileno()).st_ino:
            return handle
        handle.close()


def _release(path: Path, handle: IO[str]) -> None:
    """Remove the lock file, then release it (in this order: see :func:`_open_locked`)."""
    with contextlib.suppress(FileNotFoundError):
        os.unlink(path)
    handle.close()  # closing releases the flock


@contextlib.contextmanager
def locked_folder(folder: str | os.PathLike[str]) -> Iterator[Path]:
    """
    Hold an exclusive lock on a run folder for the duration (``flock`` on ``FOLDER/.hddpg.lock``, which
    records the holder's pid): another run asking for it gets :class:`FolderLockedError` at once. Re-entrant
    within a process, and shared with the processes it starts through :data:`HELD_FOLDERS_ENV`.

    :param folder: the run folder (created if missing).
    :return: the folder.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    key = folder.resolve()
    if key in _HELD or _held_by_ancestor(key):
        if key in _HELD:
            _HELD[key].depth += 1
        try:
            yield folder
        finally:
            if key in _HELD:
                _HELD[key].depth -= 1
        return
    try:
        handle = _open_locked(folder / LOCK_FILE, blocking=False)
    except BlockingIOError as error:
        holder = str(error) or "unknown"
        raise FolderLockedError(
            f"{str(folder)!r} is in use by another run (pid {holder}); wait for it to finish or choose "
            "another folder"
        ) from None
    handle.seek(0)
    handle.truncate()
    handle.write(f"{os.getpid()}\n")
    handle.flush()
    _HELD[key] = _HeldLock(handle, 1)
    inherited = os.environ.get(HELD_FOLDERS_ENV, "")
    os.environ[HELD_FOLDERS_ENV] = os.pathsep.join(filter(None, [inherited, str(key)]))
    try:
        yield folder
    finally:
        _HELD[key].depth -= 1
        if _HELD[key].depth == 0:
            del _HELD[key]
            held = [f for f in os.environ.get(HELD_FOLDERS_ENV, "").split(os.pathsep) if f and f != str(key)]
            os.environ[HELD_FOLDERS_ENV] = os.pathsep.join(held)
            _release(folder / LOCK_FILE, handle)


@contextlib.contextmanager
def locked_file(path: str | os.PathLike[str]) -> Iterator[None]:
    """A short exclusive lock for a read-modify-write of ``path`` (on a hidden ``.NAME.lock`` beside it)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    lock = path.parent / f".{path.name}.lock"
    handle = _open_locked(lock, blocking=True)
    try:
        yield
    finally:
        _release(lock, handle)


def holds_folder_lock(folder_of: Callable[[inspect.BoundArguments], Any]) -> Callable[[F], F]:
    """
    Decorate a function that writes a run folder so that it runs under :func:`locked_folder`.

    :param folder_of: picks the folder from the call's bound arguments (defaults applied).
    """
    return runs_within(lambda call: locked_folder(folder_of(call)))


def runs_within(
    context_of: Callable[[inspect.BoundArguments], contextlib.AbstractContextManager[object]],
) -> Callable[[F], F]:
    """
    Decorate a function so that every call runs inside the context manager ``context_of`` makes of it.

    :param context_of: the context of one call, from its bound arguments (defaults applied).
    """

    def decorate(function: F) -> F:
        signature = inspect.signature(function)

        @functools.wraps(function)
        def wrapper(*args: object, **kwargs: object) -> Any:
            bound = signature.bind(*args, **kwargs)
            bound.apply_defaults()
            with context_of(bound):
                return function(*args, **kwargs)

        return wrapper  # type: ignore[return-value]

    return decorate

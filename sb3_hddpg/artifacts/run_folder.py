"""
The one owner of "clear or write a folder this tool wrote": what ``--force`` may delete, and what it must refuse.

A folder is cleared (:func:`clear_run_folder`) only when it is not protected (root, home, the current folder
or one above it), not a symbolic link, one of the tool's run folders (:data:`RUN_MARKER`, or the run lock for
older folders) and not locked by another live process; then only the entries the tool wrote are deleted (its
marker's inventory, or the entries of :data:`RUN_LAYOUT` that were not there when it took the folder), and
anything else is kept and returned. A folder is written (:func:`check_out_folder`) only when it is new,
empty, or a run folder where nothing the tool did not write has a name the tool may write over.
"""

from __future__ import annotations

import contextlib
import fcntl
import inspect
import os
import re
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

from sb3_hddpg.artifacts.containment import RUN_MARKER, is_run_folder
from sb3_hddpg.artifacts.io import (
    LOCK_FILE,
    TMP_SUFFIX,
    atomic_write_json,
    holds_lock,
    locked_folder,
    runs_within,
)
from sb3_hddpg.artifacts.limits import MAX_MARKER_BYTES, MAX_MARKER_ENTRIES, parse_json, read_file_bytes

F = TypeVar("F", bound=Callable[..., Any])

#: The top-level names the tool writes into a run or package folder: the only entries ``--force`` deletes.
RUN_LAYOUT = re.compile(
    r"\A(?:"
    # folders: training runs, benchmarks, tuning, quickstart
    r"workers|manager|simplex|flat|checkpoints|best|tensorboard|evaluations|records|worker-curves|zoo|trials"
    r"|plots"
    r"|seed-[0-9]{1,10}|replaced-[0-9]{8}-[0-9]{6}"
    # files: results, records, configs, studies, the package's card and replay
    r"|hierarchy\.zip|ham\.json|results\.json|results\.md|benchmark\.json|index\.json|manifest\.json"
    r"|config\.json|config(?:-[a-z]{1,20})?\.yml|switch_frontier\.json|evaluations\.csv|README\.md|replay\.mp4"
    r"|study\.db(?:-journal|-wal|-shm)?"
    r"|[A-Za-z0-9][A-Za-z0-9_.-]{0,200}\.(?:png|gif|mp4|zip)"
    # temporaries of atomic writes and short locks (hidden)
    r"|\.[^/]{1,250}\.(?:tmp|lock)"
    r")\Z"
)


#: A top-level entry a marker may list: one plain file or folder name (no separator, not hidden).
RUN_ENTRY = re.compile(r"\A[A-Za-z0-9][A-Za-z0-9_.-]{0,200}\Z", re.ASCII)


class RunFolderError(ValueError):
    """A folder may not be cleared (or written) by this tool; the message names the folder and why."""


def protected_reason(folder: str | os.PathLike[str]) -> str | None:
    """Why ``folder`` may never be a run folder, whatever it holds (``"the current folder"``...), or ``None``."""
    resolved = Path(folder).resolve()
    if resolved == Path(resolved.anchor):
        return "the root folder"
    if resolved == Path.home().resolve():
        return "your home folder"
    cwd = Path.cwd().resolve()
    if resolved == cwd:
        return "the current folder"
    if resolved in cwd.parents:
        return "a folder above the current one"
    if resolved in Path.home().resolve().parents:
        return "a folder above your home folder"
    return None


def check_output_file(path: str | os.PathLike[str], *, force: bool) -> Path:
    """
    A single file a command is about to write (a video, a figure, a JSON summary): refused with
    :class:`RunFolderError` when it is a folder or a symbolic link, or when it exists and ``force`` is not given.

    :param path: the file named by the user.
    :param force: whether the user asked to replace an existing file (``--force``).
    :return: the path.
    """
    path = Path(path)
    if path.is_symlink():
        raise RunFolderError(f"Refusing to write through a symbolic link: {str(path)!r}")
    if path.is_dir():
        raise RunFolderError(f"Expected a file to write, actually a folder: {str(path)!r}")
    if path.exists() and not force:
        raise RunFolderError(f"{str(path)!r} exists; pass --force to replace it")
    blocking = next((p for p in path.parents if p.exists() and not p.is_dir()), None)
    if blocking is not None:  # known now, not after the episodes it would have written
        raise RunFolderError(f"cannot write {str(path)!r}: {str(blocking)!r} is a file, not a folder")
    return path


def lock_holder(folder: str | os.PathLike[str]) -> str | None:
    """The pid (as recorded) of another live process holding ``folder``'s run lock, or ``None``."""
    folder = Path(folder)
    lock = folder / LOCK_FILE
    if not lock.is_file() or holds_lock(folder):
        return None
    with open(lock) as handle:
        try:
            fcntl.flock(handle.fileno(), fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return handle.read(32).strip() or "unknown"
        # Closing this descriptor releases only its own shared lock (flock locks belong to open files).
    return None


def check_clearable(folder: str | os.PathLike[str]) -> Path:
    """
    Refuse, with :class:`RunFolderError` naming the reason, to clear ``folder`` (see the module's rules).

    :param folder: the folder a command was asked to overwrite.
    :return: the folder.
    """
    folder = Path(folder)
    if not _existing_folder(folder, "clear"):
        return folder
    entries = [entry.name for entry in folder.iterdir()]
    if entries and not is_run_folder(folder):
        raise RunFolderError(
            f"refusing to clear {str(folder)!r}: it is not a folder this tool made (no {RUN_MARKER}) and holds "
            f"{len(entries)} entries, e.g. {sorted(entries)[0]!r}; choose an empty or new folder"
        )
    holder = lock_holder(folder)
    if holder is not None:
        raise RunFolderError(
            f"refusing to clear {str(folder)!r}: it is in use by another run (pid {holder}); wait for it to "
            "finish or choose another folder"
        )
    return folder


def _existing_folder(folder: Path, verb: str) -> bool:
    """Whether ``folder`` exists; refused when it is a symbolic link, a file or protected (to ``verb``)."""
    if folder.is_symlink():
        raise RunFolderError(
            f"{str(folder)!r} is a symbolic link (to {os.readlink(folder)!r}); refusing to write or clear what "
            "it points to: name the folder itself"
        )
    if not folder.exists():
        return False
    if not folder.is_dir():
        raise RunFolderError(f"{str(folder)!r} is a file, not a folder")
    reason = protected_reason(folder)
    if reason is not None:
        raise RunFolderError(f"refusing to {verb} {str(folder)!r}: it is {reason}")
    return True


def tool_entries(folder: str | os.PathLike[str]) -> frozenset[str]:
    """
    The top-level entries of ``folder`` the tool wrote, by its marker: the inventory a finished command
    recorded and the entries it listed; while that is not recorded, also every entry of :data:`RUN_LAYOUT`
    that was not there when the tool took the folder.
    """
    folder = Path(folder)
    marker = _read_marker(folder)
    present = {entry.name for entry in folder.iterdir()} - {LOCK_FILE, RUN_MARKER}
    listed = _names(marker.get("entries")) | _names(marker.get("written"))
    if "written" in marker and not marker.get("open", False):
        return frozenset(present & listed)
    foreign = _names(marker.get("foreign"))
    return frozenset(
        name for name in present if name in listed or (RUN_LAYOUT.match(name) and name not in foreign)
    )


def _marks_run_folder(name: str) -> bool:
    """Whether an entry is the tool's lock or marker, or one of them half-written by another process."""
    return name in (LOCK_FILE, RUN_MARKER) or any(
        name.startswith(f".{mark}.") and name.endswith(TMP_SUFFIX) for mark in (LOCK_FILE, RUN_MARKER)
    )


def check_out_folder(folder: str | os.PathLike[str]) -> Path:
    """
    The one rule for a folder a command is about to write (see the module's rules): a :class:`RunFolderError`.

    :param folder: the folder named by the user.
    :return: the folder.
    """
    folder = Path(folder)
    if not _existing_folder(folder, "write into"):
        return folder
    entries = sorted(entry.name for entry in folder.iterdir() if not _marks_run_folder(entry.name))
    if not entries and not is_run_folder(folder):
        return folder
    if not is_run_folder(folder):
        raise RunFolderError(
            f"refusing to write into {str(folder)!r}: it holds {len(entries)} entries this tool did not write "
            f"(e.g. {entries[0]!r}) and is not one of its run folders (no {RUN_MARKER}); choose a new or empty "
            "folder"
        )
    ours = tool_entries(folder)
    in_the_way = [name for name in entries if name not in ours and RUN_LAYOUT.match(name)]
    if in_the_way:
        raise RunFolderError(
            f"refusing to write into {str(folder)!r}: {in_the_way[0]!r} there was not written by this tool and "
            f"a run may write over it ({len(in_the_way)} such entries); move it out of the folder first"
        )
    return folder


def clear_run_folder(folder: str | os.PathLike[str]) -> list[str]:
    """
    Delete the tool's own entries of a run folder (``--force``), after :func:`check_clearable`; the lock
    and the marker stay (removing a held lock would let another run take the folder meanwhile).

    :param folder: the run folder.
    :return: the names of the entries kept because the tool did not write them.
    """
    folder = check_clearable(folder)
    if not folder.exists():
        return []
    ours = tool_entries(folder)
    kept = []
    for entry in sorted(folder.iterdir()):
        if entry.name in (LOCK_FILE, RUN_MARKER):
            continue
        if entry.name not in ours:
            kept.append(entry.name)
        elif entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry)
        else:
            entry.unlink()
    return kept


def mark_run_folder(
    folder: str | os.PathLike[str], command: str, entries: list[str] | None = None, reopen: bool = False
) -> Path:
    """
    Mark ``folder`` as one of the tool's run folders (created if missing), open until
    :func:`record_written`, recording the entries present that the tool did not write.

    :param folder: the folder.
    :param command: the command that writes it, recorded for whoever looks.
    :param entries: top-level names the command wrote beyond :data:`RUN_LAYOUT` (a package's unpacked
        model folder); a later ``--force`` deletes them too.
    :param reopen: open an existing marker again (a command that will record its inventory when it ends);
        otherwise an existing marker is kept when ``entries`` is ``None``.
    :return: the marker file.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    if (folder / RUN_MARKER).is_file() and entries is None and not reopen:
        return folder / RUN_MARKER
    marker = _read_marker(folder)
    ours = tool_entries(folder)
    present = {entry.name for entry in folder.iterdir()} - {LOCK_FILE, RUN_MARKER}
    record = {
        "tool": "sb3-hddpg",
        "command": command,
        "entries": sorted(set(entries or []) | _names(marker.get("entries"))),
        "written": sorted(ours),
        "foreign": sorted(present - ours),
        "open": True,
    }
    return atomic_write_json(folder / RUN_MARKER, record)


def record_written(folder: str | os.PathLike[str]) -> None:
    """
    Close a run folder's marker when the command that took it ends: its inventory becomes every entry now
    present that was not the user's when the tool took it. No-op without a marker.

    :param folder: the run folder.
    """
    folder = Path(folder)
    if folder.is_symlink() or not (folder / RUN_MARKER).is_file():
        return
    marker = _read_marker(folder)
    foreign = _names(marker.get("foreign"))
    present = {entry.name for entry in folder.iterdir()} - {LOCK_FILE, RUN_MARKER}
    written = {name for name in present - foreign if RUN_ENTRY.match(name) or name.startswith(".")}
    atomic_write_json(folder / RUN_MARKER, {**marker, "written": sorted(written), "open": False})


def holds_run_folder(folder_of: Callable[[inspect.BoundArguments], Any], command: str) -> Callable[[F], F]:
    """
    Decorate a library function that writes a run folder (``train_workers``...): it runs under the folder's
    lock, and a folder it takes without a marker is marked and its inventory recorded when it returns, as
    the CLI does.

    :param folder_of: picks the folder from the call's bound arguments (defaults applied).
    :param command: recorded in the marker.
    """
    return runs_within(lambda call: _held_run_folder(Path(folder_of(call)), command))


@contextlib.contextmanager
def _held_run_folder(folder: Path, command: str) -> Iterator[None]:
    """:func:`holds_run_folder`'s context: the folder locked, and marked if it had no marker."""
    with locked_folder(folder):
        fresh = not (folder / RUN_MARKER).is_file()
        if fresh:
            mark_run_folder(folder, command)
        try:
            yield
        finally:
            if fresh:
                record_written(folder)


def _names(value: object) -> frozenset[str]:
    """Plain top-level names from a marker's list (never ``.``, ``..`` or anything with a separator)."""
    if not isinstance(value, list):
        return frozenset()
    return frozenset(
        e
        for e in value[:MAX_MARKER_ENTRIES]
        if isinstance(e, str)
        and (RUN_ENTRY.match(e) or RUN_LAYOUT.match(e))
        and "/" not in e
        and e not in (".", "..")
    )


def _read_marker(folder: Path) -> dict[str, object]:
    """The marker, read within its limits; ``{}`` when missing or unreadable."""
    try:
        data = parse_json(read_file_bytes(folder / RUN_MARKER, MAX_MARKER_BYTES), str(folder / RUN_MARKER))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}

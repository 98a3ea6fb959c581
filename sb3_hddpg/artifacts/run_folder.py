"""
The one owner of "clear a folder this tool wrote": what ``--force`` may delete, and what it must refuse.

Every command that replaces earlier results (``train-workers``, ``train-manager``, ``train-flat``,
``benchmark``, ``quickstart``, ``package``) calls :func:`clear_run_folder`; nothing else in the package deletes a
user-named folder. A folder is cleared only when all of these hold:

- it is not the root, the home folder, the current folder or any folder above the current one, and it is
  not reached through a symbolic link (whose target may be anyone's);
- it is one of the tool's run folders: it carries :data:`RUN_MARKER` (written by :func:`mark_run_folder`
  when a command takes a folder) or, for folders made before the marker existed, the run lock file;
- no other live process holds its lock (the message names the holder's pid).

Then only the entries of the tool's own run layout (:data:`RUN_LAYOUT`: ``workers/``, ``checkpoints/``,
``hierarchy.zip``, figures, records...) are deleted; anything else in the folder (a user's notes, data
they put there) is kept and returned, so that the caller can say so. Symbolic links inside are removed as
links, never followed.
"""

from __future__ import annotations

import fcntl
import os
import re
import shutil
from pathlib import Path

from sb3_hddpg.artifacts.io import LOCK_FILE, atomic_write_json, holds_lock
from sb3_hddpg.artifacts.limits import MAX_MARKER_BYTES, MAX_MARKER_ENTRIES, parse_json

#: The hidden file that marks a folder as one of the tool's run folders.
RUN_MARKER = ".hddpg-run"

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
    """
    Why ``folder`` may never be a run folder, whatever it holds (``"the current folder"``...), or ``None``.
    """
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
    :class:`RunFolderError` when it is a folder or a symbolic link, or when it exists and ``force`` is not
    given, so that a second run never replaces a file without being asked to.

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
    return path


def is_run_folder(folder: str | os.PathLike[str]) -> bool:
    """Whether ``folder`` is one of the tool's run folders (its marker, or the lock of an older run)."""
    folder = Path(folder)
    return (folder / RUN_MARKER).is_file() or (folder / LOCK_FILE).is_file()


def lock_holder(folder: str | os.PathLike[str]) -> str | None:
    """
    The pid (as recorded) of another live process holding ``folder``'s run lock, or ``None``: the lock is
    free, missing, or held by this process (or the run it belongs to).
    """
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
    Refuse, with :class:`RunFolderError` naming the folder and the reason, to clear ``folder`` (see the
    module's rules); a missing or empty folder is always fine.

    :param folder: the folder a command was asked to overwrite.
    :return: the folder.
    """
    folder = Path(folder)
    if folder.is_symlink():
        raise RunFolderError(
            f"{str(folder)!r} is a symbolic link (to {os.readlink(folder)!r}); refusing to clear what it points "
            "to: name the folder itself"
        )
    if not folder.exists():
        return folder
    if not folder.is_dir():
        raise RunFolderError(f"{str(folder)!r} is a file, not a folder")
    reason = protected_reason(folder)
    if reason is not None:
        raise RunFolderError(f"refusing to clear {str(folder)!r}: it is {reason}")
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


def clear_run_folder(folder: str | os.PathLike[str]) -> list[str]:
    """
    Delete the tool's own entries of a run folder (``--force``), after :func:`check_clearable`; the lock
    file and the marker stay (removing a held lock would let another run take the folder meanwhile).

    :param folder: the run folder.
    :return: the names of the entries kept because the tool did not write them.
    """
    folder = check_clearable(folder)
    if not folder.exists():
        return []
    listed = _listed_entries(folder)
    kept = []
    for entry in sorted(folder.iterdir()):
        if entry.name in (LOCK_FILE, RUN_MARKER):
            continue
        if not (RUN_LAYOUT.match(entry.name) or entry.name in listed):
            kept.append(entry.name)
        elif entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry)
        else:
            entry.unlink()
    return kept


def mark_run_folder(folder: str | os.PathLike[str], command: str, entries: list[str] | None = None) -> Path:
    """
    Mark ``folder`` as one of the tool's run folders (created if missing), so that a later ``--force`` may
    clear what the tool wrote into it.

    :param folder: the folder.
    :param command: the command that writes it, recorded for whoever looks.
    :param entries: top-level names the command wrote beyond :data:`RUN_LAYOUT` (a package's unpacked
        model folder); a later ``--force`` deletes them too. An existing marker is kept when ``None``.
    :return: the marker file.
    """
    folder = Path(folder)
    marker = folder / RUN_MARKER
    if marker.is_file() and entries is None:
        return marker
    record = {"tool": "sb3-hddpg", "command": command, "entries": sorted(entries or [])}
    return atomic_write_json(marker, record)


def _listed_entries(folder: Path) -> frozenset[str]:
    """
    The extra entries the marker lists, read defensively (the marker is a file in a folder anyone may edit):
    only plain top-level names, never ``.``, ``..`` or anything with a separator.
    """
    try:
        with open(folder / RUN_MARKER, "rb") as handle:
            data = parse_json(handle.read(MAX_MARKER_BYTES), str(folder / RUN_MARKER))
    except (OSError, ValueError):
        return frozenset()
    entries = data.get("entries") if isinstance(data, dict) else None
    if not isinstance(entries, list):
        return frozenset()
    return frozenset(
        e
        for e in entries[:MAX_MARKER_ENTRIES]
        if isinstance(e, str) and RUN_ENTRY.match(e) and e not in (".", "..")
    )

"""Atomic file writes: a temporary file in the same folder, flushed to disk, then renamed over the target."""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

#: Suffix of the temporary files :func:`atomic_write` makes (hidden: their names start with a dot).
TMP_SUFFIX = ".tmp"


def _read_umask() -> int:
    # os.umask can only be read by setting it; set it straight back. Done once at import, because the
    # brief window with a zero umask would race with threads creating files.
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _read_umask()


def atomic_write(path: str | os.PathLike[str], write: Callable[[Path], None]) -> Path:
    """
    Produce ``path`` atomically: ``write`` fills a temporary path in the same folder, which is then renamed
    over ``path``. A reader (or a run killed at any moment, even with SIGKILL) sees the old file or the new
    one, never half. A kill can leave a hidden ``.NAME.*.tmp`` file behind; nothing reads those, and
    :func:`remove_stale_temporaries` clears them.

    :param path: the final file.
    :param write: called with the temporary path; must create that file.
    :return: the final path.
    """
    path = Path(path)
    if path.is_dir():
        # Checked first so that the error names the target rather than a temporary file.
        raise IsADirectoryError(f"Cannot write {str(path)!r}: it is a folder")
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=TMP_SUFFIX, dir=path.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        write(tmp)
        with open(tmp, "rb+") as handle:
            os.fsync(handle.fileno())
        # mkstemp creates the file readable by its owner only; give results the permissions any other
        # file would get, so that shared run folders stay readable.
        os.chmod(tmp, 0o666 & ~_UMASK)
        os.replace(tmp, path)
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
    Delete the temporary files a killed :func:`atomic_write` left in ``folder`` (not recursive).

    Only call this when no other process is writing the same files: a live writer's temporary file looks
    the same. ``target`` narrows the cleaning to one file's temporaries, for folders that several agents
    share.

    :param folder: the folder to clean (missing folders are fine).
    :param target: only the temporaries of this final file name (default: all).
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


def atomic_write_json(path: str | os.PathLike[str], obj: Any) -> Path:
    """Write ``obj`` as indented JSON to ``path`` atomically."""
    return atomic_write_bytes(path, (json.dumps(obj, indent=2, sort_keys=False) + "\n").encode())

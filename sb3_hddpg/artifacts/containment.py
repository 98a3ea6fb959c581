"""Which run folder a file belongs to, and whether its path leaves it (checked on every read from one)."""

from __future__ import annotations

import os
from pathlib import Path

from sb3_hddpg.artifacts.io import LOCK_FILE

RUN_MARKER = ".hddpg-run"  #: The hidden file that marks a folder as one of the tool's run folders.

#: Files only this tool writes, by which a run folder made before the marker existed is recognised.
TOOL_FILES = (
    "workers/manifest.json",
    "flat/manifest.json",
    "manager/manager_settings.json",
    "benchmark.json",
    "study.db",  # tune's study, in the folders tune wrote before the marker
)


def is_run_folder(folder: str | os.PathLike[str]) -> bool:
    """Whether ``folder`` is one of the tool's run folders: its marker, a run's lock, or one of :data:`TOOL_FILES`."""
    folder = Path(folder)
    return (
        (folder / RUN_MARKER).is_file()
        or (folder / LOCK_FILE).is_file()
        or any((folder / name).is_file() for name in TOOL_FILES)
    )


def enclosing_run_folder(path: str | os.PathLike[str]) -> Path | None:
    """The outermost run folder above ``path`` (as named), or ``None`` (a benchmark's seeds are some too)."""
    found = None
    for parent in Path(os.path.abspath(path)).parents:
        if parent.parent != parent and is_run_folder(parent):
            found = parent
    return found


def run_folder_escape(path: str | os.PathLike[str]) -> str | None:
    """Why reading ``path`` would leave the run folder it is in (one line), or ``None``."""
    root = enclosing_run_folder(path)
    if root is None:
        return None
    real_root = Path(os.path.realpath(root))
    target = Path(os.path.realpath(path))
    if target == real_root or real_root in target.parents:
        return None
    return (
        f"{str(path)!r} is inside the run folder {str(root)!r} but leads outside it (to {str(target)!r}) "
        "through a symbolic link; refused"
    )

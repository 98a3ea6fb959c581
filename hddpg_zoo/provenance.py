"""The code a benchmark invocation ran: the library's version and the git commit of its source tree."""

from __future__ import annotations

import re
import subprocess
from dataclasses import dataclass
from pathlib import Path

import sb3_hddpg
from sb3_hddpg import __version__
from sb3_hddpg.artifacts.limits import brief
from sb3_hddpg.artifacts.records.base import JsonObject

#: The library's source folder: the git tree asked for the commit is the one that holds it.
_SOURCE = Path(sb3_hddpg.__file__).resolve().parent
#: Seconds a ``git`` call may take before the commit counts as not recorded (a hung network filesystem).
GIT_TIMEOUT_S = 10.0


@dataclass(frozen=True)
class CodeProvenance:
    """
    The code a benchmark invocation ran: the package's version, the git commit of its source tree and whether
    that tree was clean (``None`` where there is no git repository to ask: not recorded, never guessed).

    :param version: ``sb3_hddpg.__version__``.
    :param commit: the full hash of ``HEAD``, or ``None``.
    :param clean: ``True`` when the tree had no uncommitted change to tracked files, ``None`` when unknown.
    """

    version: str
    commit: str | None = None
    clean: bool | None = None

    def to_json(self) -> JsonObject:
        return {"version": self.version, "commit": self.commit, "clean": self.clean}

    @classmethod
    def from_json(cls, value: object, what: str) -> CodeProvenance:
        """
        An invocation's ``code`` field, checked: ``version`` a string, ``commit`` 40 hex digits or null,
        ``clean`` a boolean or null.

        :param value: the field as read.
        :param what: where it is, for the ``ValueError`` naming the first problem.
        """
        if not isinstance(value, dict) or not isinstance(value.get("version"), str):
            raise ValueError(f"{what}: expected an object with the package version, got {brief(value)}")
        commit, clean = value.get("commit"), value.get("clean")
        if commit is not None and not (isinstance(commit, str) and re.fullmatch("[0-9a-f]{40}", commit)):
            raise ValueError(f"{what}.commit: expected 40 lower-case hex digits or null, got {brief(commit)}")
        if clean is not None and not isinstance(clean, bool):
            raise ValueError(f"{what}.clean: expected true, false or null, got {brief(clean)}")
        return cls(value["version"], commit, clean)

    @property
    def code_id(self) -> tuple[str, str | None]:
        """What two invocations must share to have run the same code: the version and the commit."""
        return self.version, self.commit

    def describe(self) -> str:
        """``VERSION at COMMIT`` (12 digits, ``+ uncommitted changes`` for a dirty tree) or ``not recorded``."""
        if self.commit is None:
            return f"{self.version} (commit not recorded)"
        dirty = " + uncommitted changes" if self.clean is False else ""
        return f"{self.version} at {self.commit[:12]}{dirty}"


def _git(*args: str, cwd: Path) -> str | None:
    """``git ARGS`` in ``cwd``: its output, or ``None`` where git is missing, fails or takes too long."""
    try:
        done = subprocess.run(
            ["git", *args], cwd=cwd, capture_output=True, text=True, timeout=GIT_TIMEOUT_S, check=False
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout if done.returncode == 0 else None


def code_provenance(source: str | Path | None = None) -> CodeProvenance:
    """
    The code this process runs: the package's version and, where its source lies in a git work tree, its
    ``HEAD`` commit and whether tracked files differ from it (else ``None``: never fails).

    :param source: the folder whose tree is asked (default: this package's source folder).
    """
    where = Path(source) if source is not None else _SOURCE
    if not where.is_dir():
        return CodeProvenance(__version__)
    # The source must be tracked: a wheel installed in a venv inside another repository is not its code.
    tracked = _git("ls-files", "--error-unmatch", "__init__.py", cwd=where)
    commit = _git("rev-parse", "HEAD", cwd=where)
    if tracked is None or commit is None:
        return CodeProvenance(__version__)
    # Only this package's files and the repository's own count: untracked scratch files change no code.
    status = _git("status", "--porcelain", "--untracked-files=no", cwd=where)
    return CodeProvenance(__version__, commit.strip(), None if status is None else status.strip() == "")

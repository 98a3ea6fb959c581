"""
The one place that decides a command's exit code and its one error line, from what ended it: **2** for a
usage or input error (typer's, the library's ``ValueError`` family, a missing or wrong-kind path, an env
that cannot be made, a locked run folder, a missing extra), **130** after Ctrl-C and **143** after SIGTERM
(a command that saved its work raises :class:`CommandStopped` saying how to continue), **1** for anything
else. Only :func:`sb3_hddpg.cli.main` calls :func:`exit_code` and :func:`error_line`.
"""

from __future__ import annotations

import errno

import gymnasium as gym
import typer

from sb3_hddpg.artifacts.io import FolderLockedError, stop_signal
from sb3_hddpg.extras import MissingExtraError

#: The exceptions that mean "the input cannot be used" wherever they are raised.
INPUT_ERRORS: tuple[type[BaseException], ...] = (
    ValueError,
    FileNotFoundError,
    FileExistsError,
    NotADirectoryError,
    IsADirectoryError,
    gym.error.Error,
    FolderLockedError,
    MissingExtraError,
)
#: Exit code of a usage or input error (click's own for usage errors).
USAGE_EXIT = 2
#: Exit code of an internal failure.
INTERNAL_EXIT = 1
#: Exit code after Ctrl-C (128 + SIGINT); after SIGTERM it is 143 (:func:`interrupted_exit`).
INTERRUPTED_EXIT = 130


def interrupted_exit() -> int:
    """The exit code of a command stopped by a signal: 128 + the signal that stopped it (130, 143)."""
    return 128 + stop_signal()


class CommandStopped(Exception):
    """A command stopped by Ctrl-C or SIGTERM once its work was saved; the message says how to continue."""


#: ``OSError`` numbers that mean a path the user named cannot be one (a full disk is not among them).
INPUT_ERRNOS = frozenset(
    {errno.ENAMETOOLONG, errno.ENOENT, errno.ENOTDIR, errno.EISDIR, errno.EEXIST, errno.ELOOP}
)


def exit_code(error: BaseException) -> int:
    """The exit code for a command that ended with ``error``."""
    if isinstance(error, (KeyboardInterrupt, typer.Abort, CommandStopped)):
        return interrupted_exit()
    if isinstance(error, (typer.Exit, typer.TyperException)):
        return int(error.exit_code)
    if isinstance(error, INPUT_ERRORS) or (isinstance(error, OSError) and error.errno in INPUT_ERRNOS):
        return USAGE_EXIT
    return INTERNAL_EXIT


def error_line(error: BaseException) -> str:
    """
    The error line's text for ``error``: the library's own message for its errors, else with its type too,
    since ``KeyError('x')`` alone says nothing.
    """
    if isinstance(error, (KeyboardInterrupt, typer.Abort)):
        return "interrupted"
    if isinstance(error, typer.TyperException):
        return error.format_message() + _offending_input(error)
    message = str(error)
    if isinstance(error, (*INPUT_ERRORS, OSError, RuntimeError)) and message:
        return message
    return f"{type(error).__name__}: {message}" if message else type(error).__name__


def _offending_input(error: Exception) -> str:
    """``", got 'ten'"`` when typer's type conversion rejected a value its message does not repeat."""
    errors = getattr(error.__cause__, "errors", None)
    if not callable(errors):
        return ""
    try:
        value = errors()[0]["input"]
    except (LookupError, TypeError):
        return ""
    return f", got {value!r}"

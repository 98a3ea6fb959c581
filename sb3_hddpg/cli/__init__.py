"""
``hddpg-cli``: the command line of sb3-hddpg.

Each command lives in its own module of this package and only parses, calls the library and prints (rich).
Errors a user can cause end in one line naming the problem and the value, and a non-zero exit (2 for usage
errors); ``--debug`` (or ``HDDPG_DEBUG=1``) shows the traceback instead.
"""

from __future__ import annotations

import os
import sys

import typer
from typer.main import get_command

from sb3_hddpg.cli.app import app, console_error

# Importing a command module registers its commands on ``app``.
from sb3_hddpg.cli import rollout, train, evaluate  # noqa: F401  isort: skip
from sb3_hddpg.cli import train_flat  # noqa: F401  isort: skip
from sb3_hddpg.cli import benchmark  # noqa: F401  isort: skip
from sb3_hddpg.cli import tune  # noqa: F401  isort: skip
from sb3_hddpg.cli import quickstart  # noqa: F401  isort: skip
from sb3_hddpg.cli import record  # noqa: F401  isort: skip
from sb3_hddpg.cli import plot_selection  # noqa: F401  isort: skip
from sb3_hddpg.cli import package  # noqa: F401  isort: skip
from sb3_hddpg.cli import report  # noqa: F401  isort: skip


def main(argv: list[str] | None = None) -> None:
    """Console-script entry point: run ``app`` and turn expected failures into one-line errors."""
    args = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in args or os.environ.get("HDDPG_DEBUG") == "1"
    args = [a for a in args if a != "--debug"]
    command = get_command(app)
    try:
        code = command.main(args=args, prog_name="hddpg-cli", standalone_mode=False)
    except typer.Abort:
        console_error("aborted")
        sys.exit(130)
    except typer.TyperException as error:  # usage errors: unknown option, bad value (exit code 2)
        if type(error).__name__ == "NoArgsIsHelpError":  # bare `hddpg-cli`: the help, not an error
            print(error.format_message())
            sys.exit(0)
        if debug and error.__cause__ is not None:  # the library's error behind a usage error
            raise
        console_error(error.format_message() + _offending_input(error))
        sys.exit(error.exit_code)
    except typer.Exit as error:
        sys.exit(error.exit_code)
    except KeyboardInterrupt:
        console_error("interrupted")
        sys.exit(130)
    except Exception as error:  # the one place that turns any failure into a clean line
        if debug:
            raise
        # Our own errors are sentences; anything else (KeyError('x'), ...) needs its type to make sense.
        own = isinstance(error, (ValueError, OSError, RuntimeError)) and str(error)
        console_error(str(error) if own else f"{type(error).__name__}: {error}")
        sys.exit(1)
    sys.exit(code if isinstance(code, int) else 0)


def _offending_input(error: Exception) -> str:
    """
    ``", got 'ten'"`` when typer's type conversion rejected a value: its messages (from pydantic, e.g.
    "Input should be a valid integer") do not repeat the value, which the user should see.
    """
    errors = getattr(error.__cause__, "errors", None)
    if not callable(errors):
        return ""
    try:
        value = errors()[0]["input"]
    except (LookupError, TypeError):
        return ""
    return f", got {value!r}"


__all__ = ["app", "main"]

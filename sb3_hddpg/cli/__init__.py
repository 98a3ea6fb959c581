"""
``hddpg-cli``: the command line of sb3-hddpg. Each command's module only parses, calls the library and
prints; an error ends in one line and a non-zero exit, or with ``--debug`` (``HDDPG_DEBUG=1``) a traceback.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys

import typer
from rich.markup import escape
from typer.main import get_command

from sb3_hddpg.artifacts.io import forget_stop_signal, note_stop_signal
from sb3_hddpg.cli.app import COMMANDS, app, console, console_error
from sb3_hddpg.cli.errors import INTERRUPTED_EXIT, CommandStopped, error_line, exit_code, interrupted_exit
from sb3_hddpg.envs.headless import as_rendering_error


def _sigterm(signum: int, frame: object) -> None:
    note_stop_signal(signum)
    raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> None:
    """Console-script entry point: run ``app``; whatever ends it becomes one line and an exit code."""
    args = list(sys.argv[1:] if argv is None else argv)
    forget_stop_signal()  # an earlier command of this process (a test's batch) may have been stopped
    # SIGTERM ends every command as Ctrl-C does (one line, exit 143), not silently; not in another thread.
    with contextlib.suppress(ValueError):
        if signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:
            signal.signal(signal.SIGTERM, _sigterm)
    debug = "--debug" in args or os.environ.get("HDDPG_DEBUG") == "1"
    args = [a for a in args if a != "--debug"]
    command = get_command(app)
    try:
        code = command.main(args=args, prog_name="hddpg-cli", standalone_mode=False)
    except typer.Exit as error:
        sys.exit(error.exit_code)
    except typer.TyperException as error:
        if type(error).__name__ == "NoArgsIsHelpError":  # bare `hddpg-cli`: the help, not an error
            print(error.format_message())
            sys.exit(0)
        if debug and error.__cause__ is not None:  # the library's error behind a usage error
            raise
        console_error(error_line(error))
        sys.exit(exit_code(error))
    except CommandStopped as stopped:
        console.print(f"[yellow]{escape(str(stopped))}[/]", soft_wrap=True)
        sys.exit(exit_code(stopped))
    except (KeyboardInterrupt, typer.Abort) as error:
        console_error(error_line(error))
        sys.exit(exit_code(error))
    except Exception as error:  # the one place that turns any failure into a clean line
        if debug:
            raise
        error = as_rendering_error(error) or error  # an OpenGL context that could not be made: with its fix
        console_error(error_line(error))
        sys.exit(exit_code(error))
    if code == INTERRUPTED_EXIT:
        # typer turns Ctrl-C (and so SIGTERM) into this code before the handlers above see it.
        console_error("interrupted")
        code = interrupted_exit()
    sys.exit(code if isinstance(code, int) else 0)


__all__ = ["COMMANDS", "app", "main"]

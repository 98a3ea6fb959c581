"""
``hddpg-cli``: the command line of sb3-hddpg.

Each command lives in its own module of this package and only parses, calls the library and prints (rich).
Errors a user can cause end in one line naming the problem and the value, and a non-zero exit;
``--debug`` (or ``HDDPG_DEBUG=1``) shows the traceback instead.
"""

from __future__ import annotations

import os
import sys

from sb3_hddpg.cli.app import app, console_error

# Importing a command module registers its commands on ``app``.
from sb3_hddpg.cli import rollout  # noqa: F401  isort: skip


def main(argv: list[str] | None = None) -> None:
    """Console-script entry point: run ``app`` and turn expected failures into one-line errors."""
    args = sys.argv[1:] if argv is None else argv
    debug = "--debug" in args or os.environ.get("HDDPG_DEBUG") == "1"
    if "--debug" in args:
        args = [a for a in args if a != "--debug"]
    try:
        app(args=args, prog_name="hddpg-cli", standalone_mode=True)
    except SystemExit:
        raise
    except KeyboardInterrupt:
        console_error("interrupted")
        sys.exit(130)
    except Exception as error:  # the one place that turns any failure into a clean line
        if debug:
            raise
        console_error(f"{error}" if str(error) else type(error).__name__)
        sys.exit(1)


__all__ = ["app", "main"]

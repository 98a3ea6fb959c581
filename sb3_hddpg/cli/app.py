"""The typer application every ``hddpg-cli`` command registers on, and the shared console."""

from __future__ import annotations

import typer
import typer.core
from rich.console import Console
from rich.markup import escape

import sb3_hddpg

#: Where commands print their tables and progress.
console = Console()
_error_console = Console(stderr=True, highlight=False)


def _usage_name(argument: typer.core.TyperArgument) -> str:
    """A required argument as ``PATH`` in usage lines (click's spelling), an optional one as ``[PATH]``."""
    name = argument.metavar or (argument.name or "").upper()
    name = name if argument.required else f"[{name}]"
    return name + ("..." if argument.nargs != 1 else "")


# Typer's usage line writes a required argument as {path}, which reads as a template left unfilled.
if hasattr(typer.core.TyperArgument, "_usage_display_name"):
    typer.core.TyperArgument._usage_display_name = _usage_name  # type: ignore[method-assign,assignment]

app = typer.Typer(
    name="hddpg-cli",
    help="Hierarchical DDPG on Stable-Baselines3: train workers, a manager that selects them, and compare.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)


def one_line(message: str) -> str:
    """``message`` on one line: errors from deep down (numpy reprs, torch) may span several."""
    return " ".join(line.strip() for line in message.splitlines() if line.strip())


#: The longest error line shown (a last guard: messages already truncate values from files).
MAX_ERROR_CHARS = 2000


def console_error(message: str) -> None:
    """Print a one-line error to stderr (the message is shown as is, never read as rich markup)."""
    line = one_line(message)
    if len(line) > MAX_ERROR_CHARS:
        line = line[: MAX_ERROR_CHARS - 1] + "…"
    _error_console.print(f"[bold red]error:[/] {escape(line)}", soft_wrap=True)


def console_note(message: str) -> None:
    """Print a one-line note to stderr: something the user should know that is not an error."""
    _error_console.print(f"[yellow]note:[/] {escape(one_line(message))}", soft_wrap=True)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"sb3-hddpg {sb3_hddpg.__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="Print the version and exit."
    ),
) -> None:
    """Hierarchical DDPG on Stable-Baselines3. Add --debug to any command to see tracebacks."""

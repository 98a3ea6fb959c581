"""The typer application every ``hddpg-cli`` command registers on, and the shared console."""

from __future__ import annotations

import importlib
from typing import Any

import typer
import typer.core
import typer.main
from rich.console import Console
from rich.markup import escape

import sb3_hddpg
from sb3_hddpg.extras import INSTALL_EXTRA, MissingExtraError

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

#: Every command, in the order the help lists them: its name -> the module that registers it (a bare name
#: is this package's, a dotted one the harness's), and its line in ``hddpg-cli --help``. A command's module
#: (and with it torch) is imported only when it runs or shows its help, so ``hddpg-cli --help`` is instant.
COMMANDS: dict[str, tuple[str, str]] = {
    "quickstart": ("hddpg_zoo.cli.quickstart", "The whole method at a small budget, every method compared."),
    "train-workers": ("train", "Train one worker (a plain SB3 model) per reward term."),
    "train-manager": ("train", "Train a manager that selects a worker, over trained workers."),
    "grow": ("train", "Add workers where the front gains most (optimistic linear support)."),
    "fit-critics": ("train", "Give workers per-term critics fitted on rollouts, for GPI."),
    "train-flat": ("train_flat", "Train one SB3 agent on every objective (the flat baseline)."),
    "evaluate": ("evaluate", "Evaluate a policy: reward, each term, worker choices."),
    "record": ("hddpg_zoo.cli.record", "Render a policy to a GIF or MP4, showing the acting worker."),
    "plot-selection": ("hddpg_zoo.cli.plot_selection", "Plot which worker acts at each step, and why."),
    "rollout": ("rollout", "Roll out a random and a scripted policy: the env's metrics."),
    "benchmark": ("hddpg_zoo.cli.benchmark", "Train and evaluate every method on every seed."),
    "report": ("hddpg_zoo.cli.report", "Regenerate a page's result tables from a benchmark."),
    "morl-report": (
        "hddpg_zoo.cli.benchmark_protocol",
        "Write docs/MORL.md from MORL-baselines protocol runs.",
    ),
    "export-models": ("hddpg_zoo.cli.export_models", "Copy a benchmark's final models into a folder."),
    "snapshot": ("hddpg_zoo.cli.snapshot", "Copy a benchmark's finished seeds, to resume it elsewhere."),
    "tune": ("hddpg_zoo.cli.tune", "Tune hyperparameters with Optuna, in one or many processes."),
    "export-study": ("hddpg_zoo.cli.report", "Export a tuning study's trials to JSON."),
    "package": ("hddpg_zoo.cli.package", "Package a model, card and replay as a Hugging Face folder."),
}

#: The packages of the ``bench`` extra: a command that misses one stops with one line naming the extra.
BENCH_MODULES = frozenset(
    {"rliable", "pymoo", "scipy", "pandas", "matplotlib", "imageio", "imageio_ffmpeg", "PIL", "tensorboard"}
)


def command_module(name: str) -> str:
    """The module that registers command ``name`` (its entry in :data:`COMMANDS`), as an import path."""
    module = COMMANDS[name][0]
    return module if "." in module else f"sb3_hddpg.cli.{module}"


class LazyCommands(typer.core.TyperGroup):
    """The command group of ``hddpg-cli``: :data:`COMMANDS`, each module imported when its command is asked for."""

    # click's types as typer vendors them (typer._click) are private: the signatures say Any.
    def list_commands(self, ctx: Any) -> list[str]:
        return list(COMMANDS)

    def get_command(self, ctx: Any, cmd_name: str) -> Any:
        if cmd_name not in self.commands and cmd_name in COMMANDS:
            try:
                importlib.import_module(command_module(cmd_name))
            except ModuleNotFoundError as error:
                missing = (error.name or "").split(".")[0]
                if isinstance(error, MissingExtraError) or missing not in {*BENCH_MODULES, "hddpg_zoo"}:
                    raise
                raise MissingExtraError(
                    f"{cmd_name} needs {missing}, which is not installed: {INSTALL_EXTRA}"
                ) from error
            self.commands.update(typer.main.get_command(app).commands)  # type: ignore[attr-defined]
        return self.commands.get(cmd_name)

    def format_commands(self, ctx: Any, formatter: Any) -> None:
        # Each line whole (wrapped, never cut with an ellipsis), without importing any command's module.
        with formatter.section("Commands"):
            formatter.write_dl([(name, line) for name, (_, line) in COMMANDS.items()])


app = typer.Typer(
    name="hddpg-cli",
    cls=LazyCommands,
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

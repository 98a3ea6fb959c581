"""
The code in the README and the documentation pages, read the way a user copies it: fenced blocks by
language, shell blocks as command lines, and the checks that keep each kind true.

A block that is not meant to run (a fragment of a class, a command that needs a cluster) says so on its first
line, ``# doc: not run``; everything else is checked.
"""

from __future__ import annotations

import re
import shlex
from dataclasses import dataclass
from pathlib import Path

import pytest
import tomllib

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
DOCS = REPO / "docs"
#: The first line of a block that is shown, not run.
NOT_RUN = "# doc: not run"
#: Names the docs import from ``sb3_hddpg`` that this checkout does not define yet: a block using one is
#: skipped (and says so) until the name exists, then runs like every other.
PENDING_API = ("load_workers",)

_FENCE = re.compile(
    r"^(?P<fence>```+|~~~+)\s*\{?(?P<lang>[\w-]*)\}?[^\n]*\n(?P<body>.*?)^(?P=fence)\s*$", re.M | re.S
)


@dataclass(frozen=True)
class Block:
    """A fenced code block: where it is, its language and its text."""

    path: Path
    line: int
    lang: str
    code: str

    @property
    def name(self) -> str:
        return f"{self.path.relative_to(REPO)}:{self.line}"

    @property
    def runs(self) -> bool:
        return not self.code.lstrip().startswith(NOT_RUN)


def pending_api(code: str) -> list[str]:
    """The names of :data:`PENDING_API` that ``code`` imports from ``sb3_hddpg`` and that are still missing."""
    import sb3_hddpg

    imported = re.findall(r"^from sb3_hddpg import (.+)$", code, flags=re.M)
    names = {name.strip() for line in imported for name in line.split(",")}
    return [name for name in PENDING_API if name in names and not hasattr(sb3_hddpg, name)]


def doc_pages() -> list[Path]:
    """The README and every page of the site (the benchmark's generated tables aside)."""
    pages = sorted(p for p in DOCS.rglob("*.md") if "_build" not in p.parts and "results" not in p.parts)
    return [README, *pages]


def blocks(path: Path, langs: tuple[str, ...]) -> list[Block]:
    """Every fenced block of ``path`` in one of ``langs``."""
    text = path.read_text()
    found = []
    for match in _FENCE.finditer(text):
        if match["lang"] in langs:
            line = text.count("\n", 0, match.start()) + 1
            found.append(Block(path, line, match["lang"], match["body"]))
    return found


def command_lines(block: Block) -> list[list[str]]:
    """
    A shell block's commands, continuation lines joined, comments dropped, each split like a shell. The
    body of a ``for VAR in A B ...; do`` loop is checked with VAR at its first value.
    """
    joined = re.sub(r"\\\n\s*", " ", block.code)
    commands, loop_values = [], {}
    for line in joined.splitlines():
        loop = re.fullmatch(r"\s*for (\w+) in (.+?); do\s*", line)
        if loop:
            loop_values[loop[1]] = shlex.split(loop[2])[0]
            continue
        if line.strip() == "done":
            continue
        for name, value in loop_values.items():
            line = re.sub(rf"\$\{{?{name}\b\}}?", value, line)
        words = shlex.split(line, comments=True)
        if words:
            commands.append(words)
    return commands


def make_targets() -> set[str]:
    """The targets the Makefile defines."""
    text = (REPO / "Makefile").read_text()
    return set(re.findall(r"^([\w-]+):", text, flags=re.M))


def extras() -> set[str]:
    """The optional-dependency groups of pyproject.toml."""
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    return set(project["optional-dependencies"])


def parse_cli(words: list[str]) -> None:
    """
    Parse one ``hddpg-cli`` command line without running it: the command exists and every option and value
    is one it accepts (types and ranges included), as Click checks them before calling the command. Run it
    in an empty working folder: the inputs a command line names (a workers folder, a bundle) are made there,
    empty, when the parser asks for them, since whether they exist is the user's state, not the docs'.
    """
    import typer
    from typer.main import get_command

    from sb3_hddpg.cli import app

    group = get_command(app)
    if words in (["--help"], ["--version"]):
        return
    for _ in range(len(words) + 1):
        context = group.make_context("hddpg-cli", list(words[:1]), resilient_parsing=True)
        name, command, rest = group.resolve_command(context, list(words))
        assert command is not None, f"unknown command in {words}"
        try:
            command.make_context(str(name), [w for w in rest if w != "--help"], parent=context)
            return
        except typer.BadParameter as error:
            missing = re.fullmatch(r"no such (file|folder): '(.+)'", error.message)
            if missing is None or Path(missing[2]).exists():
                raise
            made = Path(missing[2])
            made.parent.mkdir(parents=True, exist_ok=True)
            made.touch() if missing[1] == "file" else made.mkdir()


def relative_links(path: Path) -> list[str]:
    """The targets of a Markdown page's relative links (no scheme, no pure anchor)."""
    text = re.sub(r"```.*?```", "", path.read_text(), flags=re.S)
    targets = re.findall(r"\]\(([^)\s]+)\)", text)
    return [t for t in targets if not re.match(r"^[a-z][\w+.-]*:", t) and not t.startswith("#")]


#: Programs of other projects that the docs show (a cluster, a database, a dashboard): the extra that
#: installs each, checked to exist; their own options are theirs to document.
EXTERNAL = {
    "ray": "cluster",
    "optuna-dashboard": "dashboard",
    "tensorboard": None,
    "createdb": None,
    # The shell's own.
    "cd": None,
    "cp": None,
    "mkdir": None,
    "export": None,
}


def check_command(words: list[str]) -> None:
    """One shell command of the docs is true of this checkout; an unknown kind of command fails."""
    program, args = words[0], words[1:]
    if program == "hddpg-cli":
        parse_cli(args)
    elif program in ("python", "python3") and args[:2] == ["-m", "sb3_hddpg"]:
        parse_cli(args[2:])
    elif program in ("python", "python3") and args and args[0] == "-c":
        compile(args[1], shlex.join(words), "exec")
    elif program in ("python", "python3") and args and args[0] == "-m":
        __import__("importlib.util").util.find_spec(args[1]) or _fail(words, f"no module {args[1]!r}")
    elif program in ("python", "python3"):
        assert (REPO / args[0]).is_file(), f"{shlex.join(words)}: no script {args[0]!r} in the checkout"
    elif program == "make":
        missing = set(a for a in args if "=" not in a) - make_targets()
        assert not missing, f"{shlex.join(words)}: the Makefile has no target {sorted(missing)}"
    elif program == "pip":
        _check_pip(words)
    elif program == "source":
        assert args == [".venv/bin/activate"] and "VENV := .venv" in (REPO / "Makefile").read_text()
    elif program in EXTERNAL:
        extra = EXTERNAL[program]
        assert extra is None or extra in extras(), f"{shlex.join(words)}: no extra {extra!r}"
    else:
        _fail(words, "a kind of command the docs test does not know: check it here")


def _check_pip(words: list[str]) -> None:
    for word in words[2:]:
        match = re.fullmatch(r"(?:\.|\./sb3-hddpg|sb3-hddpg)\[([\w,-]+)\]", word)
        if match:
            unknown = set(match[1].split(",")) - extras()
            assert not unknown, f"{shlex.join(words)}: pyproject.toml has no extra {sorted(unknown)}"


def _fail(words: list[str], why: str) -> None:
    raise AssertionError(f"{shlex.join(words)}: {why}")


@pytest.fixture(scope="module")
def tiny_quickstart_workers(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """
    A working folder with ``runs/quickstart/workers`` (both snake workers, trained with the bundled config
    for 300 steps each), the folder the docs' examples read, as ``hddpg-cli quickstart --out runs/quickstart``
    leaves it.
    """
    from sb3_hddpg.training.workers import train_workers

    folder = tmp_path_factory.mktemp("docs")
    train_workers(
        folder / "runs" / "quickstart", timesteps=300, eval_freq=0, eval_episodes=1, checkpoint_freq=0
    )
    return folder

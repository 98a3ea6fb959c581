"""The README is true of this checkout: every command parses, the Python example runs, every link resolves."""

from __future__ import annotations

import re
import runpy
import shlex

import pytest

from tests.doc_blocks import (
    README,
    REPO,
    blocks,
    check_command,
    command_lines,
    pending_api,
    relative_links,
    tiny_quickstart_workers,  # noqa: F401  (a fixture)
)

MAX_WORDS = 1600
SHELL = ("bash", "sh", "console", "shell")


def readme_commands() -> list[list[str]]:
    return [words for block in blocks(README, SHELL) for words in command_lines(block)]


def test_readme_is_a_product_page_within_its_word_limit():
    text = README.read_text()
    assert len(text.split()) <= MAX_WORDS
    # Plain expectations, not run logs: no UTC stamps, dates or commit hashes.
    assert not re.search(r"\bUTC\b|\b20\d\d-\d\d-\d\d\b|\b[0-9a-f]{7,40}\b", text)
    results = re.search(r"<!-- results:start -->\n(.+?)<!-- results:end -->", text, flags=re.S)
    assert results is not None and "docs/RESULTS.md" in results[1]


@pytest.mark.parametrize("words", readme_commands(), ids=shlex.join)
def test_every_readme_command_parses(words, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    check_command(words)


def test_the_readme_shows_the_two_set_up_commands_and_the_cli():
    commands = {shlex.join(words) for words in readme_commands()}
    assert {"make quickstart", "make test", "source .venv/bin/activate"} <= commands
    assert sum(c.startswith("hddpg-cli ") for c in commands) >= 8


@pytest.mark.parametrize("target", relative_links(README))
def test_every_readme_link_resolves(target):
    assert (REPO / target.split("#")[0]).exists(), f"README links to {target!r}, which is not in the checkout"


def test_the_readme_python_example_runs_at_a_tiny_budget(tiny_quickstart_workers, monkeypatch, capsys):  # noqa: F811
    """The example as written, over tiny trained workers, with the manager's budget and episodes lowered."""
    (block,) = [b for b in blocks(README, ("python",))]
    if pending_api(block.code):
        pytest.skip(f"the README example imports {pending_api(block.code)}, not in this checkout yet")
    code, learns = re.subn(r"\.learn\(\s*[\d_]+", ".learn(300", block.code)
    code, episodes = re.subn(r"n_episodes=\d+", "n_episodes=1", code)
    assert learns == 1 and episodes == 1, "the README example changed shape: update this test"
    monkeypatch.chdir(tiny_quickstart_workers)
    script = tiny_quickstart_workers / "example.py"
    script.write_text(code)
    names = runpy.run_path(str(script), run_name="__main__")
    assert (tiny_quickstart_workers / "runs" / "my-hierarchy.zip").is_file()  # under runs/, which git ignores
    # One episode evaluated, however the summary is printed (a dict or a table of words).
    assert re.search(r"'episodes': 1\b|\b1 episodes?\b", capsys.readouterr().out)
    assert names["hierarchy"].env_id == "hddpg/SnakeReach-v0"


@pytest.mark.parametrize(
    "words",
    [
        ["hddpg-cli", "evaluate", "runs/manager/hierarchy.zip", "--episodes", "none"],
        ["hddpg-cli", "train-manager", "--no-such-option"],
        ["hddpg-cli", "no-such-command"],
        ["make", "no-such-target"],
        ["pip", "install", "-e", ".[no-such-extra]"],
        ["curl", "example.org"],
    ],
    ids=shlex.join,
)
def test_the_command_check_refuses_what_would_fail_for_a_user(words, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(Exception):  # noqa: B017  (a usage error, an assertion: any failure is the point)
        check_command(words)

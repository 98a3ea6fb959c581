"""
The documentation site is true of this checkout: every command line of its pages parses, every script and
make target they name exists, and every Python block runs at a tiny budget (a page's blocks in order, in
one fresh interpreter, in a folder holding tiny trained workers and a bundle, as a reader would follow it).
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.doc_blocks import (
    DOCS,
    README,
    REPO,
    blocks,
    check_command,
    command_lines,
    doc_pages,
    pending_api,
    tiny_quickstart_workers,  # noqa: F401  (a fixture)
)

PAGES = [page for page in doc_pages() if page != README]
SHELL = ("bash", "sh", "console", "shell")
#: Budgets and counts lowered in every Python block: pattern -> replacement.
TINY = {
    r"\.learn\(\s*[\d_]+": ".learn(300",
    r"\b(n_episodes|n_trials|n_evaluations|n_jobs)=[\d_]+": r"\1=1",
    r"\btimesteps=[\d_]+": "timesteps=300",
}


def page_id(page: Path) -> str:
    return str(page.relative_to(DOCS))


def tiny(code: str) -> str:
    for pattern, replacement in TINY.items():
        code = re.sub(pattern, replacement, code)
    return code


def commands() -> list[tuple[str, list[str]]]:
    return [
        (block.name, words)
        for page in PAGES
        for block in blocks(page, SHELL)
        if block.runs
        for words in command_lines(block)
    ]


@pytest.mark.parametrize(
    ("where", "words"), commands(), ids=lambda value: shlex.join(value) if isinstance(value, list) else value
)
def test_every_command_of_the_docs_parses(where, words, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    check_command(words)


@pytest.fixture(scope="module")
def tiny_bundle(tiny_quickstart_workers: Path) -> Path:  # noqa: F811
    """The tiny workers' folder with a tiny manager's bundle beside them, as ``hierarchy.zip``."""
    from sb3_hddpg.training.training import train_manager

    run = tiny_quickstart_workers / "runs" / "quickstart"
    train_manager(run, run, timesteps=100, eval_freq=0, eval_episodes=1, checkpoint_freq=0)
    shutil.copy(run / "hierarchy.zip", tiny_quickstart_workers / "hierarchy.zip")
    return tiny_quickstart_workers


#: Pages whose blocks take longer than the default suite allows (a tuning study, however tiny).
SLOW_PAGES = ("TUNING.md",)
RUNNABLE = [
    pytest.param(page, marks=[pytest.mark.slow] if page_id(page) in SLOW_PAGES else [])
    for page in PAGES
    if any(block.runs for block in blocks(page, ("python",)))
]


@pytest.mark.parametrize("page", RUNNABLE, ids=page_id)
def test_every_python_block_of_a_page_runs_at_a_tiny_budget(page, tiny_bundle, tmp_path):
    folder = tmp_path / "reader"
    shutil.copytree(tiny_bundle, folder)
    runnable = [block for block in blocks(page, ("python",)) if block.runs]
    # A block that imports a name this checkout lacks yet waits for it; the page's other blocks run now.
    ready = [block for block in runnable if not pending_api(block.code)]
    if not ready:
        pytest.skip(f"{page_id(page)} imports names from sb3_hddpg that are not in this checkout yet")
    code = "\n\n".join(tiny(block.code) for block in ready)
    script = folder / "page.py"
    script.write_text(code)
    path = os.pathsep.join(p for p in (str(REPO), os.environ.get("PYTHONPATH", "")) if p)
    env = {**os.environ, "PYTHONPATH": path, "SDL_VIDEODRIVER": "dummy", "MPLBACKEND": "Agg"}
    result = subprocess.run(
        [sys.executable, str(script)], cwd=folder, env=env, capture_output=True, text=True, timeout=600
    )
    assert result.returncode == 0, f"{page_id(page)}:\n{result.stdout[-2000:]}\n{result.stderr[-4000:]}"


def test_blocks_that_do_not_run_are_few_and_say_why():
    shown = [block for page in doc_pages() for block in blocks(page, ("python", *SHELL)) if not block.runs]
    assert len(shown) <= 6, [block.name for block in shown]
    for block in shown:
        assert re.match(r"# doc: not run \(.+\)", block.code.lstrip()), (
            f"{block.name}: say why it does not run"
        )

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
    from sb3_hddpg.training.manager import train_manager

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


# ----------------------------------------------------------------------------------- no lab notebook in prose
#: What restates a run log instead of interpreting a record: a date, a clock time, a commit hash. The
#: records under docs/results/ and the git history hold those; the CHANGELOG is dated by its nature.
RUN_LOG = {
    "a date": re.compile(
        r"\b(?:19|20)\d{2}-[01]\d-[0-3]\d\b"  # 2026-12-01, also inside an ISO time stamp
        r"|\b20\d{2}[01]\d[0-3]\d-\d{6}\b"  # a folder stamp such as replaced-20261202-045121
        r"|\b\d{1,2} (?:Jan|Feb|Mar|Apr|May|Jun|Jul|Aug|Sep|Oct|Nov|Dec)[a-z]* 20\d{2}\b"
        r"|\b(?:Jan|Feb|Mar|Apr|May|Jun|Jul|Aug|Sep|Oct|Nov|Dec)[a-z]* \d{1,2}, 20\d{2}\b"
    ),
    "a clock time": re.compile(
        r"\b[0-2]?\d:[0-5]\d(?::[0-5]\d)?(?:\s*-\s*[0-2]?\d:[0-5]\d(?::[0-5]\d)?)?\s*(?:UTC|GMT)\b"
        r"|\b(?:UTC|GMT)\s*[0-2]?\d:[0-5]\d\b"
        r"|\b[0-2]\d:[0-5]\d\s*-\s*[0-2]\d:[0-5]\d\b"  # a span of the clock, 21:56-22:52
        r"|\b(?:at|from|until|since|by)\s+[0-2]\d:[0-5]\d(?:\s*-\s*[0-2]?\d:[0-5]\d)?(?:\s*(?:UTC|GMT))?"
    ),
    "a commit hash": re.compile(
        r"`[0-9a-f]{7,40}`"  # a code span holding only hex digits, as a hash is quoted (write 1_000_000)
        r"|\bcommits?\s+`?[0-9a-f]{7,40}\b"
        r"|\b(?=[0-9a-f]*\d)(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}\b"  # a bare hex word with letters and digits
    ),
}


def run_log_stamps(text: str) -> list[tuple[int, str, str]]:
    """Every date, clock time and commit hash of ``text``: ``(line, kind, what)``."""
    found = []
    for number, line in enumerate(text.splitlines(), start=1):
        for kind, pattern in RUN_LOG.items():
            found.extend((number, kind, match.group(0)) for match in pattern.finditer(line))
    return found


def test_the_run_log_detector_finds_stamps_and_spares_figures():
    stamped = (
        "Started on 2026-12-01 at 21:56 UTC (`721f12d`) and resumed at 06:15-07:14 UTC; see commit 43d7648.\n"
        "Its runs are in `runs/bench-e20/replaced-20261202-045121/`, from `4834694` (c64a145b), 2 December 2026.\n"
        "Console logs: 23:29-23:50, then 6 min 13 s at 05:06."
    )
    kinds = [kind for _, kind, _ in run_log_stamps(stamped)]
    assert kinds.count("a date") == 3, run_log_stamps(stamped)
    assert kinds.count("a clock time") == 4
    assert kinds.count("a commit hash") == 4
    figures = (
        "seed 99999999999 (over 2^32 - 1); `buffer_size: 1000000`, `1_000_000`; 100,000 steps; lr 4.7e-3; ratio 4:1;\n"
        "`--ray-address 6:621`; old runs move to `replaced-<UTC time>/`; a sha256 of 64 hex digits:\n"
        "0123456789abcdef0123456789abcdef0123456789abcdef0123456789abcdef; seeds 15000-15019; 340k; 2022."
    )
    assert run_log_stamps(figures) == []


#: The README and every page of the site but the changelog.
UNDATED_PAGES = [page for page in doc_pages() if page.name.lower() != "changelog.md"]


@pytest.mark.parametrize("page", UNDATED_PAGES, ids=lambda page: str(page.relative_to(REPO)))
def test_docs_interpret_records_and_hold_no_run_log(page):
    stamps = run_log_stamps(page.read_text())
    assert stamps == [], (
        f"{page.relative_to(REPO)} restates a run log (dates, clock times and commit hashes belong in the "
        f"records and the git history; say what changed and how to reproduce it): "
        + "; ".join(f"line {line}: {kind} {what!r}" for line, kind, what in stamps)
    )


def test_the_benchmark_guide_lists_every_registered_method():
    from hddpg_zoo.benchmark import METHOD_REGISTRY

    section = (DOCS / "guide" / "benchmark.md").read_text().split("## The methods", 1)[1].split("\n## ", 1)[0]
    missing = [name for name in METHOD_REGISTRY if f"`{name}`" not in section]
    assert not missing, f"docs/guide/benchmark.md's methods table lacks {missing}"

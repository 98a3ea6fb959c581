"""After set-up the next command works: `make quickstart` says to activate the venv; install lines run in a checkout."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.skipif(shutil.which("make") is None, reason="needs make")
def test_make_quickstart_ends_by_printing_the_activation_and_next_commands():
    dry = subprocess.run(["make", "-n", "quickstart"], cwd=ROOT, capture_output=True, text=True, check=True)
    lines = dry.stdout.splitlines()
    train = next(i for i, line in enumerate(lines) if "hddpg-cli quickstart" in line)
    after = "\n".join(lines[train + 1 :])
    assert "source .venv/bin/activate" in after
    assert "hddpg-cli evaluate runs/quickstart/hierarchy.zip" in after
    assert "examples/own_manager.py runs/quickstart/workers" in after
    assert "--out runs/quickstart" in lines[train]


def test_docs_install_from_the_checkout_and_name_no_unpublished_package():
    for page in sorted((ROOT / "docs").glob("*.md")):
        for number, line in enumerate(page.read_text().splitlines(), 1):
            for command in re.findall(r"pip install [^`\n)]*", line):
                where = f"{page.name}:{number}: {command}"
                assert "sb3-hddpg" not in command, where  # not published on PyPI
                if "[" in command:
                    assert 'pip install -e ".[' in command, where

"""Run ``hddpg-cli`` in a subprocess, as a user would: ``python -m sb3_hddpg``, this checkout first on the path."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: The command line that starts ``hddpg-cli`` in a fresh interpreter.
CLI = [sys.executable, "-m", "sb3_hddpg"]


def run_cli(*args: str, timeout: float = 600, check: bool = False) -> subprocess.CompletedProcess:
    path = os.pathsep.join(p for p in (str(REPO), os.environ.get("PYTHONPATH", "")) if p)
    env = {**os.environ, "SDL_VIDEODRIVER": "dummy", "COLUMNS": "200", "PYTHONPATH": path}
    result = subprocess.run([*CLI, *map(str, args)], capture_output=True, text=True, timeout=timeout, env=env)
    if check and result.returncode != 0:
        raise AssertionError(
            f"hddpg-cli {' '.join(map(str, args))} failed ({result.returncode}):\n{result.stdout}\n{result.stderr}"
        )
    return result

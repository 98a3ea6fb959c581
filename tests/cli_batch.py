"""
Run many ``hddpg-cli`` command lines in ONE subprocess, as ``python -m sb3_hddpg ...`` would run each of them.

Starting Python, torch and SB3 takes seconds per process on a busy machine, so a table of dozens of
command lines is run here, in a single fresh interpreter: each command line gets ``sb3_hddpg.cli.main``,
its own captured stdout and stderr, and its exit code from ``SystemExit``; an exception escaping ``main``
is recorded as the interpreter would print it (a traceback on stderr, exit code 1).

Usage: ``python -m tests.cli_batch < commands.json > results.json`` (a JSON list of argument lists in, a
JSON list of ``{"code", "stdout", "stderr"}`` out).
"""

from __future__ import annotations

import contextlib
import io
import json
import subprocess
import sys
import traceback
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run_one(argv: list[str]) -> dict[str, object]:
    """Run one command line through the CLI's entry point and capture what a user would see."""
    from sb3_hddpg.cli import main

    out, err = io.StringIO(), io.StringIO()
    code: object = 0
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            main(argv)
        except SystemExit as exit_:
            code = exit_.code if exit_.code is not None else 0
        except BaseException:  # what the interpreter would print for an uncaught exception
            err.write(traceback.format_exc())
            code = 1
    return {"code": code if isinstance(code, int) else 1, "stdout": out.getvalue(), "stderr": err.getvalue()}


def run_batch(
    commands: list[list[str]], timeout: float = 900, cwd: Path = ROOT
) -> list[subprocess.CompletedProcess]:
    """
    Run ``commands`` in one fresh interpreter, from the folder ``cwd``; one ``CompletedProcess``-like
    result per command.
    """
    import os

    env = {**os.environ, "SDL_VIDEODRIVER": "dummy", "COLUMNS": "200", "PYTHONPATH": str(ROOT)}
    env.pop("HDDPG_DEBUG", None)
    done = subprocess.run(
        [sys.executable, "-m", "tests.cli_batch"],
        input=json.dumps(commands),
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
        cwd=cwd,
    )
    if done.returncode != 0:
        raise RuntimeError(f"the batch runner itself failed ({done.returncode}):\n{done.stderr[-3000:]}")
    return [
        subprocess.CompletedProcess(argv, r["code"], r["stdout"], r["stderr"])
        for argv, r in zip(commands, json.loads(done.stdout))
    ]


if __name__ == "__main__":
    commands = json.load(sys.stdin)
    real_stdout = sys.stdout
    results = [run_one([str(a) for a in argv]) for argv in commands]
    real_stdout.write(json.dumps(results))

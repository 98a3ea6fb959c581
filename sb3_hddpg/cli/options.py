"""Option validators shared by the commands: each names the option and the offending value."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import typer

#: Files whose presence means a folder already holds results of ours.
RESULT_MARKERS = (
    "workers/manifest.json",
    "hierarchy.zip",
    "results.json",
    "benchmark.json",
    "flat",
    "checkpoints",
    "study.db",
)


def at_least(minimum: int):
    """A typer callback that accepts integers >= ``minimum`` (``None`` passes)."""

    def check(value: int | None) -> int | None:
        if value is not None and value < minimum:
            raise typer.BadParameter(f"must be >= {minimum}, got {value}")
        return value

    return check


def positive_float(value: float | None) -> float | None:
    """A typer callback that accepts finite floats > 0 (``None`` passes)."""
    if value is not None and (not math.isfinite(value) or value <= 0):
        raise typer.BadParameter(f"must be a finite number > 0, got {value}")
    return value


def prepare_out_dir(out: Path, resume: bool, force: bool) -> Path:
    """
    Refuse to overwrite a folder that already holds results unless ``--resume`` or ``--force``;
    ``--force`` clears it first.
    """
    if out.exists() and not out.is_dir():
        raise typer.BadParameter(f"is a file, not a folder: {str(out)!r}", param_hint="'--out'")
    held = [m for m in RESULT_MARKERS if (out / m).exists()]
    if held and not (resume or force):
        raise typer.BadParameter(
            f"{str(out)!r} already holds results ({held[0]}); pass --resume to continue or --force to overwrite",
            param_hint="'--out'",
        )
    if held and force and not resume:
        shutil.rmtree(out)
    out.mkdir(parents=True, exist_ok=True)
    return out

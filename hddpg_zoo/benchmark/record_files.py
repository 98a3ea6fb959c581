"""
Where a benchmark folder keeps each task's files: a seed's models (``seed-<s>/``), a finished task's record
(``records/<method>/seed-<s>.json``, what ``--resume`` keeps) and the wall time an interrupted task has spent;
reading a record back, and a value as a record stores it.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from hddpg_zoo.benchmark.tasks import Task
from hddpg_zoo.records import read_benchmark_record
from sb3_hddpg.artifacts.limits import read_json_file

#: A record's field naming the record it was copied from (relative to the folder): a run of another
#: benchmark, whose models stay there (:func:`~.workers_source.copy_flat_runs`).
COPIED_FROM = "copied_from"


def seed_dir(out: Path, seed: int) -> Path:
    """The folder of one seed's models."""
    return out / f"seed-{seed}"


def record_path(out: Path, task: Task) -> Path:
    """Where a finished task's record goes."""
    return out / "records" / task.method / f"seed-{task.seed}.json"


def read_record(out: Path, task: Task) -> dict[str, Any] | None:
    """A finished task's record, or ``None``."""
    path = record_path(out, task)
    if not path.exists():
        return None
    record = read_record_file(path)
    return record if record.get("status") == "done" else None


def read_record_file(path: Path) -> dict[str, Any]:
    """
    A task's record file as its JSON object, read and checked by
    :func:`~hddpg_zoo.records.read_benchmark_record` (the JSON size and depth limits; ``status``
    and ``method`` strings, ``seed`` a whole number in ``[0, MAX_SEED]``).

    :raises ValueError: one line naming the file (a ``LimitError`` for one too big or too deep).
    """
    return read_benchmark_record(path).to_json()


def elapsed_path(out: Path, task: Task) -> Path:
    """Where an interrupted task keeps the wall time it has spent so far, until an invocation finishes it."""
    return seed_dir(out, task.seed) / f".elapsed-{task.method}.json"


def time_spent_before(out: Path, task: Task) -> float:
    """The wall time earlier, interrupted invocations spent on ``task`` (0 if none, or if unreadable)."""
    try:
        kept = read_json_file(elapsed_path(out, task))
    except (OSError, ValueError):
        return 0.0
    spent = kept.get("wall_time_s") if isinstance(kept, dict) else None
    return float(spent) if isinstance(spent, (int, float)) and spent >= 0 and math.isfinite(spent) else 0.0


def as_stored(value: Any) -> Any:
    """A value as JSON stores it (tuples become lists), so a config block compares with its stored copy."""
    return json.loads(json.dumps(value))

"""A benchmark task's record (``records/METHOD/seed-N.json``)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sb3_hddpg.artifacts.limits import MAX_SEED, read_json_record
from sb3_hddpg.artifacts.records.base import (
    BENCHMARK_RECORD_VERSION,
    JsonObject,
    JsonRecord,
    check_version,
)

#: A benchmark record's own fields; the rest are its method's results.
_RECORD_FIELDS = ("record_version", "method", "seed", "status")


@dataclass(frozen=True, eq=False)
class BenchmarkRecord(JsonRecord):
    """
    One benchmark task's record (``records/METHOD/seed-N.json``): which run it is, whether it finished,
    and what its method measured.

    :param method: the run key (a method name, ``NAME@PREFERENCE`` for a preference run, or ``workers``).
    :param seed: the seed.
    :param status: ``done`` for a finished run.
    :param results: the method's fields (config blocks, test evaluation, episodes, history, wall times...),
        kept as written: each consumer (statistics, report, export) reads its own.
    :param record_version: the record's version.
    """

    method: str
    seed: int
    status: str = "done"
    results: Mapping[str, Any] = field(default_factory=dict)
    record_version: int = BENCHMARK_RECORD_VERSION

    def to_json(self) -> JsonObject:
        return {
            "record_version": self.record_version,
            "method": self.method,
            "seed": self.seed,
            "status": self.status,
            **{k: v for k, v in self.results.items() if k not in _RECORD_FIELDS},
        }

    @classmethod
    def from_json(cls, value: object, what: str) -> BenchmarkRecord:
        """
        The one reader of a record (parsed by the limited JSON reader): an object whose ``status`` and
        ``method`` are strings, whose ``seed`` is a whole number in ``[0, MAX_SEED]`` and whose version
        (``1`` when absent, as in the first records) is one this library reads.

        :raises ValueError: one line naming ``what``.
        """
        seed = value.get("seed") if isinstance(value, dict) else None
        if (
            not isinstance(value, dict)
            or not isinstance(value.get("status"), str)
            or not isinstance(value.get("method"), str)
            or isinstance(seed, bool)
            or not isinstance(seed, int)
            or not 0 <= seed <= MAX_SEED
        ):
            raise ValueError(f"{what}: expected a benchmark record (status, method, seed in [0, {MAX_SEED}])")
        version = check_version(value.get("record_version"), BENCHMARK_RECORD_VERSION, what)
        results = {k: v for k, v in value.items() if k not in _RECORD_FIELDS}
        return cls(value["method"], seed, value["status"], results, version)


def benchmark_record(method: str, seed: int, results: Mapping[str, Any]) -> BenchmarkRecord:
    """The one builder of a finished task's record, at this library's version (see :class:`BenchmarkRecord`)."""
    return BenchmarkRecord(method, seed, "done", dict(results), BENCHMARK_RECORD_VERSION)


def read_benchmark_record(path: str | Path) -> BenchmarkRecord:
    """
    A task's record file, through the JSON size and depth limits (:meth:`BenchmarkRecord.from_json`).

    :raises ValueError: one line naming the file (a ``LimitError`` for one too big or too deep).
    """
    value = read_json_record(path, f"{path}: not a readable benchmark record")
    return BenchmarkRecord.from_json(value, str(path))

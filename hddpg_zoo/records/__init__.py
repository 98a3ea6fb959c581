"""
The benchmark's records, beside the library's (:mod:`sb3_hddpg.artifacts.records`), each a frozen dataclass
with one builder and one reader:

- :class:`BenchmarkRecord`: a task's ``records/METHOD/seed-N.json`` (:func:`benchmark_record`,
  :func:`read_benchmark_record`).
- :class:`BenchmarkResults`: a benchmark's ``results.json`` (:func:`benchmark_results`,
  :func:`read_benchmark_results`), its parts :class:`MethodResults` and :class:`Comparison`.
"""

from hddpg_zoo.records.benchmark import BenchmarkRecord, benchmark_record, read_benchmark_record
from hddpg_zoo.records.results import (
    BenchmarkResults,
    Comparison,
    MethodResults,
    benchmark_results,
    read_benchmark_results,
)
from hddpg_zoo.records.results_leaves import Summary

__all__ = [
    "BenchmarkRecord",
    "BenchmarkResults",
    "Comparison",
    "MethodResults",
    "Summary",
    "benchmark_record",
    "benchmark_results",
    "read_benchmark_record",
    "read_benchmark_results",
]

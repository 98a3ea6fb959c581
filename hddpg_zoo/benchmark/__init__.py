"""
The benchmark of paper Section 3.3-3.4: every method for every seed, one common metric, seed statistics.

Methods are records in :data:`METHOD_REGISTRY` (:class:`Method`: name, whether it needs its seed's
workers, how it runs, its budget, its colour); adding a method is one :func:`register_method` call. Built in:

- ``hddpg``: the two workers, then a manager with equal preferences (paper Algorithm 1);
- ``hddpg-goal`` / ``hddpg-avoid``: managers preferring one worker by ``bias`` (15 %, paper Figure 10);
- ``ham``: the hand-written switch over the same workers (:mod:`sb3_hddpg.baselines.ham`), no training;
- ``ddpg``, ``td3``, ``sac`` (and ``tqc``): one flat agent on the combined reward, each given the
  hierarchy's total env steps (workers + manager), configured by ``zoo_configs/<algo>.yml``;
- on another env (``--env``, :mod:`.env_methods`): each worker alone (``term1-only``...), flat DQN/QR-DQN,
  managers in the discrete selection mode (``hddpg-dqn``, ``hddpg-qrdqn``) and, on highway-env, the
  time-to-collision switch (``ttc``, ``ttc-tuned``).

**Scenarios.** ``standard`` runs every method once per seed. ``transfer`` (the paper's "minimal learning
period") trains each seed's workers once, then for every given preference (e.g. ``goal=2,avoid=1``) a
manager with those factors and each flat agent from scratch on the same scalarised reward
(:class:`~sb3_hddpg.hierarchy.preference.PreferenceReward`); :func:`transfer_results` compares the env steps each
needs to reach 90 % of its final score. A run on a preference is the method key ``<method>@<preference>``.

Workers are trained once per seed and shared by that seed's ``hddpg*`` and ``ham`` runs; with
``workers_from`` they are copied from another benchmark that trained the same ones (e.g. the transfer
scenario reusing a standard run's workers, :func:`check_workers_source`). ``front`` measures every hierarchy
over the whole trade-off (:mod:`.front`): per seed a preference-conditioned manager swept over 7 preferences,
a manager per preference, HAM over a threshold sweep and each worker alone, with pymoo hypervolumes. Every run is an
independent process (``n_jobs`` at a time, one torch thread each); a run's dependencies (its seed's
workers) are scheduled before it. Every finished run writes a record atomically to
``DIR/records/<method>/seed-<s>.json``, which :func:`run_benchmark` skips when resuming.

**Metric.** ``mean_reach_reward``, the env's combined normalised reward, on fixed test seeds disjoint from
the learning-curve seeds (see :mod:`.statistics`).

The package follows the benchmark's sections, each a module: :mod:`.methods` (the records),
:mod:`.settings` (settings, tasks, plan), :mod:`.run` (one task, the whole run on the process runner),
:mod:`.statistics` and :mod:`.report`. Everything public is re-exported here.
"""

from __future__ import annotations

from hddpg_zoo.benchmark.comparisons import compare
from hddpg_zoo.benchmark.env_methods import (
    DISCRETE_FLAT_METHODS,
    DISCRETE_MANAGERS,
    ENV_METHODS,
    ENV_ONLY_METHODS,
    default_env_methods,
    ttc_workers,
)
from hddpg_zoo.benchmark.front import FRONT_METHOD, SWEEP
from hddpg_zoo.benchmark.front_pages import front_figure
from hddpg_zoo.benchmark.front_points import (
    PLANES,
    REFERENCE_POINTS,
    SNAKE_FRONT,
    FrontPoint,
    FrontSpec,
    env_front,
    hypervolume,
)
from hddpg_zoo.benchmark.front_statistics import front_results
from hddpg_zoo.benchmark.methods import (
    DEFAULT_ENV_METHODS,
    DEFAULT_METHODS,
    FLAT_HER_METHODS,
    FLAT_METHODS,
    METHOD_REGISTRY,
    METHODS,
    WORKERS,
    Method,
    method_key,
    register_method,
    split_key,
)
from hddpg_zoo.benchmark.record_files import read_record, read_record_file, record_path, seed_dir
from hddpg_zoo.benchmark.report import (
    CSV_KEYS,
    OUTPUT_FILES,
    evaluation_rows,
    final_scores_text,
    flat_reaches_text,
    markdown_report,
    output_files_in,
    write_csv,
    write_outputs,
)
from hddpg_zoo.benchmark.run import (
    changed_settings,
    check_redo,
    machine_info,
    run_benchmark,
    run_task,
    task_job,
)
from hddpg_zoo.benchmark.settings import (
    DEFAULT_TRANSFER_METHODS,
    DEFAULT_TRANSFER_PREFERENCES,
    FRONT_METHODS,
    SCENARIOS,
    BenchmarkSettings,
    canonical_preference,
)
from hddpg_zoo.benchmark.statistics import (
    FINAL_METRICS,
    SLOPE_UNIT,
    TRANSFER_FRACTION,
    compute_results,
    curve_bands,
    curve_statistics,
    normalised_term_sums,
    preference_score,
    steps_to_fraction,
    transfer_results,
)
from hddpg_zoo.benchmark.tasks import Task, comparison_pairs, plan_tasks, task_cost
from hddpg_zoo.benchmark.workers_source import check_workers_source
from sb3_hddpg.artifacts.records import BENCHMARK_RECORD_VERSION as RECORD_VERSION

__all__ = [
    "CSV_KEYS",
    "DEFAULT_ENV_METHODS",
    "DEFAULT_METHODS",
    "DEFAULT_TRANSFER_METHODS",
    "DEFAULT_TRANSFER_PREFERENCES",
    "DISCRETE_FLAT_METHODS",
    "DISCRETE_MANAGERS",
    "ENV_METHODS",
    "ENV_ONLY_METHODS",
    "FINAL_METRICS",
    "FLAT_HER_METHODS",
    "FLAT_METHODS",
    "FRONT_METHOD",
    "FRONT_METHODS",
    "METHODS",
    "METHOD_REGISTRY",
    "OUTPUT_FILES",
    "PLANES",
    "RECORD_VERSION",
    "REFERENCE_POINTS",
    "SCENARIOS",
    "SLOPE_UNIT",
    "SNAKE_FRONT",
    "SWEEP",
    "TRANSFER_FRACTION",
    "WORKERS",
    "BenchmarkSettings",
    "FrontPoint",
    "FrontSpec",
    "Method",
    "Task",
    "canonical_preference",
    "changed_settings",
    "check_redo",
    "check_workers_source",
    "compare",
    "comparison_pairs",
    "compute_results",
    "curve_bands",
    "curve_statistics",
    "default_env_methods",
    "env_front",
    "evaluation_rows",
    "final_scores_text",
    "flat_reaches_text",
    "front_figure",
    "front_results",
    "hypervolume",
    "machine_info",
    "markdown_report",
    "method_key",
    "normalised_term_sums",
    "output_files_in",
    "plan_tasks",
    "preference_score",
    "read_record",
    "read_record_file",
    "record_path",
    "register_method",
    "run_benchmark",
    "run_task",
    "seed_dir",
    "split_key",
    "steps_to_fraction",
    "task_cost",
    "task_job",
    "transfer_results",
    "ttc_workers",
    "write_csv",
    "write_outputs",
]

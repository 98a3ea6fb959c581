"""
Running a benchmark: each task in its own process on the process runner (:mod:`sb3_hddpg.experiments.runner`),
its record written atomically to ``DIR/records/<method>/seed-<s>.json`` (what ``--resume`` keeps), then the
statistics and the report.
"""

from __future__ import annotations

import json
import os
import platform
import time
from collections.abc import Callable
from dataclasses import asdict, fields, replace
from pathlib import Path
from typing import Any

from sb3_hddpg.artifacts.io import atomic_write_json
from sb3_hddpg.experiments.benchmark.methods import (
    WORKERS,
    history_of,
    random_reference,
    split_key,
    workers_steps,
)
from sb3_hddpg.experiments.benchmark.report import write_outputs
from sb3_hddpg.experiments.benchmark.settings import BenchmarkSettings, Task, plan_tasks, task_cost
from sb3_hddpg.experiments.benchmark.statistics import compute_results
from sb3_hddpg.experiments.executors import make_executor
from sb3_hddpg.experiments.runner import Job, run_jobs
from sb3_hddpg.training.training import train_workers

#: Bumped when a record's meaning changes.
RECORD_VERSION = 1


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
    record = json.loads(path.read_text())
    return record if record.get("status") == "done" else None


def run_task(task: Task, settings: BenchmarkSettings, out: str | Path) -> dict[str, Any]:
    """
    Run one task to the end and write its record atomically (the function each process runs).

    :param task: what to run.
    :param settings: the benchmark's settings.
    :param out: the benchmark folder.
    :return: the record written.
    """
    out = Path(out)
    folder = seed_dir(out, task.seed)
    start = time.perf_counter()
    record: dict[str, Any] = {
        "record_version": RECORD_VERSION,
        "method": task.method,
        "seed": task.seed,
        "status": "done",
    }
    spec = task.spec
    if spec is None:
        record.update(_run_workers(task, settings, folder))
    else:
        record.update(spec.run(task, settings, folder))
        preference = split_key(task.method)[1]
        if preference is not None:
            record["preference"] = preference
            record["reference"] = random_reference(settings)
    record["wall_time_s"] = time.perf_counter() - start
    atomic_write_json(record_path(out, task), record)
    return record


def _run_workers(task: Task, settings: BenchmarkSettings, folder: Path) -> dict[str, Any]:
    """Train (or finish) a seed's two workers."""

    budget = settings.worker_timesteps or settings.workers_budget
    run = settings.run_options(task.seed, settings.worker_timesteps, budget)
    manifest = train_workers(folder, env=settings.terms_env, run=run)
    return {
        "worker_timesteps": workers_steps(folder),
        "workers": {
            name: {"timesteps": entry["timesteps_trained"], "metrics": entry["metrics"]}
            for name, entry in manifest["workers"].items()
        },
        "history": {
            name: history_of(folder / "evaluations" / f"{name}.json", 0) for name in manifest["workers"]
        },
    }


def task_job(task: Task, settings: BenchmarkSettings, out: Path) -> Job:
    """
    A task as a job of the process runner: after its seed's workers (when it needs them), seed by seed,
    longest (by budget) first within a seed.
    """
    after = (Task(WORKERS, task.seed).label,) if task.needs_workers else ()
    return Job(
        task.label,
        run_task,
        (task, settings, str(out)),
        cost=task_cost(task, settings),
        group=settings.seeds.index(task.seed),
        after=after,
    )


#: Settings a resumed benchmark may change (every other must be as the folder's ``benchmark.json`` says).
RESUME_MAY_CHANGE = ("methods", "seeds")


def run_benchmark(
    settings: BenchmarkSettings,
    out: str | Path,
    n_jobs: int | None = 1,
    resume: bool = False,
    on_event: Callable[[str, Task, dict[str, Any] | None], None] | None = None,
    ray_address: str | None = None,
) -> dict[str, Any]:
    """
    Run every task not yet finished, ``n_jobs`` at a time, then compute and write the results.

    The tasks run on the process runner (:mod:`sb3_hddpg.experiments.runner`, see :func:`task_job`): workers
    of a seed before the runs that need them, seed by seed, longest first; Ctrl-C or SIGTERM makes every
    running task checkpoint and stop, so that ``resume`` continues it.

    :param settings: what to run.
    :param out: the benchmark folder (``benchmark.json``, ``records/``, ``seed-*/``, results).
    :param n_jobs: processes (or Ray tasks) at a time (``None``: 1 locally, every CPU of a Ray cluster).
    :param resume: keep finished runs (their records) and continue interrupted ones from checkpoints; the
        methods and seeds may differ from the folder's (new runs are added), every other setting may not.
    :param on_event: called with ``("start" | "done" | "skip" | "failed", task, record or None)``.
    :param ray_address: run each task as a Ray task on the cluster at this address (``auto`` or
        ``HOST:PORT``; every node must see ``out`` at the same path, and a task lost with its node is run
        again from its checkpoint: :mod:`sb3_hddpg.experiments.ray_executor`); ``None``: local processes.
    :return: the results (also written to ``out/results.json``).
    """
    if n_jobs is not None and n_jobs < 1:
        raise ValueError(f"Expected `n_jobs` >= 1, actually: {n_jobs}")
    out = Path(out)
    notify = on_event or (lambda kind, task, record: None)
    settings_path = out / "benchmark.json"
    stored = asdict(settings)
    if resume and settings_path.exists():
        previous = json.loads(settings_path.read_text())["settings"]
        # Settings added since that benchmark was made hold their defaults in it.
        defaults = asdict(BenchmarkSettings())
        previous = {**{f.name: defaults[f.name] for f in fields(BenchmarkSettings)}, **previous}
        # Methods and seeds may change: each run is its own record, made with the same budgets and episodes
        # whatever else ran beside it, so a resumed benchmark can grow (or report a subset).
        changed = sorted(k for k in stored if k not in RESUME_MAY_CHANGE and previous.get(k) != stored[k])
        if changed:
            raise ValueError(
                f"Cannot resume {str(out)!r} with different settings ({', '.join(changed)} changed); "
                "run with the same options, or use --force to start over"
            )
    atomic_write_json(settings_path, {"settings": stored, "machine": machine_info()})

    tasks = plan_tasks(settings)
    records: dict[Task, dict[str, Any]] = {}
    for task in tasks:
        record = read_record(out, task) if resume else None
        if record is not None:
            records[task] = record
            notify("skip", task, record)
    start = time.perf_counter()
    by_label = {task.label: task for task in tasks}
    kept = {task.label for task in records}
    jobs = [task_job(task, settings, out) for task in tasks if task not in records]
    outcome = run_jobs(
        [replace(job, after=tuple(d for d in job.after if d not in kept)) for job in jobs],
        make_executor(n_jobs, ray_address=ray_address),
        on_event=lambda kind, job, value: notify(kind, by_label[job.key], value if kind == "done" else None),
    )
    records.update({by_label[label]: record for label, record in outcome.results.items()})
    failed = {by_label[label]: outcome.failure_message(label) for label in outcome.failures}
    wall = time.perf_counter() - start
    results = compute_results(settings, [records[t] for t in tasks if t in records])
    results["wall_time_s_this_invocation"] = wall
    results["failures"] = {t.label: message for t, message in failed.items()}
    results["machine"] = machine_info()
    write_outputs(out, results, [records[t] for t in tasks if t in records])
    return results


def machine_info() -> dict[str, Any]:
    """The machine a benchmark ran on (for the record: timings depend on it)."""
    cpu = platform.processor() or ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"nproc": os.cpu_count(), "cpu": cpu, "platform": platform.platform()}

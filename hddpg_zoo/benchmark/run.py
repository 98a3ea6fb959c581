"""
Running a benchmark: each task in its own process on the process runner (:mod:`hddpg_zoo.runner`),
its record written atomically to ``DIR/records/<method>/seed-<s>.json`` (what ``--resume`` keeps), then the
statistics and the report.
"""

from __future__ import annotations

import contextlib
import functools
import os
import platform
import shutil
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, fields, replace
from pathlib import Path
from typing import Any

from hddpg_zoo.agent_settings import read_history
from hddpg_zoo.benchmark.benchmark_file import (
    check_same_code,
    invocation_codes,
    read_benchmark_file,
)
from hddpg_zoo.benchmark.machine_paths import (
    MACHINE_PATHS,
    check_machine_paths,
    relative_to_run,
    settings_record,
)
from hddpg_zoo.benchmark.methods import (
    METHOD_REGISTRY,
    WORKERS,
    random_reference,
    split_key,
    workers_steps,
)
from hddpg_zoo.benchmark.record_files import (
    as_stored,
    elapsed_path,
    read_record,
    record_path,
    seed_dir,
    time_spent_before,
)
from hddpg_zoo.benchmark.report import write_outputs
from hddpg_zoo.benchmark.settings import BenchmarkSettings
from hddpg_zoo.benchmark.statistics import check_episode_sets, compute_results
from hddpg_zoo.benchmark.tasks import Task, plan_tasks, task_cost
from hddpg_zoo.benchmark.workers_source import (
    check_workers_source,
    copy_flat_runs,
    copy_workers,
    worker_names,
)
from hddpg_zoo.executors import make_executor
from hddpg_zoo.provenance import CodeProvenance, code_provenance
from hddpg_zoo.records import BenchmarkResults, benchmark_record
from hddpg_zoo.runner import Executor, Job, RunOutcome, run_jobs
from sb3_hddpg.artifacts.io import atomic_write_json
from sb3_hddpg.training.workers import train_workers, worker_hyperparams


def run_task(task: Task, settings: BenchmarkSettings, out: str | Path) -> dict[str, Any]:
    """
    Run one task to the end and write its record atomically (the function each process runs).

    The record's ``wall_time_s`` is this invocation's; ``wall_time_s_total`` adds what earlier invocations
    spent on the task before they were interrupted (Ctrl-C, SIGTERM, an error: kept in
    :func:`elapsed_path`; a SIGKILL loses that invocation's share).

    :param task: what to run.
    :param settings: the benchmark's settings.
    :param out: the benchmark folder.
    :return: the record written.
    """
    out = Path(out)
    before = time_spent_before(out, task)
    start = time.perf_counter()
    try:
        record = _run_task(task, settings, out)
    except BaseException:
        # Kept for the invocation that finishes the task; failing to keep it must not hide why the task stopped.
        with contextlib.suppress(OSError):
            atomic_write_json(elapsed_path(out, task), {"wall_time_s": before + time.perf_counter() - start})
        raise
    record["wall_time_s"] = time.perf_counter() - start
    record["wall_time_s_total"] = before + record["wall_time_s"]
    atomic_write_json(record_path(out, task), record)
    elapsed_path(out, task).unlink(missing_ok=True)
    return record


def _run_task(task: Task, settings: BenchmarkSettings, out: Path) -> dict[str, Any]:
    """The record of one task, run to the end (without its wall times)."""
    folder = seed_dir(out, task.seed)
    # Read before training: the blocks this run trains from, whatever the file holds when it ends.
    results: dict[str, Any] = {"config_blocks": as_stored(task_config_blocks(task, settings))}
    spec = task.spec
    if spec is None:
        results.update(_run_workers(task, settings, folder, out))
    else:
        results.update(spec.run(task, settings, folder))
        preference = split_key(task.method)[1]
        if preference is not None:
            results["preference"] = preference
            results["reference"] = random_reference(settings)
    return benchmark_record(task.method, task.seed, results).to_json()


def _run_workers(task: Task, settings: BenchmarkSettings, folder: Path, out: Path) -> dict[str, Any]:
    """Train (or finish) a seed's workers, or copy them from ``settings.workers_from`` (recorded relative to ``out``)."""

    reused: dict[str, Any] = {}
    if settings.workers_from is not None:
        source = seed_dir(Path(settings.workers_from), task.seed)
        if not (folder / "workers" / "manifest.json").exists():  # else copied before an interruption
            copy_workers(source, folder)
        reused = {"workers_from": relative_to_run(str(source), out)}
    budget = settings.worker_timesteps or settings.workers_budget
    run = settings.run_options(task.seed, settings.worker_timesteps, budget)
    # Copied workers are finished ones with this budget: train_workers keeps them (resume) and trains nothing.
    manifest = train_workers(folder, env=settings.terms_env, run=run, algos=settings.worker_algos).manifest
    return {
        **reused,
        "worker_timesteps": workers_steps(folder),
        "workers": {
            name: {"timesteps": entry["timesteps_trained"], "metrics": entry["metrics"]}
            for name, entry in manifest["workers"].items()
        },
        "history": {
            name: read_history(folder / "evaluations" / f"{name}.json") for name in manifest["workers"]
        },
    }


def task_config_blocks(task: Task, settings: BenchmarkSettings) -> dict[str, Any]:
    """The bundled config blocks a task trains from, by a label (the workers': one per worker)."""
    if task.spec is not None:
        return task.spec.config_blocks(settings)
    algos = settings.worker_algos or {}
    blocks = worker_hyperparams(worker_names(settings), None, settings.terms_env, algos or None)
    return {f"{algos.get(name, 'ddpg')}.yml, {name} worker": block.raw for name, block in blocks.items()}


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
#: Where ``redo`` moves the runs it replaces: ``DIR/replaced-<UTC time>/`` (records and seed folders).
REPLACED_PREFIX = "replaced-"


def changed_settings(
    settings: BenchmarkSettings, saved: dict[str, Any], redo: Sequence[str] = ()
) -> list[str]:
    """
    The settings that differ from a folder's ``benchmark.json`` (``saved``), beyond those a resume may
    change. The manager's budget counts in env steps: its decisions may differ when a new manager block
    decides every k env steps for as many env steps (that block's runs are told by their config blocks).
    A setting some methods own (:attr:`Method.own_settings`, e.g. HAM's threshold) may change when every
    one of them, among the folder's methods and this run's, is in ``redo``.
    """
    stored = asdict(settings)
    previous = saved["settings"]
    # Settings added since that benchmark was made hold their defaults in it.
    defaults = asdict(BenchmarkSettings())
    previous = {**{f.name: defaults[f.name] for f in fields(BenchmarkSettings)}, **previous}
    # Methods and seeds may change: each run is its own record, made with the same budgets and episodes
    # whatever else ran beside it, so a resumed benchmark can grow (or report a subset).
    changed = sorted(k for k in stored if k not in RESUME_MAY_CHANGE and previous.get(k) != stored[k])
    same_env_steps = saved.get("budgets", {}).get("manager_env_steps") == settings.manager_env_steps

    def redone(key: str) -> bool:
        owners = _owners(key, settings, saved)
        return bool(owners) and set(owners) <= set(redo)

    def moved(key: str) -> bool:
        return key in MACHINE_PATHS and previous[key] is not None and stored[key] is not None

    return [
        k for k in changed if not (k == "timesteps" and same_env_steps) and not redone(k) and not moved(k)
    ]


def _owners(key: str, settings: BenchmarkSettings, saved: dict[str, Any]) -> list[str]:
    """
    The methods that own setting ``key`` (:attr:`Method.own_settings`) among this run's and the folder's
    (``saved``, its ``benchmark.json``): the ones a change of ``key`` must redo.
    """
    methods = {*settings.methods, *saved["settings"].get("methods", ())}
    return sorted(m for m in methods if m in METHOD_REGISTRY and key in METHOD_REGISTRY[m].own_settings)


def _stale_runs(settings: BenchmarkSettings, records: dict[Task, dict[str, Any]]) -> dict[Task, list[str]]:
    """
    The kept runs whose config blocks differ from the bundled ones now, with the blocks that differ. A
    record from before records kept their blocks cannot be checked, and is kept.
    """
    stale: dict[Task, list[str]] = {}
    current: dict[str, dict[str, Any]] = {}
    for task, record in records.items():
        kept = record.get("config_blocks")
        if not isinstance(kept, dict):
            continue
        name = task.method if task.spec is None else task.spec.name
        if name not in current:
            current[name] = as_stored(task_config_blocks(task, settings))
        differ = sorted(k for k in {*kept, *current[name]} if kept.get(k) != current[name].get(k))
        if differ:
            stale[task] = differ
    return stale


def check_redo(settings: BenchmarkSettings, redo: Sequence[str], resume: bool) -> list[str]:
    """
    ``redo`` as a list: methods of this benchmark (the workers cannot be redone under the runs built on them),
    which replace runs of a benchmark folder, so only with ``resume``.

    :raises ValueError: naming what cannot be redone.
    """
    redo = list(redo)
    if redo and not resume:
        raise ValueError("--redo replaces runs of a benchmark folder: it goes with --resume")
    if WORKERS in redo:
        raise ValueError(
            "The workers cannot be redone in place: every run of their seed is built on them; start a new "
            "benchmark folder (or --force)"
        )
    unknown = [m for m in redo if m not in settings.methods]
    if unknown:
        raise ValueError(f"Cannot redo {unknown}: not among this benchmark's methods {settings.methods}")
    return redo


def _set_aside(out: Path, tasks: Sequence[Task]) -> None:
    """
    Move the runs of ``tasks`` (records and seed folders) to ``out/replaced-<UTC time>/``, keeping their
    paths: nothing is deleted, and ``--resume`` then runs them afresh.
    """
    target = out / f"{REPLACED_PREFIX}{time.strftime('%Y%m%d-%H%M%S', time.gmtime())}"
    for task in tasks:
        for path in (record_path(out, task), seed_dir(out, task.seed) / task.method, elapsed_path(out, task)):
            if path.exists():
                destination = target / path.relative_to(out)
                destination.parent.mkdir(parents=True, exist_ok=True)
                shutil.move(str(path), str(destination))


def run_benchmark(
    settings: BenchmarkSettings,
    out: str | Path,
    n_jobs: int | None = 1,
    resume: bool = False,
    on_event: Callable[[str, Task, dict[str, Any] | None], None] | None = None,
    ray_address: str | None = None,
    redo: Sequence[str] = (),
    allow_mixed_commits: bool = False,
) -> BenchmarkResults:
    """
    Run every task not yet finished, ``n_jobs`` at a time, then compute and write the results.

    The tasks run on the process runner (:mod:`hddpg_zoo.runner`, see :func:`task_job`): workers
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
        again from its checkpoint: :mod:`hddpg_zoo.ray_executor`); ``None``: local processes.
    :param redo: with ``resume``, methods to run again: their runs so far are moved to
        ``out/replaced-<UTC time>/``. A kept run whose bundled config block has changed since it ran is
        refused otherwise, so that one benchmark never mixes runs of two configs unawares.
    :param allow_mixed_commits: with ``resume``, continue a benchmark whose earlier invocations ran other code
        (another version or git commit, or one not recorded); refused otherwise
        (:func:`~.benchmark_file.check_same_code`). Every invocation records its code in ``benchmark.json``
        (``invocations[].code``) and whether it mixed.
    :return: the results (also written to ``out/results.json``).
    """
    if n_jobs is not None and n_jobs < 1:
        raise ValueError(f"Expected `n_jobs` >= 1, actually: {n_jobs}")
    out = Path(out)
    notify = on_event or (lambda kind, task, record: None)
    settings_path = out / "benchmark.json"
    settings, redo, saved, code, mixed = _checked_start(settings, out, resume, redo, allow_mixed_commits)
    tasks = plan_tasks(settings)
    records = _kept_records(settings, tasks, out, resume, redo)
    for task, record in records.items():
        notify("skip", task, record)
    header = {
        "settings": settings_record(settings, out),
        "budgets": {"manager_env_steps": settings.manager_env_steps},
        "machine": machine_info(),
    }
    # Every invocation's wall time, so that a benchmark resumed several times still says what it took.
    previous_invocations = (saved or {}).get("invocations")
    invocations = list(previous_invocations) if isinstance(previous_invocations, list) else []
    atomic_write_json(settings_path, {**header, "invocations": invocations})
    by_label = {task.label: task for task in tasks}
    outcome, wall = _run_pending(
        settings,
        tasks,
        records,
        out,
        functools.partial(make_executor, n_jobs, ray_address=ray_address),
        notify,
        header,
        invocations,
        {"code": code.to_json(), "mixed_commits": mixed},
    )
    records.update({by_label[label]: record for label, record in outcome.results.items()})
    failed = {by_label[label]: outcome.failure_message(label) for label in outcome.failures}
    finished = [records[t] for t in tasks if t in records] + copy_flat_runs(settings, out)
    computed = compute_results(settings, finished)
    results = replace(computed, settings=header["settings"]).with_run(
        wall_time_s_this_invocation=wall,
        wall_time_s_all_invocations=sum(float(i.get("wall_time_s", 0.0)) for i in invocations),
        invocations=len(invocations),
        failures={t.label: message for t, message in failed.items()},
        machine=machine_info(),
    )
    return write_outputs(out, results, [records[t] for t in tasks if t in records])


def _checked_start(
    settings: BenchmarkSettings, out: Path, resume: bool, redo: Sequence[str], allow_mixed_commits: bool
) -> tuple[BenchmarkSettings, list[str], dict[str, Any] | None, CodeProvenance, bool]:
    """
    What an invocation starts from, each checked before anything runs (see :func:`run_benchmark`): the
    methods to redo, the folder's saved ``benchmark.json`` when resuming (the same settings and, unless
    allowed, the same code), this machine's paths and the workers source.

    :return: the settings with this machine's paths checked, the methods to redo, the saved
        ``benchmark.json`` (``None`` when not resuming one), the code this process runs and whether it
        differs from earlier invocations'.
    """
    settings_path = out / "benchmark.json"
    checked_redo = check_redo(settings, redo, resume)
    saved = read_benchmark_file(settings_path) if resume and settings_path.exists() else None
    code = code_provenance()
    mixed = False
    if saved is not None:
        _check_same_settings(settings, saved, checked_redo, out)
        mixed = check_same_code(
            invocation_codes(saved, str(settings_path)), code, allow_mixed_commits, str(out)
        )
    settings = check_machine_paths(settings)
    check_workers_source(settings)
    return settings, checked_redo, saved, code, mixed


def _check_same_settings(
    settings: BenchmarkSettings, saved: dict[str, Any], redo: Sequence[str], out: Path
) -> None:
    """Refuse to resume ``out`` with other settings than it was started with, naming them (and the --redo that
    would allow a change that only some methods read)."""
    changed = changed_settings(settings, saved, redo)
    if changed:
        raise ValueError(
            f"Cannot resume {str(out)!r} with different settings ({', '.join(changed)} changed); "
            "run with the same options, or use --force to start over"
            + "".join(
                f"; {key} is read only by {', '.join(owners)}: add --redo {','.join(owners)}"
                for key in changed
                if (owners := _owners(key, settings, saved))
            )
        )


def _kept_records(
    settings: BenchmarkSettings, tasks: Sequence[Task], out: Path, resume: bool, redo: Sequence[str]
) -> dict[Task, dict[str, Any]]:
    """
    The finished runs a resumed benchmark keeps: their records, checked against this run's episode sets and
    config blocks; the runs of the ``redo`` methods are set aside instead.
    """
    records: dict[Task, dict[str, Any]] = {}
    for task in tasks:
        record = read_record(out, task) if resume else None
        if record is not None:
            records[task] = record
    redone = [t for t in tasks if t.spec is not None and t.spec.name in redo]
    # Before anything runs: a kept run scored on other episodes would stop the results at the end.
    check_episode_sets(settings, [r for t, r in records.items() if t not in redone])
    stale = {t: blocks for t, blocks in _stale_runs(settings, records).items() if t not in redone}
    if stale:
        _refuse_stale(stale, out)
    if redone:
        _set_aside(out, redone)
        records = {t: r for t, r in records.items() if t not in redone}
    return records


def _refuse_stale(stale: Mapping[Task, Sequence[str]], out: Path) -> None:
    """Refuse kept runs whose config blocks changed since they ran, saying how to run them again."""
    changed_blocks = ", ".join(sorted({b for blocks in stale.values() for b in blocks}))
    if any(t.spec is None for t in stale):
        raise ValueError(
            f"Cannot resume {str(out)!r}: the workers' config blocks changed since they were trained "
            f"({changed_blocks}); every run of their seed is built on them: start a new benchmark folder "
            "(or --force)"
        )
    methods = sorted({t.spec.name for t in stale if t.spec is not None})
    raise ValueError(
        f"Cannot resume {str(out)!r}: the config blocks of {', '.join(t.label for t in stale)} changed since "
        f"they ran ({changed_blocks}); run them again with --redo {','.join(methods)} (the old runs are "
        "kept aside), or start over with --force"
    )


def _run_pending(
    settings: BenchmarkSettings,
    tasks: Sequence[Task],
    records: Mapping[Task, dict[str, Any]],
    out: Path,
    executor: Callable[[], Executor],
    notify: Callable[[str, Task, dict[str, Any] | None], None],
    header: dict[str, Any],
    invocations: list[dict[str, Any]],
    provenance: dict[str, Any],
) -> tuple[RunOutcome, float]:
    """
    Run every task without a kept record, and add this invocation (its wall time, even when interrupted, and
    ``provenance``: the code it ran and whether that mixes commits) to ``benchmark.json``.

    :param executor: makes the executor the tasks run on.
    :return: the runner's outcome and this invocation's wall time.
    """
    started_at = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    start = time.perf_counter()
    by_label = {task.label: task for task in tasks}
    kept = {task.label for task in records}
    jobs = [task_job(task, settings, out) for task in tasks if task not in records]
    outcome = None
    try:
        outcome = run_jobs(
            [replace(job, after=tuple(d for d in job.after if d not in kept)) for job in jobs],
            executor(),
            on_event=lambda kind, job, value: notify(
                kind, by_label[job.key], value if kind == "done" else None
            ),
        )
    finally:
        # Written even when interrupted: the time spent counts, and the next --resume adds its own.
        wall = time.perf_counter() - start
        invocations.append(
            {
                "started": started_at,
                "wall_time_s": wall,
                "runs_kept": len(kept),
                "runs_to_do": len(jobs),
                "runs_done": len(outcome.results) if outcome is not None else None,
                "interrupted": outcome is None,
                **provenance,
            }
        )
        atomic_write_json(out / "benchmark.json", {**header, "invocations": invocations})
    return outcome, wall


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

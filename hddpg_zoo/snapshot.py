"""
``snapshot_benchmark``: the finished seeds of a benchmark, finished or still running, copied into a compact
folder that is a benchmark folder itself, so that a long run survives the machine it runs on.

A seed is copied once every run of it has finished: its records, its final models as
:func:`~hddpg_zoo.model_export.export_models` lays them out (with ``index.json``) and its workers'
learning curves, then ``benchmark.json``. Left out is what only an unfinished run needs or what is
not a result: checkpoints, replay buffers, best-model folders, TensorBoard logs and, unless asked for, the
front's managers trained for one preference each (their records keep their scores). A snapshot is therefore

- resumed like the benchmark it copies (``hddpg-cli benchmark ... --out SNAPSHOT --resume`` keeps every run in it
  and runs the rest, on any machine);
- a ``--workers-from`` source (each seed's workers, their manifest and learning curves);
- an export (``index.json``, :func:`~hddpg_zoo.model_export.read_index`).

Taken again into the same folder, a snapshot adds the runs finished since and never replaces one: a run
whose record there differs from the benchmark's (the folder was resumed on its own, or a run was redone) is
refused, naming it, and so is a folder holding anything but an earlier snapshot of the same benchmark.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from hddpg_zoo.benchmark import (
    WORKERS,
    BenchmarkSettings,
    Task,
    changed_settings,
    plan_tasks,
    read_record,
    read_record_file,
    record_path,
)
from hddpg_zoo.benchmark.benchmark_file import read_benchmark_file, settings_from_json
from hddpg_zoo.model_export import (
    IndexEntry,
    ModelFile,
    copy_model,
    destination,
    file_inside,
    run_models,
    write_index,
)
from sb3_hddpg.artifacts.io import atomic_write_json, locked_folder
from sb3_hddpg.artifacts.limits import MAX_MODEL_FILE_BYTES, read_file_bytes, read_json_file
from sb3_hddpg.artifacts.provenance import sha256_bytes
from sb3_hddpg.artifacts.run_folder import RunFolderError, mark_run_folder, protected_reason

#: What a snapshot adds to a benchmark's layout: the command its folder marker records.
SNAPSHOT_COMMAND = "snapshot"


@dataclass(frozen=True)
class Snapshot:
    """
    A snapshot after :func:`snapshot_benchmark`.

    :param folder: the snapshot's folder.
    :param seeds: the benchmark's seeds whose every run has finished: all of them are in the snapshot.
    :param pending: its seeds with a run still to finish (none of their runs is copied).
    :param copied: the runs copied this time (``<run>/seed-<s>``); the others were there already.
    :param models: the models its ``index.json`` lists.
    """

    folder: Path
    seeds: tuple[int, ...]
    pending: tuple[int, ...]
    copied: tuple[str, ...]
    models: int


def finished_seeds(run: Path, settings: BenchmarkSettings) -> tuple[list[int], list[int]]:
    """
    The seeds of the benchmark folder ``run`` whose every run has finished (its record says so), and the
    others, each in the benchmark's order.
    """
    tasks = plan_tasks(settings)
    finished = [
        seed
        for seed in settings.seeds
        if all(read_record(run, task) is not None for task in tasks if task.seed == seed)
    ]
    return finished, [seed for seed in settings.seeds if seed not in finished]


def snapshot_benchmark(run: str | Path, dest: str | Path, *, per_preference: bool = False) -> Snapshot:
    """
    Copy the finished seeds of the benchmark folder ``run`` into ``dest`` (see the module): each run's
    files first, its record after them, ``index.json`` and ``benchmark.json`` last, so that an interrupted
    snapshot holds only whole runs and is completed by taking it again. ``dest`` is locked meanwhile.

    :param run: the benchmark folder (``--out`` of ``hddpg-cli benchmark``), finished or running.
    :param dest: the snapshot's folder: missing, empty, or an earlier snapshot of the same benchmark.
    :param per_preference: copy the front's managers trained for one preference each too (of the front's runs
        copied this time: a run already in ``dest`` is left as it is).
    :return: what the snapshot holds.
    :raises FileNotFoundError: ``run`` is not a benchmark folder.
    :raises ValueError: ``dest`` may not be written (:class:`RunFolderError`), or holds another run.
    """
    run, dest = Path(run), Path(dest)
    settings_path = run / "benchmark.json"
    if not settings_path.is_file():
        raise FileNotFoundError(f"Not a benchmark folder (no benchmark.json): {str(run)!r}")
    saved = read_benchmark_file(settings_path)
    settings = settings_from_json(saved["settings"], str(settings_path))
    check_destination(run, dest, settings, saved.get("invocations", []))
    finished, pending = finished_seeds(run, settings)
    # Every run is checked before any is copied (a refused snapshot writes nothing, not even its folder),
    # and again once the folder is locked, in case another process wrote it meanwhile.
    _runs_to_copy(run, dest, settings, finished)
    with locked_folder(dest):
        todo = _runs_to_copy(run, dest, settings, finished)
        mark_run_folder(dest, SNAPSHOT_COMMAND)
        for task in todo:
            _copy_run(run, dest, task, per_preference)
        index = write_index(dest, [_in_place(model, dest) for model in _models(dest)])
        atomic_write_json(dest / "benchmark.json", saved)
    return Snapshot(dest, tuple(finished), tuple(pending), tuple(t.label for t in todo), len(index))


def _runs_to_copy(run: Path, dest: Path, settings: BenchmarkSettings, seeds: Sequence[int]) -> list[Task]:
    """The finished runs of ``seeds`` not yet in ``dest`` (:func:`_is_new`), in the benchmark's order."""
    return [task for task in plan_tasks(settings) if task.seed in seeds and _is_new(run, dest, task)]


def _is_new(run: Path, dest: Path, task: Task) -> bool:
    """
    Whether a finished run of ``run`` is still to be copied into ``dest``.

    :raises ValueError: its record is not where it belongs, or ``dest`` holds another run of it.
    """
    source = record_path(run, task)
    record = read_record_file(source)
    if (record.get("method"), record.get("seed")) != (task.method, task.seed):
        # Its models are found by what it says: a record moved from another run's place would copy those.
        raise ValueError(f"{str(source)!r}: expected the record of {task.label}, actually of another run")
    target = record_path(dest, task)
    if not target.is_file():
        return True
    if read_record_file(target) == record:
        return False
    raise ValueError(
        f"{str(target)!r} holds another run of {task.label} than {str(source)!r} (resumed or redone since the "
        "snapshot?): take the snapshot into a new folder"
    )


def _copy_run(run: Path, dest: Path, task: Task, per_preference: bool) -> None:
    """
    Copy one finished run into ``dest``: its models (and for the workers their learning curves, which
    ``--workers-from`` checks), then its record, so that a run counts as copied only once it is whole.
    """
    source = record_path(run, task)
    models = run_models(run, source, per_preference=per_preference)
    for model in models:
        copy_model(model, run, dest)
    if task.method == WORKERS:
        for model in models:
            curve = model.path.parent.parent / "evaluations" / f"{model.method.split(':', 1)[1]}.json"
            atomic_write_json(destination(dest, curve), read_json_file(file_inside(run, curve)))
    record = record_path(dest, task).relative_to(dest)
    atomic_write_json(destination(dest, record), read_record_file(source))


def _models(folder: Path) -> list[ModelFile]:
    """Every model of the runs recorded in ``folder``, as they are there."""
    return [
        model
        for record in sorted(folder.glob("records/*/seed-*.json"))
        for model in run_models(folder, record)
    ]


def _in_place(model: ModelFile, folder: Path) -> IndexEntry:
    """A model's ``index.json`` record, from its file in ``folder``."""
    return model.index_entry(
        sha256_bytes(read_file_bytes(file_inside(folder, model.path), MAX_MODEL_FILE_BYTES))
    )


def check_destination(
    run: str | Path, dest: str | Path, settings: BenchmarkSettings, invocations: Sequence[object] = ()
) -> None:
    """
    Refuse a ``dest`` that is not missing, empty or an earlier snapshot of this benchmark: one whose
    settings are the benchmark's (but for those a resume may change) and whose invocations are the first of
    the benchmark's, so that a folder resumed on its own since is never overwritten. A benchmark checks its
    ``--snapshot`` folder with it before it starts.

    :param run: the benchmark folder.
    :param dest: the snapshot's folder.
    :param settings: the benchmark's settings.
    :param invocations: the benchmark's invocations so far (its ``benchmark.json``; none for a new one).
    :raises ValueError: naming the folder and why (:class:`RunFolderError` for a folder never to be written).
    """
    run, dest = Path(run), Path(dest)
    reason = "the current folder" if str(dest) in ("", ".") else protected_reason(dest)
    if reason is not None:
        raise RunFolderError(f"Expected a snapshot folder, actually {str(dest)!r} ({reason})")
    inside = dest.resolve() == run.resolve() or run.resolve() in dest.resolve().parents
    if inside or dest.resolve() in run.resolve().parents:
        raise ValueError(
            f"Expected a snapshot folder apart from the benchmark folder, actually {str(dest)!r}"
        )
    if dest.is_symlink() or (dest.exists() and not dest.is_dir()):
        raise RunFolderError(f"Expected a snapshot folder, actually {str(dest)!r} (not a plain folder)")
    if not dest.is_dir() or not any(dest.iterdir()):
        return
    theirs = dest / "benchmark.json"
    if not theirs.is_file():
        raise RunFolderError(
            f"Expected a new or empty folder, or an earlier snapshot (with benchmark.json), actually "
            f"{str(dest)!r}, which holds other files"
        )
    earlier = read_benchmark_file(theirs)
    changed = changed_settings(settings, earlier)
    if changed:
        raise ValueError(
            f"{str(dest)!r} holds another benchmark than {str(run)!r} ({', '.join(changed)} differ): take the "
            "snapshot into a new folder"
        )
    if not _is_prefix(earlier.get("invocations", []), invocations):
        raise ValueError(
            f"{str(dest)!r} was run on its own since it was taken from {str(run)!r} (its invocations differ): "
            "take the snapshot into a new folder"
        )


def _is_prefix(first: Sequence[object], whole: Sequence[object]) -> bool:
    return len(first) <= len(whole) and list(first) == list(whole[: len(first)])


__all__ = ["SNAPSHOT_COMMAND", "Snapshot", "check_destination", "finished_seeds", "snapshot_benchmark"]

"""
``export_models``: a finished benchmark's final models copied into one folder with an ``index.json``, so that
anyone can re-evaluate them on episodes of their own (as ``docs/results/record/`` ships the run of record's).

The folder keeps the benchmark's layout below it (``seed-<s>/workers/``, ``seed-<s>/<method>/...``), so that
every file still finds what it refers to: a worker zip its ``manifest.json`` beside it, a flat zip its
``flat/manifest.json``, ``ham.json`` its workers by a relative path; a hierarchy bundle is self-contained.
``index.json`` lists one record per model: ``{"method", "seed", "path", "sha256"}`` (plus ``"preference"``
for the transfer scenario's runs and the front's per-preference managers, and ``"manager_preferences"``, the
space a conditioned bundle was trained over), ``method`` one of :data:`INDEX_METHODS`, ``path`` relative to
the folder and openable with :func:`sb3_hddpg.hierarchy.loading.load_policy` (``hddpg-cli evaluate PATH``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TypedDict

from hddpg_zoo.benchmark import (
    DISCRETE_FLAT_METHODS,
    DISCRETE_MANAGERS,
    FLAT_HER_METHODS,
    FLAT_METHODS,
    WORKERS,
    read_record_file,
    split_key,
)
from hddpg_zoo.benchmark.front import FRONT_METHOD
from hddpg_zoo.benchmark.front_points import preference_label
from hddpg_zoo.benchmark.front_support import SUPPORT_METHOD
from hddpg_zoo.benchmark.record_files import COPIED_FROM
from sb3_hddpg.artifacts.io import atomic_write_bytes, atomic_write_json
from sb3_hddpg.artifacts.limits import (
    MAX_MODEL_FILE_BYTES,
    MAX_SEED,
    MAX_WORKERS,
    LimitError,
    brief,
    read_file_bytes,
    read_json_file,
)
from sb3_hddpg.artifacts.manifests import read_workers_manifest
from sb3_hddpg.artifacts.provenance import sha256_bytes, sha256_file, verify_sha256
from sb3_hddpg.artifacts.run_folder import RunFolderError, protected_reason
from sb3_hddpg.hierarchy.bundle import read_bundle
from sb3_hddpg.names import check_plain_name, check_preference_text

#: The front's managers (the benchmark method ``hddpg-front``): its preference-conditioned manager, one
#: bundle for every preference, and the managers trained for one preference each.
CONDITIONED = "hddpg-conditioned"
PER_PREFERENCE = "hddpg-preference"
#: The front's GPI over the seed's workers (no manager; any preference at run time).
GPI = "hddpg-gpi"
#: The support method's (``hddpg-support``) conditioned manager over its support, a bundle holding every
#: worker; GPI over the support's critics; and HAM's threshold switch over the seed's two per-term workers.
SUPPORT = "hddpg-support"
SUPPORT_GPI = "hddpg-support-gpi"
SUPPORT_HAM = "ham-threshold"
#: The ``method`` values of ``index.json``: the workers, then the benchmark's methods.
INDEX_METHODS = (
    "worker:goal",
    "worker:avoid",
    "hddpg",
    "hddpg-goal",
    "hddpg-avoid",
    "hddpg-sac",
    *(f"hddpg-{algo}" for algo in DISCRETE_MANAGERS),
    CONDITIONED,
    PER_PREFERENCE,
    GPI,
    SUPPORT,
    SUPPORT_GPI,
    SUPPORT_HAM,
    "ham",
    "ham-tuned",
    *FLAT_METHODS,
    *FLAT_HER_METHODS,
    *DISCRETE_FLAT_METHODS,
)
#: The methods whose model is a hierarchy bundle (another env's managers by index among them).
HIERARCHY_METHODS = (
    "hddpg",
    "hddpg-goal",
    "hddpg-avoid",
    "hddpg-sac",
    *(f"hddpg-{a}" for a in DISCRETE_MANAGERS),
)


class IndexEntry(TypedDict, total=False):
    """
    One exported model in ``index.json``: its method (and preference, or for the front's conditioned manager
    the preference space it was trained over, as its bundle records it), seed, file and the file's sha256.
    """

    method: str
    seed: int
    path: str
    sha256: str
    preference: str
    manager_preferences: object


@dataclass(frozen=True)
class ModelFile:
    """
    One model of a finished run, as a benchmark folder lays it out: what ``index.json`` says of it (but the
    digest) and the files it is opened through, every path relative to the folder.

    :param method: one of :data:`INDEX_METHODS`.
    :param seed: the run's seed.
    :param path: the file the model is opened by.
    :param needs: the files it opens through (a worker's or a flat agent's manifest), copied first.
    :param preference: a transfer run's or a per-preference manager's preference.
    :param manager_preferences: the preference space a conditioned manager was trained over.
    """

    method: str
    seed: int
    path: Path
    needs: tuple[Path, ...] = ()
    preference: str | None = None
    manager_preferences: object = None

    def index_entry(self, digest: str) -> IndexEntry:
        """Its record in ``index.json``, given its file's sha256."""
        entry: IndexEntry = {
            "method": self.method,
            "seed": self.seed,
            "path": self.path.as_posix(),
            "sha256": digest,
        }
        if self.preference is not None:
            entry["preference"] = self.preference
        if self.manager_preferences is not None:
            entry["manager_preferences"] = self.manager_preferences
        return entry


def file_inside(root: str | Path, relative: str | Path) -> Path:
    """
    A file of a folder someone else may have made, by its path inside it: refused with :class:`LimitError`
    when any part of that path is a symbolic link or it resolves outside ``root``.

    :param root: the folder.
    :param relative: the file's path inside it.
    :return: the path.
    """
    root = Path(root)
    current = root
    for part in Path(relative).parts:
        current = current / part
        if current.is_symlink():
            raise LimitError(
                f"{str(current)!r} is a symbolic link inside {str(root)!r}; refused (it may lead anywhere)"
            )
    if root.resolve() not in current.resolve().parents:
        raise LimitError(f"{str(current)!r} resolves outside {str(root)!r}; refused")
    return current


def destination(dest_root: Path, relative: Path) -> Path:
    """
    The path a file of an export (or a snapshot) is written to, its folders made: refused unless it resolves
    inside ``dest_root``. Defence in depth at the writers: every name was checked where it was read, and a
    symbolic link planted in the destination could still point elsewhere.
    """
    target = dest_root / relative
    if dest_root.resolve() not in target.resolve().parents:
        raise ValueError(f"Refusing to write {relative.as_posix()!r}: it resolves outside {str(dest_root)!r}")
    target.parent.mkdir(parents=True, exist_ok=True)
    return target


def _copy(root: Path, dest_root: Path, relative: Path) -> str:
    """
    Copy ``root/relative`` to ``dest_root/relative``: read once (a regular file inside ``root``, no link
    on the way, within the size limit), written atomically from those bytes. Returns their sha256.
    """
    source = file_inside(root, relative)
    if not source.is_file():
        raise FileNotFoundError(f"Expected a finished run's file, missing: {str(source)!r}")
    data = read_file_bytes(source, MAX_MODEL_FILE_BYTES)
    atomic_write_bytes(destination(dest_root, relative), data)
    return sha256_bytes(data)


def copy_model(model: ModelFile, root: Path, dest: Path) -> IndexEntry:
    """
    Copy one model (the files it needs first) from the benchmark folder ``root`` into ``dest``, at the same
    relative paths, checking the copy's sha256 against its source.

    :return: its record in ``index.json``.
    """
    for extra in model.needs:
        _copy(root, dest, extra)
    digest = _copy(root, dest, model.path)
    # The copy is checked against the bytes read, not the source again (which may have changed since).
    if sha256_file(dest / model.path) != digest:
        raise OSError(f"Copy of {str(root / model.path)!r} differs from what was read (sha256): disk full?")
    return model.index_entry(digest)


def _read_record(record_file: Path) -> tuple[str, int, list[str]] | None:
    """
    A finished run's key, seed and (for the workers' record) worker names, every one checked before it
    becomes part of a path; ``None`` for a run that is not done, or one copied from another benchmark (its
    models are there).
    """
    record = read_record_file(record_file)
    if not isinstance(record, dict) or record.get("status") != "done" or COPIED_FROM in record:
        return None
    what = str(record_file)
    key = record.get("method")
    if not isinstance(key, str):
        raise ValueError(f"{what}: method: expected a name, got {brief(key)}")
    base, preference = split_key(key)
    check_plain_name(base, f"{what}: method")
    if preference is not None:
        check_preference_text(preference, f"{what}: method preference")
    seed = record.get("seed")
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
        raise ValueError(f"{what}: seed: expected an integer in [0, {MAX_SEED}], got {brief(seed)}")
    workers = record.get("workers", []) if key == WORKERS else []
    if isinstance(workers, dict):  # a record maps each worker to its results
        workers = list(workers)
    if not isinstance(workers, list) or len(workers) > MAX_WORKERS:
        raise ValueError(
            f"{what}: workers: expected a list or object of at most {MAX_WORKERS} names, got {brief(workers)}"
        )
    return key, seed, [check_plain_name(name, f"{what}: workers") for name in workers]


def _model_files(run_key: str, base: str) -> tuple[str, list[str]] | None:
    """The file a run's model is opened by and the files it needs beside it, relative to the seed folder."""
    if base in HIERARCHY_METHODS:
        return f"{run_key}/hierarchy.zip", []
    if base in ("ham", "ham-tuned"):
        return f"{base}/ham.json", []  # its workers are exported with the seed's workers
    if base in FLAT_METHODS or base in DISCRETE_FLAT_METHODS or base in FLAT_HER_METHODS:
        # A flat agent's zip is named after its algorithm (``ddpg-her`` trains a ``ddpg.zip``).
        algo = FLAT_HER_METHODS.get(base, base)
        return f"{run_key}/flat/{algo}.zip", [f"{run_key}/flat/manifest.json"]
    return None


def run_models(root: Path, record_file: Path, *, per_preference: bool = True) -> list[ModelFile]:
    """
    The models of the run whose record is ``record_file``, in the benchmark folder ``root``: none for a run
    that is not finished, or of a method registered elsewhere whose files this exporter does not know.

    :param root: the benchmark folder.
    :param record_file: ``root/records/<run>/seed-<s>.json``.
    :param per_preference: with the front's run, its managers trained for one preference each too (else its
        conditioned manager alone).
    """
    checked = _read_record(record_file)
    if checked is None:
        return []
    key, seed, workers = checked
    seed_folder = Path(f"seed-{seed}")
    if key == WORKERS:
        # The manifest first: a worker zip is opened through it.
        manifest = seed_folder / "workers" / "manifest.json"
        return [
            ModelFile(f"worker:{name}", seed, seed_folder / "workers" / f"{name}.zip", (manifest,))
            for name in sorted(workers)
        ]
    base, preference = split_key(key)
    if base == FRONT_METHOD:
        return _front_models(root, seed_folder / base, seed, per_preference)
    if base == SUPPORT_METHOD:
        return _support_models(root, seed_folder, seed)
    files = _model_files(key, base)
    if files is None:
        return []
    model, extras = files
    needs = tuple(seed_folder / extra for extra in extras)
    return [ModelFile(base, seed, seed_folder / model, needs, preference)]


def _front_models(root: Path, run: Path, seed: int, per_preference: bool) -> list[ModelFile]:
    """
    The front's bundles of one seed: the conditioned manager (with the preference space it was trained
    over, read from its verified manifest), each per-preference manager (with its preference) and GPI's.
    """
    models: list[ModelFile] = []
    for relative in sorted((root / run).glob("*/hierarchy.zip")):
        relative = relative.relative_to(root)
        manifest, _ = read_bundle(root / relative)
        selection = manifest.selection if isinstance(manifest.selection, dict) else {}
        space = selection.get("manager_preferences")
        if space is not None:
            models.append(ModelFile(CONDITIONED, seed, relative, manager_preferences=space))
        elif per_preference:
            label = preference_label(selection.get("preferences") or {})
            models.append(ModelFile(PER_PREFERENCE, seed, relative, preference=label))
    if (
        root / run / "gpi.zip"
    ).is_file():  # the front's GPI member, a bundle of the workers with their critics
        models.append(ModelFile(GPI, seed, run / "gpi.zip"))
    return models


def _support_models(root: Path, seed_folder: Path, seed: int) -> list[ModelFile]:
    """
    The support method's models of one seed: its conditioned bundle (with the preference space it was trained
    over), its GPI bundle, and HAM over the seed's per-term workers (whose zips and manifest go with it; its
    front's thresholds are in the record, one is set at run time).
    """
    run = seed_folder / SUPPORT_METHOD
    models: list[ModelFile] = []
    conditioned = run / "conditioned" / "hierarchy.zip"
    if (root / conditioned).is_file():
        manifest, _ = read_bundle(root / conditioned)
        selection = manifest.selection if isinstance(manifest.selection, dict) else {}
        models.append(
            ModelFile(SUPPORT, seed, conditioned, manager_preferences=selection.get("manager_preferences"))
        )
    if (root / run / "gpi.zip").is_file():
        models.append(ModelFile(SUPPORT_GPI, seed, run / "gpi.zip"))
    if (root / run / "ham.json").is_file():
        workers = seed_folder / "workers"
        entries = read_workers_manifest(root / workers / "manifest.json").entries
        needs = (workers / "manifest.json", *(workers / str(entries[n]["file"]) for n in ("goal", "avoid")))
        models.append(ModelFile(SUPPORT_HAM, seed, run / "ham.json", needs))
    return models


def write_index(folder: Path, index: list[IndexEntry]) -> list[IndexEntry]:
    """
    Write ``folder/index.json`` atomically, its records in :data:`INDEX_METHODS` order (then preference and
    seed), after every file they name is in place.

    :return: the records as written.
    """
    order = {name: i for i, name in enumerate(INDEX_METHODS)}
    index = sorted(
        index, key=lambda e: (order.get(e["method"], len(order)), e.get("preference") or "", e["seed"])
    )
    atomic_write_json(folder / "index.json", index)
    return index


def export_models(
    benchmark_dir: str | Path, dest: str | Path, methods: Sequence[str] | None = None
) -> list[IndexEntry]:
    """
    Copy a finished benchmark's final models into ``dest`` and write ``dest/index.json``.

    Only finished runs (``records/<method>/seed-<s>.json`` with status ``done``) are exported; every copied
    file's sha256 is checked against the source after copying, and the index is written last, atomically,
    so that an interrupted export leaves no index that promises missing files.

    :param benchmark_dir: the benchmark folder (``--out`` of ``hddpg-cli benchmark``).
    :param dest: the folder to fill: missing, empty, or an earlier export (its ``index.json``), whose files of
        the same names are replaced; a folder holding anything else is refused, so nobody's files are lost.
    :param methods: only the models of these ``index.json`` methods (default: every model), so that a run
        ships the models its docs re-evaluate and no more; ``worker:<name>`` names any env's worker.
    :return: the index's records.
    """
    # Another env's workers are indexed as ``worker:<its term>`` too, beyond the snake's two.
    unknown = sorted(
        m for m in set(methods or ()) - set(INDEX_METHODS) if not (m.startswith("worker:") and m[7:])
    )
    if unknown:
        raise ValueError(
            f"Expected methods among {list(INDEX_METHODS)} or worker:<name>, actually also {unknown}"
        )

    root = Path(benchmark_dir)
    records_dir = root / "records"
    if not records_dir.is_dir():
        raise FileNotFoundError(f"Not a benchmark folder (no records/): {str(benchmark_dir)!r}")
    dest = _check_destination(root, Path(dest))
    index = [
        copy_model(model, root, dest)
        for record_file in sorted(records_dir.glob("*/seed-*.json"))
        for model in run_models(root, record_file)
        if methods is None or model.method in methods
    ]
    if not index:
        raise ValueError(
            f"No finished runs to export in {str(benchmark_dir)!r}"
            + (f" with models of {list(methods)}" if methods is not None else "")
        )
    return write_index(dest, index)


def _check_destination(root: Path, dest: Path) -> Path:
    """
    ``dest`` if an export may fill it: not a protected folder, not inside the benchmark, and new, empty or
    an earlier export (its ``index.json``), so that no file of anyone else's is replaced.
    """
    reason = "the current folder" if str(dest) in ("", ".") else protected_reason(dest)
    if reason is not None:  # it replaces files of its own names there: never in such a folder
        raise RunFolderError(f"Expected an export folder, actually {str(dest)!r} ({reason})")
    if dest.resolve() == root.resolve() or root.resolve() in dest.resolve().parents:
        raise ValueError(f"Expected an export folder outside the benchmark folder, actually: {str(dest)!r}")
    if dest.is_symlink() or (dest.exists() and not dest.is_dir()):
        raise RunFolderError(f"Expected an export folder, actually {str(dest)!r} (not a plain folder)")
    if dest.is_dir() and not (dest / "index.json").is_file() and any(dest.iterdir()):
        raise RunFolderError(
            f"Expected a new or empty export folder, or an earlier export (with index.json), actually "
            f"{str(dest)!r}, which holds other files"
        )
    return dest


def read_index(folder: str | Path) -> list[IndexEntry]:
    """
    An export's ``index.json``, every file checked against its recorded sha256.

    :param folder: the export folder.
    :return: the records, each with ``path`` still relative to ``folder``.
    :raises ValueError: naming the record whose file is missing, outside the folder, or altered.
    """
    folder = Path(folder)
    index = read_json_file(folder / "index.json")
    if not isinstance(index, list) or not all(
        isinstance(e, dict) and isinstance(e.get("path"), str) and isinstance(e.get("sha256"), str)
        for e in index
    ):
        raise ValueError(f"{folder / 'index.json'}: expected a list of records with a path and a sha256")
    for entry in index:
        path = (folder / entry["path"]).resolve()
        if folder.resolve() not in path.parents:
            raise ValueError(f"index.json: {entry['path']!r} points outside {str(folder)!r}")
        if not path.is_file():
            raise ValueError(f"index.json: {entry['path']!r} is missing")
        verify_sha256(path, entry["sha256"], entry["path"], where="index.json")
    return index

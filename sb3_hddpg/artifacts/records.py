"""
The records this package writes beside trained models, each a frozen dataclass with one builder and one
reader, and the schema version of every file it writes, in one place.

- :class:`ModelEntry`: one trained model's entry in a models manifest (built by
  :func:`~sb3_hddpg.artifacts.manifests.model_entry`, which hashes the file and describes the model).
- :class:`ModelsManifest`: ``workers/manifest.json`` and ``flat/manifest.json`` (:func:`models_manifest`,
  :func:`read_models_manifest`).
- :class:`BundleManifest`: a hierarchy bundle's ``manifest.json`` (:func:`bundle_manifest`,
  :meth:`BundleManifest.from_json`).
- :class:`HamFile`: ``ham.json``, the HAM switch's settings (:func:`ham_file`, :func:`read_ham_file`).

Every reader checks what it reads through :mod:`sb3_hddpg.artifacts.limits` (the size- and depth-limited
JSON reader, plain names, file entries) and :mod:`sb3_hddpg.artifacts.values` (env settings), and refuses
a schema version newer than the one here. Each record is also a read-only mapping of the JSON it is
written as, so that code reading a manifest as the JSON object it was keeps working.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

from sb3_hddpg.artifacts.limits import (
    MAX_SEED,
    MAX_WORKERS,
    LimitError,
    brief,
    check_env_id,
    check_file_entry,
    check_name,
    read_json_file,
)
from sb3_hddpg.artifacts.values import check_env_kwargs

#: Schema version of ``workers/manifest.json``.
WORKERS_MANIFEST_VERSION = 1
#: Schema version of ``flat/manifest.json``.
FLAT_MANIFEST_VERSION = 1
#: Schema version of a hierarchy bundle's ``manifest.json``.
BUNDLE_MANIFEST_VERSION = 1
#: Schema version of ``ham.json``.
HAM_FILE_VERSION = 1
#: Version of a benchmark task's record (``records/METHOD/seed-N.json``).
BENCHMARK_RECORD_VERSION = 1
#: Schema version of the quickstart's ``results.json`` (2: no ``ham_available``, HAM is always compared).
QUICKSTART_RESULTS_VERSION = 2

#: A models manifest's kind: the key its entries are under.
ManifestKind = Literal["workers", "models"]
_MANIFEST_VERSIONS: dict[str, int] = {"workers": WORKERS_MANIFEST_VERSION, "models": FLAT_MANIFEST_VERSION}

BUNDLE_KIND = "sb3-hddpg-hierarchy"
HAM_KIND = "sb3-hddpg-ham"

#: A JSON object as read from a file: its values are checked where they are used.
JsonObject = dict[str, Any]


class JsonRecord(Mapping[str, Any]):
    """A record that reads as the JSON object it is written as (``record["workers"]``, ``dict(record)``)."""

    def to_json(self) -> JsonObject:
        """The record as the JSON object written to its file."""
        raise NotImplementedError

    def __getitem__(self, key: str) -> Any:
        return self.to_json()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self.to_json())

    def __len__(self) -> int:
        return len(self.to_json())


def _check_version(value: object, newest: int, what: str) -> int:
    """A schema version: a whole number no newer than ``newest`` (a missing one is version 1)."""
    version = 1 if value is None else value
    if isinstance(version, bool) or not isinstance(version, int) or not 1 <= version <= newest:
        raise ValueError(
            f"{what}: unsupported schema version {brief(value)} (this library reads <= {newest})"
        )
    return version


# ----------------------------------------------------------------------------------------------------------
# Models manifests
# ----------------------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class ModelEntry(JsonRecord):
    """
    One trained model's entry in a models manifest: what it is, where its file is, how to rebuild it.

    :param name: the entry's name; the model file is ``NAME.zip`` beside the manifest.
    :param sha256: the file's hash.
    :param algo: the algorithm's registry name.
    :param env_id: the env the model was trained on.
    :param env_kwargs: its keyword arguments.
    :param config: ``{"file": ..., "block": ...}``: the config the model was trained with.
    :param seed: the training seed.
    :param timesteps_requested: the budget asked for.
    :param timesteps_trained: the steps trained.
    :param backend: ``sb3`` or ``sbx``.
    :param versions: the library versions it was trained with.
    :param metrics: its evaluation metrics.
    :param spec: the weights-only rebuild spec (:func:`~sb3_hddpg.artifacts.spec.model_spec`).
    :param facts: more facts for this kind of model (reward term and bounds, preferences, threads...).
    """

    name: str
    sha256: str
    algo: str
    env_id: str
    env_kwargs: Mapping[str, Any]
    config: Mapping[str, Any]
    seed: int
    timesteps_requested: int
    timesteps_trained: int
    backend: str
    versions: Mapping[str, str]
    metrics: Mapping[str, Any]
    spec: Mapping[str, Any]
    facts: Mapping[str, Any] = field(default_factory=dict)

    @property
    def file(self) -> str:
        """The model file's name, beside the manifest."""
        return f"{self.name}.zip"

    def to_json(self) -> JsonObject:
        return {
            "name": self.name,
            "file": self.file,
            "sha256": self.sha256,
            "algo": self.algo,
            "env_id": self.env_id,
            "env_kwargs": dict(self.env_kwargs),
            "config": dict(self.config),
            "seed": self.seed,
            "timesteps_requested": self.timesteps_requested,
            "timesteps_trained": self.timesteps_trained,
            **self.facts,
            "backend": self.backend,
            "versions": dict(self.versions),
            "metrics": dict(self.metrics),
            "spec": dict(self.spec),
        }


@dataclass(frozen=True, eq=False)
class ModelsManifest(JsonRecord):
    """
    ``workers/manifest.json`` (``kind="workers"``) or ``flat/manifest.json`` (``kind="models"``): name ->
    model entry, in order, and for workers trained on another env than the snake arm, the shared env.

    Entries read from a file stay the JSON objects they are (checked: a plain name, a file beside the
    manifest and its sha256); the loaders check the rest (spec, env settings) where they use it.

    :param kind: ``workers`` or ``models``.
    :param entries: name -> entry.
    :param shared_env: ``{"env_id": ..., "env_kwargs": ...}`` of the env the workers share, if recorded.
    :param schema_version: the file's schema version.
    """

    kind: ManifestKind
    entries: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    shared_env: Mapping[str, Any] | None = None
    schema_version: int = 1

    @property
    def names(self) -> list[str]:
        """The entries' names, in order."""
        return list(self.entries)

    def with_entry(self, name: str, entry: Mapping[str, Any]) -> ModelsManifest:
        """This manifest with ``entry`` (a :class:`ModelEntry` or a JSON object) as ``name``'s."""
        as_json = entry.to_json() if isinstance(entry, JsonRecord) else dict(entry)
        return replace(self, entries={**self.entries, name: as_json})

    def with_shared_env(self, env_id: str, env_kwargs: Mapping[str, Any]) -> ModelsManifest:
        """This manifest recording ``env_id`` and ``env_kwargs`` as the workers' shared env."""
        return replace(self, shared_env={"env_id": env_id, "env_kwargs": dict(env_kwargs)})

    def to_json(self) -> JsonObject:
        out: JsonObject = {
            "schema_version": self.schema_version,
            self.kind: {k: dict(v) for k, v in self.entries.items()},
        }
        if self.shared_env is not None:
            out["shared_env"] = dict(self.shared_env)
        return out


def models_manifest(
    kind: ManifestKind,
    entries: Mapping[str, Mapping[str, Any]] | None = None,
    shared_env: Mapping[str, Any] | None = None,
) -> ModelsManifest:
    """
    The one builder of a models manifest, at this library's schema version.

    :param kind: ``workers`` or ``models``.
    :param entries: name -> entry (:class:`ModelEntry` or its JSON).
    :param shared_env: the workers' shared env, ``{"env_id": ..., "env_kwargs": ...}``.
    """
    manifest = ModelsManifest(
        kind, {}, dict(shared_env) if shared_env is not None else None, _MANIFEST_VERSIONS[kind]
    )
    for name, entry in (entries or {}).items():
        manifest = manifest.with_entry(name, entry)
    return manifest


def models_manifest_from_json(value: object, kind: ManifestKind, what: str) -> ModelsManifest:
    """
    A models manifest from parsed JSON, checked: an object with its entries under ``kind``, each a plain
    name with a file beside the manifest and its sha256, and a schema version this library reads.

    :raises ValueError: naming ``what`` and the first problem.
    """
    if not isinstance(value, dict) or not isinstance(value.get(kind), dict):
        raise ValueError(f"Not a valid {kind} manifest: {what!r}")
    version = _check_version(value.get("schema_version"), _MANIFEST_VERSIONS[kind], what)
    entries: dict[str, Mapping[str, Any]] = {}
    # Names and files travel with shared folders: each must be a plain name before it picks a file.
    for name, entry in value[kind].items():
        check_name(name, f"{what}: {kind}")
        entries[name] = check_file_entry(entry, f"{what}: {kind}.{brief(name)}")
    shared = value.get("shared_env")
    if shared is not None and not isinstance(shared, dict):
        raise ValueError(f"{what}: shared_env must be a mapping, actually: {brief(shared)}")
    return ModelsManifest(kind, entries, shared, version)


def read_models_manifest(path: str | Path, kind: ManifestKind) -> ModelsManifest:
    """
    The one reader of a models manifest file, through the size- and depth-limited JSON reader.

    :param path: the manifest.
    :param kind: ``workers`` or ``models``.
    :return: the manifest; raises ``ValueError`` naming the file if it is not a valid one (a
        :class:`~sb3_hddpg.artifacts.limits.LimitError` if over a limit).
    """
    try:
        value = read_json_file(Path(path))
    except LimitError:
        raise
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        raise ValueError(f"Not a valid {kind} manifest: {str(path)!r}") from None
    return models_manifest_from_json(value, kind, str(path))


def read_workers_manifest(path: str | Path) -> ModelsManifest:
    """Read and check a ``workers/manifest.json`` (:func:`read_models_manifest`)."""
    return read_models_manifest(path, "workers")


# ----------------------------------------------------------------------------------------------------------
# Hierarchy bundles
# ----------------------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class BundleManifest(JsonRecord):
    """
    A hierarchy bundle's ``manifest.json``: the shared env, the workers in the manager's action order,
    the selection settings, and one entry per member (the manager's, each worker's) with its file, sha256
    and rebuild spec.

    :param env_id: the shared env (checked against the allow-list when the bundle is loaded).
    :param env_kwargs: its keyword arguments.
    :param worker_names: the workers, in the manager's action order.
    :param selection: the selection settings (checked when loaded).
    :param manager: the manager's entry (file ``manager.zip``, sha256, spec, metadata).
    :param workers: name -> the worker's entry (``kind`` ``sb3`` or ``hierarchy``).
    :param versions: the library versions that wrote it.
    :param schema_version: the file's schema version.
    """

    env_id: Any
    env_kwargs: Any
    worker_names: list[str]
    selection: Any
    manager: Mapping[str, Any]
    workers: Mapping[str, Mapping[str, Any]]
    versions: Mapping[str, Any] = field(default_factory=dict)
    schema_version: int = BUNDLE_MANIFEST_VERSION

    def member_entries(self) -> list[tuple[str, Mapping[str, Any]]]:
        """(label, entry) of every member: the manager first, then the workers in order."""
        return [("manager", self.manager), *((name, self.workers[name]) for name in self.worker_names)]

    def to_json(self) -> JsonObject:
        return {
            "schema_version": self.schema_version,
            "kind": BUNDLE_KIND,
            "env_id": self.env_id,
            "env_kwargs": self.env_kwargs,
            "worker_names": list(self.worker_names),
            "selection": self.selection,
            "manager": dict(self.manager),
            "workers": {name: dict(entry) for name, entry in self.workers.items()},
            "versions": dict(self.versions),
        }

    @classmethod
    def from_json(cls, value: object, what: str) -> BundleManifest:
        """
        The one reader of a bundle manifest (parsed by the limited JSON reader): its kind and schema
        version, 2 to :data:`~sb3_hddpg.artifacts.limits.MAX_WORKERS` plain worker names that are exactly
        the workers' keys in order, and every member entry naming the member its writer gives it.

        :raises ValueError: naming ``what`` and the first problem.
        """
        if not isinstance(value, dict) or value.get("kind") != BUNDLE_KIND:
            raise ValueError(f"{what}: manifest.json is not an sb3-hddpg hierarchy manifest")
        version = value.get("schema_version")
        if isinstance(version, bool) or not isinstance(version, int) or version > BUNDLE_MANIFEST_VERSION:
            raise ValueError(
                f"{what}: unsupported bundle schema version {brief(version)} "
                f"(this library reads <= {BUNDLE_MANIFEST_VERSION})"
            )
        names, workers, manager = value.get("worker_names"), value.get("workers"), value.get("manager")
        if not isinstance(names, list) or not isinstance(workers, dict) or not isinstance(manager, dict):
            raise ValueError(
                f"{what}: manifest.json lacks the manager, the workers, or the worker_names list"
            )
        _check_worker_names(names, list(workers), what)
        record = cls(
            value.get("env_id"),
            value.get("env_kwargs"),
            names,
            value.get("selection"),
            manager,
            workers,
            versions if isinstance(versions := value.get("versions"), dict) else {},
            version,
        )
        for label, entry in record.member_entries():
            _check_member_entry(label, entry, what)
        return record


def bundle_manifest(
    env_id: str,
    env_kwargs: Mapping[str, Any],
    worker_names: Sequence[str],
    selection: Mapping[str, Any],
    manager: Mapping[str, Any],
    workers: Mapping[str, Mapping[str, Any]],
    versions: Mapping[str, Any],
) -> BundleManifest:
    """The one builder of a bundle manifest, at this library's schema version (see :class:`BundleManifest`)."""
    return BundleManifest(
        env_id,
        dict(env_kwargs),
        list(worker_names),
        dict(selection),
        manager,
        workers,
        versions,
        BUNDLE_MANIFEST_VERSION,
    )


def _check_worker_names(names: list[Any], workers: list[Any], what: str) -> None:
    """``worker_names``: 2 to ``MAX_WORKERS`` plain names, exactly the keys of ``workers`` in order."""
    if not 2 <= len(names) <= MAX_WORKERS:
        raise ValueError(
            f"{what}: manifest.json has {len(names)} workers; a manager selects between 2 and {MAX_WORKERS}"
        )
    for worker in names:
        check_name(worker, f"{what}: worker_names")
    if names != workers:
        raise ValueError(f"{what}: worker_names {brief(names)} do not match workers {brief(workers)}")


_SHA256_CHARS = frozenset("0123456789abcdef")


def _check_member_entry(label: str, entry: object, what: str) -> None:
    """
    One member's entry: its file and sha256, and the member name the writer gives it; any other name is
    refused, so a manifest cannot point at an arbitrary member.
    """
    sha = entry.get("sha256") if isinstance(entry, dict) else None
    if not (
        isinstance(entry, dict)
        and isinstance(entry.get("file"), str)
        and isinstance(sha, str)
        and len(sha) == 64
        and set(sha) <= _SHA256_CHARS
    ):
        raise ValueError(f"{what}: manifest.json entry {label!r} lacks its member's file and sha256")
    kind = entry.get("kind", "sb3")
    if kind not in ("sb3", "hierarchy") or (label == "manager" and kind != "sb3"):
        raise ValueError(f"{what}: {label!r} has an unknown kind {brief(kind)}")
    if label == "manager":
        expected = "manager.zip"
    else:
        expected = f"workers/{label}.hierarchy.zip" if kind == "hierarchy" else f"workers/{label}.zip"
    if entry["file"] != expected:
        raise ValueError(
            f"{what}: {label!r} names member {brief(entry['file'])}; a bundle names it {expected!r}"
        )


# ----------------------------------------------------------------------------------------------------------
# The HAM switch's file
# ----------------------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class HamFile(JsonRecord):
    """
    ``ham.json``: the HAM switch's settings and where its workers are.

    :param threshold: the switching threshold.
    :param hysteresis: the switching hysteresis.
    :param goal: the goal worker's name in the workers manifest.
    :param avoid: the avoid worker's name.
    :param workers_manifest: the workers manifest, relative to the ``ham.json`` file (POSIX separators).
    :param env_id: the env the switch acts in.
    :param env_kwargs: its keyword arguments.
    :param metadata: more JSON facts (seed, metrics...), kept as written.
    :param schema_version: the file's schema version.
    """

    threshold: float
    hysteresis: float
    goal: str
    avoid: str
    workers_manifest: str
    env_id: str
    env_kwargs: Mapping[str, Any] = field(default_factory=dict)
    metadata: Mapping[str, Any] = field(default_factory=dict)
    schema_version: int = HAM_FILE_VERSION

    @property
    def names(self) -> tuple[str, str]:
        """The goal and avoid workers' names."""
        return self.goal, self.avoid

    def to_json(self) -> JsonObject:
        return {
            "schema_version": self.schema_version,
            "kind": HAM_KIND,
            "threshold": self.threshold,
            "hysteresis": self.hysteresis,
            "worker_names": {"goal": self.goal, "avoid": self.avoid},
            "workers_manifest": self.workers_manifest,
            "env_id": self.env_id,
            "env_kwargs": dict(self.env_kwargs),
            **self.metadata,
        }


_HAM_FIELDS = frozenset(
    [
        "schema_version",
        "kind",
        "threshold",
        "hysteresis",
        "worker_names",
        "workers_manifest",
        "env_id",
        "env_kwargs",
    ]
)


def ham_file(
    threshold: float,
    hysteresis: float,
    names: Sequence[str],
    workers_manifest: str,
    env_id: str,
    env_kwargs: Mapping[str, Any] | None = None,
    metadata: Mapping[str, Any] | None = None,
) -> HamFile:
    """The one builder of a ``ham.json`` record, at this library's schema version (see :class:`HamFile`)."""
    extra = {k: v for k, v in (metadata or {}).items() if k not in _HAM_FIELDS}
    return HamFile(
        float(threshold),
        float(hysteresis),
        names[0],
        names[1],
        workers_manifest,
        env_id,
        dict(env_kwargs or {}),
        extra,
    )


def read_ham_file(
    path: str | Path, trusted: bool = False, allowed_env_ids: Sequence[str] | None = None
) -> HamFile:
    """
    The one reader of ``ham.json``, every field checked before use: the size-limited JSON reader, the kind
    and schema version, a workers manifest named ``manifest.json``, plain worker names, a registered and
    allowed env id with the env's own keyword arguments, finite threshold and hysteresis.

    :param path: the file.
    :param trusted: accept any registered env id.
    :param allowed_env_ids: registered env ids the file may name besides this package's own.
    :raises FileNotFoundError: if there is no such file.
    :raises ValueError: naming the file and the first problem.
    """
    where = str(path)
    try:
        meta = read_json_file(Path(path))
    except FileNotFoundError:
        raise FileNotFoundError(f"No such file: {where!r}") from None
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise ValueError(f"Not a valid JSON file: {where!r}") from None
    if not isinstance(meta, dict) or meta.get("kind") != HAM_KIND:
        raise ValueError(f"{where!r} is not an sb3-hddpg HAM file (expected kind {HAM_KIND!r})")
    version = meta.get("schema_version")
    if isinstance(version, bool) or not isinstance(version, int) or version > HAM_FILE_VERSION:
        raise ValueError(
            f"{where!r} has schema_version {brief(version)}; this sb3-hddpg reads up to {HAM_FILE_VERSION}"
        )
    missing = [k for k in ("workers_manifest", "worker_names", "env_id", "threshold") if k not in meta]
    if missing:
        raise ValueError(f"{where}: missing field {missing[0]!r}")
    relative = meta["workers_manifest"]
    if not isinstance(relative, str) or Path(relative).name != "manifest.json":
        raise ValueError(
            f"{where}: workers_manifest must be a path to a manifest.json, got {brief(relative)}"
        )
    pair = meta["worker_names"]
    if not isinstance(pair, dict) or set(pair) != {"goal", "avoid"}:
        raise ValueError(f"{where}: worker_names must map 'goal' and 'avoid' to names, got {brief(pair)}")
    goal = check_name(pair["goal"], f"{where}: worker_names.goal")
    avoid = check_name(pair["avoid"], f"{where}: worker_names.avoid")
    env_id = check_env_id(meta["env_id"], f"{where}: env_id", allowed_env_ids, trusted)
    env_kwargs = check_env_kwargs(
        env_id, meta.get("env_kwargs"), f"{where}: env_kwargs", allowed_env_ids, trusted
    )
    numbers = {key: meta.get(key, 0.0) for key in ("threshold", "hysteresis")}
    for key, value in numbers.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ValueError(f"{where}: {key} must be a finite number, got {brief(value)}")
    extra = {k: v for k, v in meta.items() if k not in _HAM_FIELDS}
    return HamFile(
        float(numbers["threshold"]),
        float(numbers["hysteresis"]),
        goal,
        avoid,
        relative,
        env_id,
        env_kwargs,
        extra,
        version,
    )


# ----------------------------------------------------------------------------------------------------------
# Benchmark task records
# ----------------------------------------------------------------------------------------------------------

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
        version = _check_version(value.get("record_version"), BENCHMARK_RECORD_VERSION, what)
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
    try:
        value = read_json_file(Path(path))
    except LimitError:
        raise
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ValueError(f"{path}: not a readable benchmark record ({type(error).__name__})") from None
    return BenchmarkRecord.from_json(value, str(path))

"""``workers/manifest.json`` and ``flat/manifest.json``: the models manifest and its entries."""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from sb3_hddpg.artifacts.limits import (
    MAX_ENV_FLOAT,
    MAX_SEED,
    MIN_ENV_FLOAT,
    LimitError,
    brief,
    check_count,
    check_name,
    read_json_record,
)
from sb3_hddpg.artifacts.records.base import (
    MANIFEST_VERSIONS,
    JsonObject,
    JsonRecord,
    ManifestKind,
    check_version,
)
from sb3_hddpg.envs.contract import check_bounds

#: A model file named in a workers or flat manifest: a name and ``.zip``, in the manifest's own folder.
FILE_PATTERN = re.compile(r"\A[A-Za-z0-9][A-Za-z0-9_-]{0,63}\.zip\Z", re.ASCII)
_SHA256 = re.compile(r"^[0-9a-f]{64}$")


def check_file_entry(entry: object, what: str) -> dict[str, Any]:
    """
    One entry of a models manifest: its ``file`` a plain ``NAME.zip`` in the manifest's folder, its ``sha256``
    a hex digest, its ``name`` and ``algo`` plain names, its seed and env numbers within their limits.

    :param entry: the entry from the file.
    :param what: where it is, for the message.
    :return: the entry; raises :class:`LimitError` naming the field otherwise.
    """
    if not isinstance(entry, Mapping):
        raise LimitError(f"{what}: expected an object, got {brief(entry)}")
    file = entry.get("file")
    if not isinstance(file, str) or not FILE_PATTERN.match(file):
        raise LimitError(
            f"{what}.file: expected a file name 'NAME.zip' in the same folder, got {brief(file)}"
        )
    if not isinstance(entry.get("sha256"), str) or not _SHA256.match(entry["sha256"]):
        raise LimitError(f"{what}.sha256: expected a sha256 hex digest, got {brief(entry.get('sha256'))}")
    for key in ("name", "algo"):
        if key in entry:
            check_name(entry[key], f"{what}.{key}")
    seed = entry.get("seed")
    if "seed" in entry and (isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED):
        raise LimitError(f"{what}.seed: expected an integer in [0, {MAX_SEED}], got {brief(seed)}")
    _check_env_numbers(entry.get("env_kwargs"), f"{what}.env_kwargs")
    return dict(entry)


def _check_env_numbers(env_kwargs: object, what: str) -> None:
    """The floats of an entry's env settings: 0 or a finite magnitude within the env settings' limits."""
    if env_kwargs is None:
        return
    if not isinstance(env_kwargs, Mapping):
        raise LimitError(f"{what}: expected a mapping, got {brief(env_kwargs)}")
    for key, value in env_kwargs.items():
        if isinstance(value, float) and not (
            value == 0 or MIN_ENV_FLOAT <= abs(value) <= MAX_ENV_FLOAT  # NaN fails both comparisons
        ):
            raise LimitError(
                f"{what}.{brief(key)}: expected 0 or a finite magnitude in [{MIN_ENV_FLOAT:g}, "
                f"{MAX_ENV_FLOAT:g}], got {value!r}"
            )


@dataclass(frozen=True, eq=False)
class ModelEntry(JsonRecord):
    """
    One trained model's entry in a models manifest, as :func:`~sb3_hddpg.artifacts.manifests.model_entry`
    builds it from its arguments and the outcome: the file's ``sha256``, the ``timesteps_trained``, the
    ``backend`` (``sb3`` or ``sbx``), the library ``versions``, the evaluation ``metrics`` and the
    weights-only rebuild ``spec``.
    """

    name: str
    sha256: str
    algo: str
    env_id: str
    env_kwargs: Mapping[str, object]
    config: Mapping[str, object]
    seed: int
    timesteps_requested: int
    timesteps_trained: int
    backend: str
    versions: Mapping[str, str]
    metrics: Mapping[str, object]
    spec: Mapping[str, object]
    facts: Mapping[str, object] = field(default_factory=dict)

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
    model entry (as JSON, :func:`check_file_entry`), in order, and the workers' shared env if recorded.

    :param kind: ``workers`` or ``models``.
    :param entries: name -> entry.
    :param shared_env: ``{"env_id": ..., "env_kwargs": ...}`` of the env the workers share, if recorded.
    :param schema_version: the file's schema version.
    """

    kind: ManifestKind
    entries: Mapping[str, JsonObject] = field(default_factory=dict)
    shared_env: Mapping[str, object] | None = None
    schema_version: int = 1

    @property
    def names(self) -> list[str]:
        """The entries' names, in order."""
        return list(self.entries)

    def with_entry(self, name: str, entry: ModelEntry | Mapping[str, object]) -> ModelsManifest:
        """This manifest with ``entry`` (a :class:`ModelEntry` or a JSON object) as ``name``'s."""
        as_json = entry.to_json() if isinstance(entry, JsonRecord) else dict(entry)
        return replace(self, entries={**self.entries, name: as_json})

    def with_shared_env(self, env_id: str, env_kwargs: Mapping[str, object]) -> ModelsManifest:
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
    entries: Mapping[str, ModelEntry | Mapping[str, object]] | None = None,
    shared_env: Mapping[str, object] | None = None,
) -> ModelsManifest:
    """
    The one builder of a models manifest, at this library's schema version.

    :param kind: ``workers`` or ``models``.
    :param entries: name -> entry (:class:`ModelEntry` or its JSON).
    :param shared_env: the workers' shared env, ``{"env_id": ..., "env_kwargs": ...}``.
    """
    manifest = ModelsManifest(
        kind, {}, dict(shared_env) if shared_env is not None else None, MANIFEST_VERSIONS[kind]
    )
    for name, entry in (entries or {}).items():
        manifest = manifest.with_entry(name, entry)
    return manifest


def models_manifest_from_json(value: object, kind: ManifestKind, what: str) -> ModelsManifest:
    """A models manifest from parsed JSON, checked; raises ``ValueError`` naming ``what`` and the first problem."""
    if not isinstance(value, dict) or not isinstance(value.get(kind), dict):
        raise ValueError(f"Not a valid {kind} manifest: {what!r}")
    version = check_version(value.get("schema_version"), MANIFEST_VERSIONS[kind], what)
    entries: dict[str, JsonObject] = {}
    # Counted before any entry is looked at, let alone loaded.
    check_count("manifest_entries", len(value[kind]), f"{what}: the number of {kind} entries")
    # Names and files travel with shared folders: each must be a plain name before it picks a file.
    for name, entry in value[kind].items():
        check_name(name, f"{what}: {kind}")
        field_of = f"{what}: {kind}.{brief(name)}"
        entries[name] = check_file_entry(entry, field_of)
        if "reward_bounds" in entry:
            # The one bounds checker, here rather than when a manager trained on them writes its bundle.
            bounds = entry["reward_bounds"]
            check_bounds({str(entry.get("reward_term", name)): bounds}, f"{field_of}.reward_bounds")
            if not isinstance(bounds, list) or len(bounds) != 2:
                raise ValueError(f"{field_of}.reward_bounds: expected [low, high], actually: {brief(bounds)}")
    shared = value.get("shared_env")
    if shared is not None and not isinstance(shared, dict):
        raise ValueError(f"{what}: shared_env must be a mapping, actually: {brief(shared)}")
    return ModelsManifest(kind, entries, shared, version)


def read_models_manifest(path: str | Path, kind: ManifestKind) -> ModelsManifest:
    """
    The one reader of a models manifest file.

    :param path: the manifest.
    :param kind: ``workers`` or ``models``.
    :return: the manifest; raises ``ValueError`` naming the file if it is not a valid one.
    """
    value = read_json_record(path, f"Not a valid {kind} manifest: {str(path)!r}")
    return models_manifest_from_json(value, kind, str(path))


def read_workers_manifest(path: str | Path) -> ModelsManifest:
    """Read and check a ``workers/manifest.json`` (:func:`read_models_manifest`)."""
    return read_models_manifest(path, "workers")

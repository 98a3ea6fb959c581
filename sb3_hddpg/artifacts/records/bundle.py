"""A hierarchy bundle's ``manifest.json``."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from sb3_hddpg.artifacts.limits import MAX_WORKERS, brief, check_name
from sb3_hddpg.artifacts.records.base import BUNDLE_KIND, BUNDLE_MANIFEST_VERSION, JsonObject, JsonRecord


@dataclass(frozen=True, eq=False)
class BundleManifest(JsonRecord):
    """
    A hierarchy bundle's ``manifest.json``.

    :param env_id: the shared env.
    :param env_kwargs: its keyword arguments.
    :param worker_names: the workers, in the manager's action order.
    :param selection: the selection settings.
    :param manager: the manager's entry (its member file, sha256, rebuild spec and metadata); ``None`` for a
        hierarchy that selects by GPI, which has no manager.
    :param workers: name -> the worker's entry (as the manager's, with ``kind`` ``sb3`` or ``hierarchy`` and
        :meth:`~sb3_hddpg.artifacts.workers.Workers.bundle_meta`).
    :param versions: the library versions that wrote it.
    :param schema_version: the file's schema version.
    """

    env_id: object
    env_kwargs: object
    worker_names: list[str]
    selection: object
    manager: JsonObject | None
    workers: Mapping[str, JsonObject]
    versions: Mapping[str, object] = field(default_factory=dict)
    schema_version: int = BUNDLE_MANIFEST_VERSION

    def member_entries(self) -> list[tuple[str, JsonObject]]:
        """(label, entry) of every member: the manager first (if any), then the workers in order."""
        manager = [("manager", self.manager)] if self.manager is not None else []
        return [*manager, *((name, self.workers[name]) for name in self.worker_names)]

    def to_json(self) -> JsonObject:
        return {
            "schema_version": self.schema_version,
            "kind": BUNDLE_KIND,
            "env_id": self.env_id,
            "env_kwargs": self.env_kwargs,
            "worker_names": list(self.worker_names),
            "selection": self.selection,
            "manager": dict(self.manager) if self.manager is not None else None,
            "workers": {name: dict(entry) for name, entry in self.workers.items()},
            "versions": dict(self.versions),
        }

    @classmethod
    def from_json(cls, value: object, what: str) -> BundleManifest:
        """
        The one reader of a bundle manifest: its kind and schema version, 2 to
        :data:`~sb3_hddpg.artifacts.limits.MAX_WORKERS` plain worker names that are exactly the workers' keys
        in order, and every member entry naming the member its writer gives it; raises ``ValueError``.
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
        selection = value.get("selection")
        # Only a GPI hierarchy acts without a manager (its workers' critics select).
        managerless = (
            manager is None
            and isinstance(selection, dict)
            and selection.get("selection") in ("gpi", "gpi-policies")
        )
        if (
            not isinstance(names, list)
            or not isinstance(workers, dict)
            or not (isinstance(manager, dict) or managerless)
        ):
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
    env_kwargs: Mapping[str, object],
    worker_names: Sequence[str],
    selection: Mapping[str, object],
    manager: Mapping[str, object] | None,
    workers: Mapping[str, Mapping[str, object]],
    versions: Mapping[str, object],
) -> BundleManifest:
    """The one builder of a bundle manifest, at this library's schema version (see :class:`BundleManifest`)."""
    return BundleManifest(
        env_id,
        dict(env_kwargs),
        list(worker_names),
        dict(selection),
        dict(manager) if manager is not None else None,
        {name: dict(entry) for name, entry in workers.items()},
        versions,
        BUNDLE_MANIFEST_VERSION,
    )


def _check_worker_names(names: list[object], workers: list[object], what: str) -> None:
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
    """One member's entry: its sha256, and the member name the writer gives it (never an arbitrary member)."""
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

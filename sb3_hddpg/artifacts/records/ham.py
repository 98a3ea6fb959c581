"""``ham.json``: the HAM switch's settings and where its workers are."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sb3_hddpg.artifacts.limits import brief, check_env_id, check_name, read_json_file
from sb3_hddpg.artifacts.records.base import HAM_FILE_VERSION, HAM_KIND, JsonObject, JsonRecord
from sb3_hddpg.artifacts.values import check_env_kwargs


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
    metadata: Mapping[str, object] = field(default_factory=dict)
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
    env_kwargs: Mapping[str, object] | None = None,
    metadata: Mapping[str, object] | None = None,
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

"""The schema version of every file this package writes, in one place, and the base of the records."""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import Any, Literal

from sb3_hddpg.artifacts.limits import brief

WORKERS_MANIFEST_VERSION = 1
FLAT_MANIFEST_VERSION = 1  #: Schema version of ``flat/manifest.json``.
BUNDLE_MANIFEST_VERSION = 1  #: Schema version of a hierarchy bundle's ``manifest.json``.
HAM_FILE_VERSION = 1  #: Schema version of ``ham.json``.
BENCHMARK_RECORD_VERSION = 1  #: Version of a benchmark task's record (``records/METHOD/seed-N.json``).
#: Schema version of a benchmark's ``results.json`` (files without one are version 1).
BENCHMARK_RESULTS_VERSION = 1
#: Schema version of the quickstart's ``results.json`` (2: no ``ham_available``, HAM is always compared).
QUICKSTART_RESULTS_VERSION = 2

ManifestKind = Literal["workers", "models"]  #: A models manifest's kind: the key its entries are under.
MANIFEST_VERSIONS: dict[str, int] = {"workers": WORKERS_MANIFEST_VERSION, "models": FLAT_MANIFEST_VERSION}

BUNDLE_KIND = "sb3-hddpg-hierarchy"
HAM_KIND = "sb3-hddpg-ham"

#: A JSON value: what ``json.loads`` returns, and what a record's JSON fields may hold.
JsonScalar = str | int | float | bool | None
JsonValue = JsonScalar | list["JsonValue"] | dict[str, "JsonValue"]

JsonObject = dict[str, Any]  #: A JSON object as read from a file: its values are checked where they are used.


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


def check_version(value: object, newest: int, what: str) -> int:
    """A schema version: a whole number no newer than ``newest`` (a missing one is version 1)."""
    version = 1 if value is None else value
    if isinstance(version, bool) or not isinstance(version, int) or not 1 <= version <= newest:
        raise ValueError(
            f"{what}: unsupported schema version {brief(value)} (this library reads <= {newest})"
        )
    return version

"""
The records this package writes beside trained models (frozen dataclasses, each with one builder and one reader
that checks what it reads through :mod:`sb3_hddpg.artifacts.limits`) and the schema version of every file it
writes. Each record is also a read-only mapping of the JSON it is written as.
"""

from sb3_hddpg.artifacts.records.base import (
    BENCHMARK_RECORD_VERSION,
    BENCHMARK_RESULTS_VERSION,
    QUICKSTART_RESULTS_VERSION,
    WORKERS_MANIFEST_VERSION,
    JsonObject,
    JsonValue,
    ManifestKind,
)
from sb3_hddpg.artifacts.records.bundle import BundleManifest, bundle_manifest
from sb3_hddpg.artifacts.records.models import (
    ModelEntry,
    ModelsManifest,
    models_manifest,
    models_manifest_from_json,
    read_models_manifest,
    read_workers_manifest,
)

__all__ = [
    "BENCHMARK_RECORD_VERSION",
    "BENCHMARK_RESULTS_VERSION",
    "QUICKSTART_RESULTS_VERSION",
    "WORKERS_MANIFEST_VERSION",
    "BundleManifest",
    "JsonObject",
    "JsonValue",
    "ManifestKind",
    "ModelEntry",
    "ModelsManifest",
    "bundle_manifest",
    "models_manifest",
    "models_manifest_from_json",
    "read_models_manifest",
    "read_workers_manifest",
]

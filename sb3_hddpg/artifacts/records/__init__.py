"""
The records this package writes beside trained models (frozen dataclasses, each with one builder and one reader
that checks what it reads through :mod:`sb3_hddpg.artifacts.limits`) and the schema version of every file it
writes. Each record is also a read-only mapping of the JSON it is written as.
"""

from sb3_hddpg.artifacts.records.base import (
    BENCHMARK_RECORD_VERSION,
    BENCHMARK_RESULTS_VERSION,
    BUNDLE_MANIFEST_VERSION,
    FLAT_MANIFEST_VERSION,
    HAM_FILE_VERSION,
    QUICKSTART_RESULTS_VERSION,
    WORKERS_MANIFEST_VERSION,
    JsonObject,
    JsonRecord,
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
    "BUNDLE_MANIFEST_VERSION",
    "FLAT_MANIFEST_VERSION",
    "HAM_FILE_VERSION",
    "QUICKSTART_RESULTS_VERSION",
    "WORKERS_MANIFEST_VERSION",
    "BundleManifest",
    "JsonObject",
    "JsonRecord",
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

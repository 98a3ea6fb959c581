"""The records written beside trained models (one builder, one limited reader each), every schema version."""

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

"""
The records this package writes beside trained models, each a frozen dataclass with one builder and one
reader, and the schema version of every file it writes, in one place.

- :class:`ModelEntry`: one trained model's entry in a models manifest (built by
  :func:`~sb3_hddpg.artifacts.manifests.model_entry`, which hashes the file and describes the model).
- :class:`ModelsManifest`: ``workers/manifest.json`` and ``flat/manifest.json`` (:func:`models_manifest`,
  :func:`read_models_manifest`).
- :class:`BundleManifest`: a hierarchy bundle's ``manifest.json`` (:func:`bundle_manifest`,
  :meth:`BundleManifest.from_json`).
- :class:`~sb3_hddpg.artifacts.records.ham.HamFile`: ``ham.json``, the HAM switch's settings (its own module,
  loaded with the HAM baseline).

Every reader checks what it reads through :mod:`sb3_hddpg.artifacts.limits` (the size- and depth-limited
JSON reader, plain names, file entries) and :mod:`sb3_hddpg.artifacts.values` (env settings), and refuses
a schema version newer than the one here. Each record is also a read-only mapping of the JSON it is
written as, so that code reading a manifest as the JSON object it was keeps working.
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

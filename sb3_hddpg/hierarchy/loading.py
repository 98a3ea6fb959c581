"""
``load_policy(path)``: any policy a user can point the CLI at, loaded safely, with the env it acts in.

- a hierarchy bundle (``hierarchy.zip``), verified by :meth:`Hierarchy.load`;
- an SB3 zip listed in the ``manifest.json`` beside it (its sha256 and rebuild spec: a weights-only load);
- a file or a name a registered loader opens (:mod:`sb3_hddpg.policy_loaders`: ``ham.json``, ``random``...);
- any other SB3 zip only with ``trusted=True`` (SB3's full loader runs code stored in the file).
"""

from __future__ import annotations

import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sb3_hddpg.artifacts.limits import check_env_id, check_run_file, read_json_record
from sb3_hddpg.artifacts.provenance import read_verified
from sb3_hddpg.artifacts.records import ManifestKind, models_manifest_from_json
from sb3_hddpg.artifacts.safe_load import load_model
from sb3_hddpg.artifacts.values import check_env_kwargs
from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID
from sb3_hddpg.hierarchy.hierarchy import Hierarchy
from sb3_hddpg.policy_loaders import LoadedPolicy, file_loader, named_loader

__all__ = ["LoadedPolicy", "load_policy"]


def load_policy(
    path: str | Path,
    env_id: str | None = None,
    trusted: bool = False,
    algo: str | None = None,
    allowed_env_ids: Sequence[str] | None = None,
    env_kwargs: dict[str, Any] | None = None,
) -> LoadedPolicy:
    """
    Load the policy at ``path`` (see the module docstring for what it may be). An env id read from a file
    must be this package's or in ``allowed_env_ids`` (any registered id with ``trusted``), with the env's own
    parameters as kwargs (:mod:`sb3_hddpg.artifacts.limits`).

    :param path: a file, or ``random`` / ``scripted``.
    :param env_id: the env to act in, for reference policies and untracked zips (default SnakeReach).
    :param trusted: allow SB3's full loader for zips without a manifest, and any registered env id.
    :param algo: the algorithm of an untracked zip loaded with ``trusted``.
    :param allowed_env_ids: registered env ids a file may name besides this package's own.
    :param env_kwargs: ``env_id``'s keyword arguments, for reference policies (an adapter's ``env_id``...).
    """
    text = str(path)
    named = named_loader(text)
    if named is not None:
        return named.load()(text, env_id or SNAKE_REACH_ENV_ID, dict(env_kwargs or {}))
    path = _policy_file(Path(path))
    check_run_file(path)  # every loader below opens it: never through a link out of a run folder
    text = str(path)
    registered = file_loader(path.suffix)
    if registered is not None:
        return registered.load()(path, trusted, allowed_env_ids)
    if _is_bundle(path):
        hierarchy = Hierarchy.load(path, trusted=trusted, allowed_env_ids=allowed_env_ids)
        return LoadedPolicy(
            hierarchy, hierarchy.env_id, hierarchy.env_kwargs, "hierarchy", path.stem, hierarchy.metadata
        )
    entry, kind = _manifest_entry(path)
    if entry is not None:
        data = read_verified(path, entry["sha256"], text)
        where = f"{text}: manifest entry"
        entry_env = check_env_id(entry.get("env_id"), f"{where} env_id", allowed_env_ids, trusted)
        env_kwargs = check_env_kwargs(
            entry_env, entry.get("env_kwargs"), f"{where} env_kwargs", allowed_env_ids, trusted
        )
        model = load_model(data, spec=entry.get("spec"), trusted=trusted)
        return LoadedPolicy(model, entry_env, env_kwargs, kind, entry.get("name", path.stem), entry)
    if not trusted:
        raise ValueError(
            f"{text!r} has no sb3-hddpg manifest beside it, so it cannot be loaded without running code stored "
            "in it; pass --trust (with --algo) only if you trust the file"
        )
    model = load_model(path, trusted=True, algorithm=(algo or "ddpg").upper())
    return LoadedPolicy(model, env_id or SNAKE_REACH_ENV_ID, {}, "flat", path.stem, {})


def _policy_file(path: Path) -> Path:
    """The file to load for ``path``: the path itself, or a run folder's ``hierarchy.zip`` or ``ham.json``."""
    text = str(path)
    if not path.exists():
        raise FileNotFoundError(f"No such file: {text!r}")
    if not path.is_dir() and not path.is_file():
        raise ValueError(f"Expected a model file, got something else (a device or pipe?): {text!r}")
    if path.is_dir():
        for candidate in ("hierarchy.zip", "ham.json"):
            if (path / candidate).exists():
                return _policy_file(path / candidate)
        raise ValueError(f"Expected a model file, got a folder without hierarchy.zip or ham.json: {text!r}")
    return path


def _is_bundle(path: Path) -> bool:
    """Whether the zip at ``path`` is a hierarchy bundle (a manifest and no SB3 ``policy.pth``)."""
    try:
        with zipfile.ZipFile(path) as archive:
            members = set(archive.namelist())
    except (zipfile.BadZipFile, EOFError):
        raise ValueError(f"Not a zip file, or a truncated one: {str(path)!r}") from None
    except OSError as error:  # permission denied, I/O error
        raise ValueError(f"Cannot read {str(path)!r}: {error.strerror or error}") from None
    return "manifest.json" in members and "policy.pth" not in members


def _manifest_entry(path: Path) -> tuple[dict[str, Any] | None, str]:
    """The entry describing ``path`` in the ``manifest.json`` beside it, if any."""
    manifest_path = path.parent / "manifest.json"
    if not manifest_path.exists():
        return None, ""
    value = read_json_record(manifest_path, f"Invalid JSON in {str(manifest_path)!r}")
    if not isinstance(value, dict):
        raise ValueError(f"Not an sb3-hddpg manifest: {str(manifest_path)!r}")
    kinds: tuple[tuple[ManifestKind, str], ...] = (("workers", "worker"), ("models", "flat"))
    for kind, label in kinds:
        if kind not in value:
            continue
        manifest = models_manifest_from_json(value, kind, str(manifest_path))
        for entry in manifest.entries.values():
            if entry.get("file") == path.name:
                return dict(entry), label
    return None, ""

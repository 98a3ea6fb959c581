"""
The bundle file (``hierarchy.zip``): its members, its manifest, and how it is written, read and verified
within the limits of :mod:`sb3_hddpg.artifacts.limits`. :class:`~sb3_hddpg.hierarchy.hierarchy.Hierarchy`
saves and loads through it.
"""

from __future__ import annotations

import io
import json
import zipfile
import zlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.save_util import data_to_json
from stable_baselines3.common.utils import get_device

from sb3_hddpg.artifacts.io import json_text
from sb3_hddpg.artifacts.limits import (
    MAX_JSON_BYTES,
    MAX_MODEL_FILE_BYTES,
    LoadBudget,
    check_env_id,
    check_zip_directory,
    parse_json,
    read_file_bytes,
    read_member,
)
from sb3_hddpg.artifacts.provenance import verify_sha256
from sb3_hddpg.artifacts.records import BundleManifest
from sb3_hddpg.artifacts.safe_load import load_model
from sb3_hddpg.artifacts.term_critic import TermCritic, read_term_critic
from sb3_hddpg.artifacts.values import check_env_kwargs
from sb3_hddpg.envs.contract import env_contract
from sb3_hddpg.hierarchy.conditioning import PreferenceSpace
from sb3_hddpg.hierarchy.selection import check_reward_terms, check_selection_settings

#: The manifest's member name.
MANIFEST = "manifest.json"

#: What SB3's ``load`` says of a bundle: ``ValueError: Policy {this} unknown`` (see :func:`sb3_refusal`).
SB3_REFUSAL = "of an sb3-hddpg hierarchy bundle, which sb3_hddpg.Hierarchy.load opens (not an SB3 class), is"


class BundleError(ValueError):
    """A bundle that cannot be used: not a zip, truncated, tampered with, or inconsistent."""


def write_bundle(manifest: BundleManifest, members: Mapping[str, bytes]) -> bytes:
    """A bundle's zip bytes: the manifest and every member (name -> bytes)."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        archive.writestr(MANIFEST, json_text(manifest, MANIFEST))
        for member, data in members.items():
            archive.writestr(member, data)
    return buffer.getvalue()


def read_bundle(
    path: str | Path | io.BytesIO, budget: LoadBudget | None = None
) -> tuple[BundleManifest, dict[str, bytes]]:
    """
    Open a bundle (a path or its bytes) and verify it: a manifest of a known schema, every member it lists
    present and of its sha256, each read within ``budget`` and the limits of :mod:`sb3_hddpg.artifacts.limits`.

    :return: the manifest and the member bytes by name.
    """
    name = str(path) if not isinstance(path, io.BytesIO) else "<bytes>"
    budget = budget if budget is not None else LoadBudget()
    try:
        # Read once, within the limit and only from a regular file (not a FIFO, not /dev/zero): the
        # members are verified and loaded from these very bytes, so a file swapped meanwhile changes nothing.
        source = (
            path if isinstance(path, io.BytesIO) else io.BytesIO(read_file_bytes(path, MAX_MODEL_FILE_BYTES))
        )
        with zipfile.ZipFile(source) as archive:
            names = {info.filename for info in check_zip_directory(archive, name)}
            if MANIFEST not in names:
                raise BundleError(f"{name} is not a hierarchy bundle: it has no {MANIFEST}")
            raw = read_member(archive, MANIFEST, name, limit=MAX_JSON_BYTES, budget=budget)
            try:
                manifest = parse_json(raw, f"{name}: {MANIFEST}")
            except (json.JSONDecodeError, UnicodeDecodeError):
                raise BundleError(f"{name}: {MANIFEST} is not valid JSON") from None
            record = BundleManifest.from_json(manifest, name)  # its ValueError: a BundleError below
            entries = record.member_entries()
            members = {}
            for label, entry in entries:
                if entry["file"] not in names:
                    raise BundleError(f"{name}: member {entry['file']!r} of {label!r} is missing")
                members[entry["file"]] = read_member(archive, entry["file"], name, budget=budget)
    except BundleError:
        raise
    except FileNotFoundError:
        raise BundleError(f"No such file: {name!r}") from None
    except IsADirectoryError:
        raise BundleError(f"Expected a bundle file, got a folder: {name!r}") from None
    except (zipfile.BadZipFile, EOFError, zipfile.LargeZipFile, zlib.error, NotImplementedError):
        raise BundleError(f"Not a zip file, or a truncated or corrupted one: {name!r}") from None
    except OSError as error:  # permission denied, I/O error
        raise BundleError(f"Cannot read {name!r}: {error.strerror or error}") from None
    except ValueError as error:  # over a limit, or a corrupt member
        raise BundleError(str(error)) from None
    for _label, entry in entries:
        verify_sha256(
            members[entry["file"]],
            entry["sha256"],
            entry["file"],
            where=name,
            consequence="the bundle was modified or corrupted",
            error=BundleError,
        )
    return record, members


def sb3_refusal(observation_space: gym.Space, action_space: gym.Space) -> bytes:
    """
    The ``data`` member of a bundle, which SB3's ``load`` reads first: SB3 then checks the spaces (given an
    env) and names the policy class, :data:`SB3_REFUSAL`, in a one-line ``ValueError`` (without it:
    ``AssertionError: No data found``). Nothing of ours reads it, so it is outside the manifest's hashes.
    """
    return data_to_json(
        {
            "policy_class": SB3_REFUSAL,
            "observation_space": observation_space,
            "action_space": action_space,
            "verbose": 0,
        }
    ).encode()


def bundle_path(path: str | Path | io.BytesIO) -> Path | io.BytesIO:
    """
    The file to open for ``path``, as SB3's ``load`` finds a model: ``path`` itself, or ``path.zip`` when
    ``path`` has no suffix and does not exist but that does.
    """
    if isinstance(path, io.BytesIO):
        return path
    path = Path(path)
    with_zip = path.with_name(f"{path.name}.zip")
    return with_zip if not path.suffix and not path.exists() and with_zip.exists() else path


def model_bytes(model: BaseAlgorithm) -> bytes:
    """An SB3 model's zip, as bytes."""
    buffer = io.BytesIO()
    model.save(buffer)
    return buffer.getvalue()


def member_critics(
    manifest: BundleManifest, members: Mapping[str, bytes], where: str
) -> dict[str, TermCritic]:
    """
    Worker name -> the per-term critic inside its SB3 member, from a verified bundle (a ``BundleError`` for
    a critic over the limits or not one this library wrote).
    """
    critics = {}
    for name in manifest.worker_names:
        entry = manifest.workers[name]
        if entry.get("kind", "sb3") != "sb3":
            continue
        try:
            critic = read_term_critic(members[entry["file"]], f"{where}: {entry['file']}")
        except (ValueError, zipfile.BadZipFile) as error:
            raise BundleError(str(error)) from None
        if critic is not None:
            critics[name] = critic
    return critics


def member_model(
    members: Mapping[str, bytes],
    entry: Mapping[str, Any],
    *,
    name: str,
    trusted: bool,
    device: str,
    budget: LoadBudget,
) -> BaseAlgorithm:
    """
    The SB3 model of the member of manifest ``entry`` (its ``file`` and rebuild ``spec``), loaded as
    :meth:`~sb3_hddpg.hierarchy.hierarchy.Hierarchy.load` says; a :class:`BundleError` naming it otherwise.
    """
    data = io.BytesIO(members[entry["file"]])
    try:
        if trusted:
            budget.spend_model(name)
        return load_model(
            data, spec=entry.get("spec"), trusted=trusted, device=get_device(device), budget=budget
        )
    except ValueError as error:
        raise BundleError(f"{name}: cannot load {entry['file']}: {error}") from None


def checked_settings(
    manifest: BundleManifest,
    name: str,
    trusted: bool,
    allowed_env_ids: Sequence[str] | None,
    env: object = None,
) -> tuple[str, dict[str, Any], dict[str, Any]]:
    """
    A bundle's env id, env kwargs and selection settings, each checked (a :class:`BundleError` otherwise);
    each worker's reward terms among those the env declares (``env``, or the bundle's own env made once).
    """
    names = manifest.worker_names
    try:
        env_id = check_env_id(manifest.env_id, f"{name}: env_id", allowed_env_ids, trusted)
        env_kwargs = check_env_kwargs(
            env_id, manifest.env_kwargs, f"{name}: env_kwargs", allowed_env_ids, trusted
        )
        settings = check_selection_settings(manifest.selection, names, f"{name}: selection")
        if settings.get("manager_preferences") is not None:
            space = PreferenceSpace.from_json(
                settings["manager_preferences"], names, f"{name}: selection.manager_preferences"
            )
            settings["manager_preferences"] = space.to_json()
        terms = declared_terms(env, env_id, env_kwargs)
        rewards = settings.get("reward_terms", {})
        # a nested hierarchy without an entry is paid its own preference's mix of the terms
        paid = [n for n in names if n in rewards or manifest.workers[n].get("kind") != "hierarchy"]
        if terms is not None:
            check_reward_terms(rewards, paid, terms, f"{name}: selection.reward_terms")
    except ValueError as error:
        raise BundleError(str(error)) from None
    return env_id, env_kwargs, settings


def declared_terms(env: object, env_id: str, env_kwargs: Mapping[str, Any]) -> list[str] | None:
    """
    The reward terms ``env`` declares, or (``None`` or a VecEnv given) the bundle's env does, made once
    and closed; ``None`` when that env cannot be made here (a missing optional dependency): the wrapper
    checks the terms again when the hierarchy is given an env.
    """
    if isinstance(env, gym.Env):
        return _terms_of(env)
    key = (env_id, json.dumps(env_kwargs, sort_keys=True, default=str))
    if key not in _DECLARED_TERMS:
        try:
            made = gym.make(env_id, **env_kwargs)
        except Exception:  # any failure of a third-party env: the wrapper checks later, with an env
            return None
        try:
            _DECLARED_TERMS[key] = _terms_of(made)
        finally:
            made.close()
    return _DECLARED_TERMS[key]


def _terms_of(env: gym.Env) -> list[str] | None:
    try:
        return list(env_contract(env).reward_bounds)
    except ValueError:
        return None


#: The terms each (env id, env kwargs) declares, so that loading many bundles makes each env once.
_DECLARED_TERMS: dict[tuple[str, str], list[str] | None] = {}

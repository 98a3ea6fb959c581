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
from collections.abc import Mapping
from pathlib import Path

from stable_baselines3.common.base_class import BaseAlgorithm

from sb3_hddpg.artifacts.io import json_text
from sb3_hddpg.artifacts.limits import (
    MAX_JSON_BYTES,
    MAX_MODEL_FILE_BYTES,
    LoadBudget,
    check_zip_directory,
    parse_json,
    read_file_bytes,
    read_member,
)
from sb3_hddpg.artifacts.provenance import verify_sha256
from sb3_hddpg.artifacts.records import BundleManifest

#: The manifest's member name.
MANIFEST = "manifest.json"


class BundleError(ValueError):
    """A bundle that cannot be used: not a zip, truncated, tampered with, or inconsistent."""


def write_bundle(manifest: BundleManifest, members: Mapping[str, bytes]) -> bytes:
    """
    A bundle's zip bytes: the manifest and every member.

    :param manifest: the bundle's manifest (its members' files and hashes).
    :param members: member name -> its bytes.
    """
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
    Open a bundle and verify it: a readable zip with a manifest of a known schema, every member listed
    and present, every sha256 matching. Only the members the manifest lists are read, each within the
    limits of :mod:`sb3_hddpg.artifacts.limits` (size declared and actual, compression ratio, total bytes). Nested
    bundles are verified when they are loaded.

    :param path: the bundle or its bytes.
    :param budget: what the read may spend (default: a fresh budget).
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
                member = entry["file"]
                if member not in names:
                    raise BundleError(f"{name}: member {member!r} of {label!r} is missing")
                members[member] = read_member(archive, member, name, budget=budget)
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


def model_bytes(model: BaseAlgorithm) -> bytes:
    """An SB3 model's zip, as bytes."""
    buffer = io.BytesIO()
    model.save(buffer)
    return buffer.getvalue()

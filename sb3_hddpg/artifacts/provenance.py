"""Provenance: sha256 of files checked against their record, and the library versions a model came from."""

from __future__ import annotations

import hashlib
import io
import platform
from pathlib import Path

import gymnasium
import numpy as np
import pymunk
import stable_baselines3
import torch

from sb3_hddpg import __version__
from sb3_hddpg.artifacts.limits import MAX_MODEL_FILE_BYTES, check_run_file, read_file_bytes


def sha256_bytes(data: bytes) -> str:
    """The sha256 hex digest of some bytes."""
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: str | Path) -> str:
    """The sha256 hex digest of a file, read in 1 MiB blocks."""
    check_run_file(path)
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def verify_sha256(
    source: bytes | str | Path,
    expected: str,
    what: str,
    where: str = "",
    consequence: str = "",
    error: type[Exception] = ValueError,
) -> str:
    """
    Check bytes or a file against the sha256 its manifest recorded: the one hash check of sb3-hddpg.

    :param source: the bytes, or the path of the file.
    :param expected: the recorded hex digest.
    :param what: the file or member, for the message.
    :param where: the manifest's owner (a bundle's name...), prefixed to the message.
    :param consequence: what a mismatch means, appended to the message.
    :param error: the exception class to raise.
    :return: the digest (equal to ``expected``).
    """
    actual = sha256_bytes(source) if isinstance(source, bytes) else sha256_file(source)
    if actual != expected:
        raise error(
            (f"{where}: " if where else "")
            + f"sha256 of {str(what)!r} does not match its manifest (expected {expected[:12]}…, got {actual[:12]}…)"
            + (f": {consequence}" if consequence else "")
        )
    return actual


def read_verified(path: str | Path, expected: str, what: str | None = None) -> io.BytesIO:
    """
    A model file someone else may have made (regular, within :data:`MAX_MODEL_FILE_BYTES`), read once and
    checked against the sha256 its manifest recorded: the bytes returned are the bytes hashed.

    :param path: the file.
    :param expected: the recorded hex digest.
    :param what: how messages name it (default: the path).
    :return: the verified bytes, ready for a loader.
    """
    data = read_file_bytes(path, MAX_MODEL_FILE_BYTES, what)
    verify_sha256(data, expected, what or str(path))
    source = io.BytesIO(data)
    source.name = str(path)  # type: ignore[attr-defined]  # how loaders' messages name it
    return source


def library_versions() -> dict[str, str]:
    """Versions of what a trained model depends on, for manifests."""
    return {
        "sb3_hddpg": __version__,
        "stable_baselines3": stable_baselines3.__version__,
        "gymnasium": gymnasium.__version__,
        "pymunk": pymunk.version,
        "torch": torch.__version__,
        "numpy": np.__version__,
        "python": platform.python_version(),
    }

"""Provenance: the sha256 of files and bytes, the one check of a hash against its record, library versions."""

from __future__ import annotations

import hashlib
import platform
from pathlib import Path

import gymnasium
import numpy as np
import pymunk
import stable_baselines3
import torch

from sb3_hddpg import __version__


def sha256_bytes(data: bytes) -> str:
    """The sha256 hex digest of some bytes."""
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: str | Path) -> str:
    """The sha256 hex digest of a file, read in 1 MiB blocks."""
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

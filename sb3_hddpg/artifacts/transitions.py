"""A worker's stored transitions with their normalised reward terms, for its critic and for warm starts."""

from __future__ import annotations

import io
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sb3_hddpg.artifacts.io import atomic_write
from sb3_hddpg.artifacts.limits import MAX_BUFFER_BYTES, LimitError, brief, check_run_file

#: A worker's transitions file beside its zip: ``<name>.transitions.npz``.
TRANSITIONS_SUFFIX = ".transitions.npz"
FIELDS = ("obs", "actions", "next_obs", "terms", "continues")  #: The arrays of a transitions file, in order.


@dataclass(frozen=True)
class Transitions:
    """
    Stored transitions with their normalised terms, flat (one row per env step).

    :param obs: observations, ``(n, obs_dim)``.
    :param actions: the actions as SB3's replay buffer stores them (scaled to [-1, 1], or indices).
    :param next_obs: the next observations.
    :param terms: normalised terms, ``(n, n_terms)``.
    :param continues: ``1 - done`` (a time-limit truncation continues).
    """

    obs: np.ndarray
    actions: np.ndarray
    next_obs: np.ndarray
    terms: np.ndarray
    continues: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.obs)
        if any(len(getattr(self, name)) != n for name in FIELDS) or self.terms.ndim != 2:
            raise ValueError(f"Expected {n} rows in every array of the transitions, with terms as a matrix")

    def __len__(self) -> int:
        return len(self.obs)

    def last(self, count: int) -> Transitions:
        """The last ``count`` transitions (all when there are fewer)."""
        return Transitions(*(getattr(self, name)[-count:] for name in FIELDS))

    def save(self, path: str | Path) -> Path:
        """Write them atomically as a plain ``.npz`` (no pickled objects)."""
        buffer = io.BytesIO()
        np.savez_compressed(buffer, **{name: getattr(self, name) for name in FIELDS})
        data = buffer.getvalue()
        return atomic_write(path, lambda tmp: tmp.write_bytes(data))

    @classmethod
    def load(cls, path: str | Path) -> Transitions:
        """Read a transitions file: plain numeric arrays within :data:`MAX_BUFFER_BYTES`, else a ``LimitError``."""
        check_run_file(path)
        try:
            with zipfile.ZipFile(path) as archive:
                size = sum(info.file_size for info in archive.infolist())
            if size > MAX_BUFFER_BYTES:
                raise LimitError(
                    f"{path}: {size} bytes of transitions, over the {MAX_BUFFER_BYTES}-byte limit"
                )
            with np.load(path, allow_pickle=False) as npz:
                if sorted(npz.files) != sorted(FIELDS):
                    raise LimitError(f"{path}: expected the arrays {list(FIELDS)}, got {brief(npz.files)}")
                arrays = [npz[name] for name in FIELDS]
        except (OSError, ValueError, zipfile.BadZipFile, EOFError) as error:
            if isinstance(error, LimitError):
                raise
            raise LimitError(f"{path}: not a transitions file: {brief(str(error))}") from None
        if not all(np.issubdtype(a.dtype, np.number) for a in arrays):
            raise LimitError(f"{path}: expected numeric arrays")
        try:
            return cls(*arrays)
        except ValueError as error:
            raise LimitError(f"{path}: {error}") from None

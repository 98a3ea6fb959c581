"""
Load shared SB3 model zips without running code from them: the model is rebuilt from its spec and only the
tensors are taken from the zip (``DDPG.load`` would unpickle the ``data`` entry, running any code in it).
"""

from __future__ import annotations

import io
import os
import re
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm

from sb3_hddpg.algorithms import REGISTRY, Algorithm
from sb3_hddpg.artifacts.limits import SBX_SNIFF_BYTES, LoadBudget, brief, check_run_file
from sb3_hddpg.artifacts.spec import ALGOS, build_from_spec
from sb3_hddpg.artifacts.weights import SafeLoadError, apply_weights, read_weights

__all__ = ["SafeLoadError", "load_model", "load_model_safely"]

#: What in a zip's ``data`` member says that SBX saved it.
_SBX_POLICY_CLASS = re.compile(r'"policy_class":\s*\{[^{}]*?"__module__":\s*"sbx\.')


def load_model_safely(
    path: str | os.PathLike[str] | io.BytesIO,
    spec: Mapping[str, Any],
    device: th.device | str = "cpu",
    budget: LoadBudget | None = None,
) -> BaseAlgorithm:
    """
    Rebuild a model from ``spec`` and load only its tensors from the SB3 zip at ``path``
    (``torch.load(weights_only=True)``). Optimizer states are fresh and training counters start at zero.

    :param path: the model zip, or its bytes (a member of a bundle).
    :param spec: the description from :func:`~sb3_hddpg.artifacts.spec.model_spec`.
    :param device: torch device to build the model on and map the tensors to.
    :param budget: the bytes and models a whole load may still spend (a bundle's; default: a fresh one).
    :return: the model, ready for ``predict``; a :class:`SafeLoadError` for an invalid spec or file, sizes over
        the limits or weights that do not match the spec, a ``FileNotFoundError`` for a missing file.
    """
    path_str = getattr(path, "name", "<bytes>") if isinstance(path, io.BytesIO) else os.fspath(path)
    budget = budget if budget is not None else LoadBudget()
    try:
        budget.spend_model(path_str)
        model = build_from_spec(spec, device)
    except SafeLoadError:
        raise
    except ValueError as e:
        raise SafeLoadError(f"{path_str}: invalid spec: {e}") from e
    if not isinstance(path, io.BytesIO) and not Path(path_str).is_file():
        raise FileNotFoundError(path_str)
    policy_state, variables = read_weights(path, path_str, device, budget)
    apply_weights(model, policy_state, variables, path_str, device)
    return model


def load_model(
    path: str | os.PathLike[str] | io.BytesIO,
    spec: Mapping[str, Any] | None = None,
    trusted: bool = False,
    *,
    algorithm: str | None = None,
    device: th.device | str = "cpu",
    budget: LoadBudget | None = None,
) -> BaseAlgorithm:
    """
    Load a model zip: safely from a spec by default, or with SB3's full loader on explicit opt-in.

    :param path: the model zip.
    :param spec: the description from :func:`~sb3_hddpg.artifacts.spec.model_spec`; required unless ``trusted``.
    :param trusted: ``True`` runs the ordinary ``ALGO.load(path)``, which unpickles the zip's ``data`` entry
        and so runs any code in it: only for files you made yourself or fully trust.
    :param algorithm: with ``trusted`` and no ``spec``, the algorithm (``"ddpg"``, ``"CrossQ"``..., any case).
    :param device: torch device.
    :param budget: see :func:`load_model_safely` (the safe path only).
    :return: the loaded model; a ``ValueError`` without a spec or ``trusted``, or for an unknown algorithm.
    """
    if not isinstance(path, io.BytesIO):
        check_run_file(path)  # SB3's loader and zipfile open the path themselves
    if not trusted:
        if spec is None:
            raise ValueError(
                f"{getattr(path, 'name', '<bytes>') if isinstance(path, io.BytesIO) else os.fspath(path)}: a model spec is required to load without running code from the file; "
                "pass spec=... or, only for a file you trust, trusted=True"
            )
        return load_model_safely(path, spec, device=device, budget=budget)
    name = algorithm if algorithm is not None else (spec or {}).get("algorithm")
    record = next((r for r in REGISTRY.values() if isinstance(name, str) and name.lower() == r.name), None)
    if record is None:
        raise ValueError(f"algorithm: unknown algorithm {brief(name)}; expected one of {sorted(ALGOS)}")
    source = path if isinstance(path, io.BytesIO) else Path(path)
    if _saved_by_sbx(source):
        return _load_sbx(source, record)
    return record.cls.load(source, device=device)


def _saved_by_sbx(source: Path | io.BytesIO) -> bool:
    """Whether ``data``'s first entry, ``policy_class``, names an ``sbx.`` module (``False``: unknown)."""
    try:
        with zipfile.ZipFile(source) as archive, archive.open("data") as member:
            head = member.read(SBX_SNIFF_BYTES).decode("utf-8", "replace")
    except (OSError, ValueError, zipfile.BadZipFile, KeyError):
        return False
    finally:
        if isinstance(source, io.BytesIO):
            source.seek(0)
    return _SBX_POLICY_CLASS.search(head) is not None


def _load_sbx(source: Path | io.BytesIO, record: Algorithm) -> BaseAlgorithm:
    """SBX's own loader for a zip SBX saved (SB3's cannot rebuild SBX's JAX policy classes)."""
    try:
        import sbx  # lazy: JAX is an optional extra, and importing it costs over a second
    except ImportError:
        raise ValueError(
            f'{brief(str(source))}: saved by SBX (JAX), which is not installed: pip install "sb3-hddpg[fast]"'
        ) from None
    if record.sbx is None:
        raise ValueError(f"algorithm: SBX does not train {record.class_name} here; the file was saved by SBX")
    algo_class = getattr(sbx, record.sbx)  # a name from our own registry, never from the file
    model: BaseAlgorithm = algo_class.load(source)
    return model

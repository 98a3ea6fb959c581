"""The tensors of a model zip, read without running code, checked against the spec-built model, put in it."""

from __future__ import annotations

import io
import os
import zipfile
from collections.abc import Mapping

import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.save_util import recursive_getattr

from sb3_hddpg.artifacts.limits import MAX_MEMBER_BYTES, LoadBudget, brief, check_zip_directory, read_member

POLICY_MEMBER = "policy.pth"
VARIABLES_MEMBER = "pytorch_variables.pth"


class SafeLoadError(ValueError):
    """A model zip or its spec refused by :func:`~sb3_hddpg.artifacts.safe_load.load_model_safely`."""


def _read_tensors(
    archive: zipfile.ZipFile, name: str, path: str, device: th.device | str, budget: LoadBudget
) -> dict[str, th.Tensor]:
    """The member ``name`` of a model zip: within the limits, and a mapping of names to tensors only."""
    try:
        raw = read_member(archive, name, path, limit=MAX_MEMBER_BYTES, budget=budget)
    except ValueError as e:
        raise SafeLoadError(str(e)) from None
    # weights_only=True: torch's restricted unpickler (tensors and plain containers only), as SB3 uses it.
    try:
        obj = th.load(io.BytesIO(raw), map_location=device, weights_only=True)
    except Exception as e:  # torch raises UnpicklingError, RuntimeError, ... depending on the damage
        raise SafeLoadError(f"{path}: member {brief(name)} is not a plain tensor file: {e}") from e
    if not isinstance(obj, Mapping):
        raise SafeLoadError(
            f"{path}: member {brief(name)} holds {type(obj).__name__}, expected a dict of tensors"
        )
    for key, value in obj.items():
        if not isinstance(key, str) or not (value is None or isinstance(value, th.Tensor)):
            raise SafeLoadError(
                f"{path}: member {brief(name)} entry {brief(key)} is {type(value).__name__}, not a tensor"
            )
    return dict(obj)


def _check_state_dict(
    expected: Mapping[str, th.Tensor], found: Mapping[str, th.Tensor], path: str, name: str
) -> None:
    """Raise SafeLoadError naming the first key whose presence or shape differs between spec and file."""

    def shape(tensors: Mapping[str, th.Tensor | None], key: str) -> str:
        if (tensor := tensors.get(key)) is not None:
            return f"shape {list(tensor.shape)}"
        return "None" if key in tensors else "no such key"

    for key in dict.fromkeys([*expected, *found]):
        if shape(found, key) != shape(expected, key):
            raise SafeLoadError(
                f"{path}: {brief(name)} key {brief(key)}: {shape(found, key)} in the file, {shape(expected, key)} "
                "in the spec-built model; the spec does not describe this model"
            )


def read_weights(
    source: str | os.PathLike[str] | io.BytesIO, path: str, device: th.device | str, budget: LoadBudget
) -> tuple[dict[str, th.Tensor], dict[str, th.Tensor]]:
    """
    The policy's state dict (``policy.pth``, required) and the variables (``pytorch_variables.pth``, SAC's
    entropy coefficient) of a model zip, the only members opened.

    :param source: the zip, or its bytes.
    :param path: how messages name it.
    :param device: where the tensors are mapped.
    :param budget: the bytes the whole load may still read.
    :return: the state dict and the variables; a :class:`SafeLoadError` for anything but plain tensors
        within the limits.
    """
    try:
        archive = zipfile.ZipFile(source)
    except zipfile.BadZipFile as e:
        raise SafeLoadError(f"{path}: not a readable zip file (truncated or not a model?): {e}") from e
    with archive:
        try:
            names = {info.filename for info in check_zip_directory(archive, path)}
        except ValueError as e:
            raise SafeLoadError(str(e)) from None
        if POLICY_MEMBER not in names:
            raise SafeLoadError(f"{path}: no {POLICY_MEMBER!r} in the zip (members: {brief(sorted(names))})")
        policy_state = _read_tensors(archive, POLICY_MEMBER, path, device, budget)
        variables: dict[str, th.Tensor] = {}
        if VARIABLES_MEMBER in names:
            variables = _read_tensors(archive, VARIABLES_MEMBER, path, device, budget)
    return policy_state, variables


def apply_weights(
    model: BaseAlgorithm,
    policy_state: Mapping[str, th.Tensor],
    variables: Mapping[str, th.Tensor | None],
    path: str,
    device: th.device | str,
) -> None:
    """
    Put the tensors :func:`read_weights` read into the model :func:`~sb3_hddpg.artifacts.spec.build_from_spec`
    built, after checking every key and shape (a :class:`SafeLoadError` naming ``path`` otherwise).

    :param model: the spec-built model.
    :param policy_state: the policy's state dict.
    :param variables: the other tensors (only those this model declares are accepted).
    :param path: how messages name the file.
    :param device: where the tensors go.
    """
    # Compare before load_state_dict so the error names the key and both shapes instead of torch's long list.
    _check_state_dict(model.policy.state_dict(), policy_state, path, POLICY_MEMBER)
    model.policy.load_state_dict(policy_state, strict=True)

    # Only the variables this model declares, so the names from the file never pick the attribute set.
    _, variable_names = model._get_torch_save_params()
    expected_vars = {name: recursive_getattr(model, name) for name in variable_names}
    expected_vars = {name: value for name, value in expected_vars.items() if value is not None}
    found_vars = {name: value for name, value in variables.items() if value is not None}
    if expected_vars or found_vars:
        _check_state_dict(expected_vars, found_vars, path, VARIABLES_MEMBER)
    for name, value in found_vars.items():
        # Same as SB3's load: set .data so optimizers keep referencing the same tensor object.
        recursive_getattr(model, name).data = value.data.to(device)

    if model.use_sde:
        model.policy.reset_noise()  # type: ignore[operator]

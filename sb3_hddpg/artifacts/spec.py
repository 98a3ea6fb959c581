"""
The model spec: a strictly validated JSON description of an SB3 model, enough to rebuild it without unpickling
(every name through an allow-list, every size against :mod:`sb3_hddpg.artifacts.limits`).
"""

from __future__ import annotations

import functools
import math
import re
from collections.abc import Callable, Collection, Mapping
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.torch_layers import FlattenExtractor

from sb3_hddpg.algorithms import ACTIVATIONS, REGISTRY, Algorithm
from sb3_hddpg.artifacts.limits import (
    MAX_CRITICS,
    MAX_DISCRETE_ACTIONS,
    MAX_DISCRETE_START,
    MAX_QUANTILES,
    MAX_RENORM_WARMUP_STEPS,
    MAX_SPACE_SIZE,
    MAX_SPEC_LAYER_WIDTH,
    MAX_SPEC_LAYERS,
    brief,
)
from sb3_hddpg.artifacts.network_limits import check_buffer_size, check_network_size

SPEC_FORMAT = "sb3-hddpg/model-spec"
SPEC_VERSION = 1

#: Algorithms that can be rebuilt from a spec, by the class name a spec records (the registry's records).
SPEC_ALGORITHMS: dict[str, Algorithm] = {record.class_name: record for record in REGISTRY.values()}
#: The same, to their classes.
ALGOS: dict[str, type[BaseAlgorithm]] = {name: record.cls for name, record in SPEC_ALGORITHMS.items()}

#: Optimizers accepted in ``policy_kwargs["optimizer_class"]``. Only matters for further training.
OPTIMIZERS: dict[str, type[th.optim.Optimizer]] = {
    cls.__name__: cls for cls in (th.optim.Adam, th.optim.AdamW, th.optim.SGD, th.optim.RMSprop)
}

DTYPES = frozenset({"bool", "float16", "float32", "float64"})  #: Box dtypes accepted in a spec (numpy names).
DTYPES |= {f"{sign}int{bits}" for sign in ("", "u") for bits in (8, 16, 32, 64)}
#: The keys of a spec.
_SPEC_KEYS = frozenset(
    [
        "format",
        "version",
        "algorithm",
        "policy",
        "observation_space",
        "action_space",
        "policy_kwargs",
        "hyperparameters",
        "learning_rate_constant",
    ]
)
_ENT_COEF_AUTO = re.compile(r"^auto(_[0-9.eE+-]+)?$")

# Strict converters: ``bool`` is a subclass of ``int``, so it is excluded explicitly everywhere.


def _as_float(key: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{key}: expected a number, got {brief(value)}")
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{key}: expected a finite number, got {brief(value)}")
    return value


def _as_int(key: str, value: object, minimum: float = -math.inf, maximum: float = math.inf) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{key}: expected an integer, got {brief(value)}")
    if not minimum <= value <= maximum:
        raise ValueError(f"{key}: expected an integer in [{minimum}, {maximum}], got {brief(value)}")
    return int(value)


def _as_bool(key: str, value: object) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{key}: expected true/false, got {brief(value)}")
    return bool(value)


def _as_ent_coef(key: str, value: object) -> float | str:
    """SAC/TQC's ``ent_coef``: a float, ``"auto"`` or ``"auto_<initial value>"``."""
    if isinstance(value, str):
        if not _ENT_COEF_AUTO.match(value):
            raise ValueError(f"{key}: expected a number, 'auto' or 'auto_<float>', got {brief(value)}")
        return value
    return _as_float(key, value)


#: A hyperparameter's kind (:attr:`~sb3_hddpg.algorithms.Algorithm.hyperparameters`) -> its converter.
_CONVERTERS: dict[str, Callable[[str, object], float | int | bool | str]] = {
    "float": _as_float,
    "int": _as_int,
    "bool": _as_bool,
    "ent_coef": _as_ent_coef,
}


#: One optimizer keyword argument of a spec: a number, a flag, ``None`` (torch picks) or numbers (betas).
OptimizerSetting = float | bool | None | list[float] | tuple[float, ...]


def _bounds_to_json(array: np.ndarray) -> object:
    # Strict JSON has no Infinity/NaN, and Box bounds often are: those are written as strings ("inf"...).
    return np.where(np.isfinite(array), array.astype(object), array.astype(str)).tolist()


def _bounds_from_json(key: str, value: object, shape: tuple[int, ...], dtype: np.dtype) -> np.ndarray:
    def decode(x: object) -> object:
        if isinstance(x, list):
            return [decode(v) for v in x]
        if isinstance(x, str):
            if x not in ("inf", "-inf", "nan"):
                raise ValueError(f"{key}: unexpected string {brief(x)} in bounds")
            return float(x)
        if isinstance(x, bool) or not isinstance(x, (int, float)):
            raise ValueError(f"{key}: bounds must be numbers, got {brief(x)}")
        return x

    if not isinstance(value, list):
        raise ValueError(f"{key}: expected a (nested) list, got {brief(value)}")
    array = np.asarray(decode(value), dtype=np.float64 if np.issubdtype(dtype, np.floating) else None)
    if array.shape != shape:
        raise ValueError(f"{key}: bounds have shape {list(array.shape)}, expected {list(shape)}")
    return array.astype(dtype)


def _space_to_json(space: spaces.Space, what: str) -> dict[str, object]:
    if type(space) is spaces.Discrete:
        return {"type": "Discrete", "n": int(space.n), "start": int(space.start)}
    if type(space) is not spaces.Box:
        raise ValueError(
            f"{what}: unsupported space {space!r}; only gymnasium.spaces.Box and Discrete can be described"
        )
    dtype = np.dtype(space.dtype).name
    if dtype not in DTYPES:
        raise ValueError(f"{what}: unsupported Box dtype {dtype!r}")
    return {
        "type": "Box",
        "low": _bounds_to_json(space.low),
        "high": _bounds_to_json(space.high),
        "shape": list(space.shape),
        "dtype": dtype,
    }


def _check_keys(value: Mapping[str, object], allowed: Collection[str], what: str) -> None:
    unknown = sorted(map(str, set(value) - set(allowed)))
    if unknown:
        raise ValueError(f"{what}: unknown key {brief(unknown[0])}")


def _discrete_from_json(value: Mapping[str, object], what: str) -> spaces.Discrete:
    _check_keys(value, ("type", "n", "start"), f"{what} (a Discrete space)")
    n = _as_int(f"{what}.n", value.get("n"), minimum=1, maximum=MAX_DISCRETE_ACTIONS)
    start = _as_int(
        f"{what}.start", value.get("start", 0), minimum=-MAX_DISCRETE_START, maximum=MAX_DISCRETE_START
    )
    return spaces.Discrete(n, start=start)


def _space_from_json(value: object, what: str) -> spaces.Box | spaces.Discrete:
    if not isinstance(value, Mapping):
        raise ValueError(f"{what}: expected an object, got {brief(value)}")
    if value.get("type") == "Discrete":
        return _discrete_from_json(value, what)
    if value.get("type") != "Box":
        raise ValueError(
            f"{what}: unsupported space type {brief(value.get('type'))}; only 'Box' and 'Discrete' are supported"
        )
    _check_keys(value, ("type", "low", "high", "shape", "dtype"), what)
    dtype_name = value.get("dtype")
    if dtype_name not in DTYPES:
        raise ValueError(f"{what}.dtype: unsupported dtype {brief(dtype_name)}")
    dtype = np.dtype(dtype_name)
    raw_shape = value.get("shape")
    if not isinstance(raw_shape, list):
        raise ValueError(f"{what}.shape: expected a list of integers, got {brief(raw_shape)}")
    if not 1 <= len(raw_shape) <= 8:
        raise ValueError(f"{what}.shape: expected 1 to 8 dimensions, got {brief(raw_shape)}")
    # Dimensions of 0 make a space SB3 cannot act in; the product is bounded before numpy allocates.
    shape = tuple(_as_int(f"{what}.shape", dim, minimum=1, maximum=MAX_SPACE_SIZE) for dim in raw_shape)
    if math.prod(shape) > MAX_SPACE_SIZE:
        raise ValueError(f"{what}.shape: {list(shape)} has more than {MAX_SPACE_SIZE} elements")
    low = _bounds_from_json(f"{what}.low", value.get("low"), shape, dtype)
    high = _bounds_from_json(f"{what}.high", value.get("high"), shape, dtype)
    return spaces.Box(low=low, high=high, shape=shape, dtype=dtype)


def _layers(key: str, value: object) -> list[int]:
    if not isinstance(value, (list, tuple)):
        raise ValueError(f"{key}: expected a list of layer sizes, got {brief(value)}")
    if len(value) > MAX_SPEC_LAYERS:
        raise ValueError(f"{key}: {len(value)} layers is more than the limit of {MAX_SPEC_LAYERS}")
    return [_as_int(key, size, minimum=1, maximum=MAX_SPEC_LAYER_WIDTH) for size in value]


def _net_arch(value: object) -> list[int] | dict[str, list[int]]:
    if isinstance(value, Mapping):
        _check_keys(value, ("pi", "qf", "vf"), "policy_kwargs.net_arch")
        return {name: _layers(f"policy_kwargs.net_arch.{name}", layers) for name, layers in value.items()}
    return _layers("policy_kwargs.net_arch", value)


def _optimizer_kwargs(value: object, to_json: bool) -> dict[str, OptimizerSetting]:
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise ValueError(f"policy_kwargs.optimizer_kwargs: expected a dict, got {brief(value)}")
    out: dict[str, OptimizerSetting] = {}
    for name, item in value.items():
        key = f"policy_kwargs.optimizer_kwargs.{name}"
        if not isinstance(name, str):
            raise ValueError(f"{key}: keys must be strings")
        if item is None:
            out[name] = None  # e.g. foreach=None, torch's "pick for me"
        elif isinstance(item, (bool, np.bool_)):
            out[name] = bool(item)
        elif isinstance(item, (list, tuple)):
            # e.g. Adam's betas: a list in JSON, a tuple for torch.
            numbers = [_as_float(key, x) for x in item]
            out[name] = numbers if to_json else tuple(numbers)
        else:
            out[name] = _as_float(key, item)
    return out


#: The ``policy_kwargs`` keys whose values are classes, each with the classes a spec may name (by their name).
_CLASS_KWARGS: dict[str, Mapping[str, type]] = {
    "activation_fn": ACTIVATIONS,
    "optimizer_class": OPTIMIZERS,
    "features_extractor_class": {"FlattenExtractor": FlattenExtractor},
}


def _policy_kwargs(algo: str, value: object, to_json: bool) -> dict[str, object]:
    """``policy_kwargs`` checked and converted from a model's to a spec's (``to_json``: classes by name) or back."""
    if not isinstance(value, Mapping):
        raise ValueError(f"policy_kwargs: expected an object, got {brief(value)}")
    out: dict[str, object] = {}
    for key, item in value.items():
        if key == "use_sde" and to_json:
            continue  # recorded as a hyperparameter (sb3_hddpg.algorithms)
        if key not in SPEC_ALGORITHMS[algo].policy_kwargs:
            raise ValueError(
                f"policy_kwargs.{key}: not supported by the safe model spec (value {brief(item)})"
            )
        if key == "features_extractor_kwargs":
            if not to_json:
                raise ValueError("policy_kwargs.features_extractor_kwargs: not supported in a spec")
            if item:  # a model's empty ones are SB3's default, which a spec leaves out
                raise ValueError(f"policy_kwargs.features_extractor_kwargs: must be empty, got {brief(item)}")
        elif key in _CLASS_KWARGS:
            out[key] = _class_name(key, item) if to_json else _class_named(key, item)
        elif key == "optimizer_kwargs":
            out[key] = _optimizer_kwargs(item, to_json=to_json)
        elif key == "net_arch":
            out[key] = _net_arch(item)
        else:
            out[key] = _POLICY_SCALARS[key](f"policy_kwargs.{key}", item)
    return out


def _class_name(key: str, value: object) -> str:
    """The name a spec records for a class-valued key: the class must be exactly the table's."""
    table = _CLASS_KWARGS[key]
    cls = table.get(getattr(value, "__name__", ""))
    if cls is None or cls is not value:
        raise ValueError(f"policy_kwargs.{key}: {brief(value)} is not one of {sorted(table)}")
    return cls.__name__


def _class_named(key: str, name: object) -> type:
    """The class a spec's name stands for, looked up in the table only (a spec is data, not an import)."""
    table = _CLASS_KWARGS[key]
    if not isinstance(name, str) or name not in table:
        raise ValueError(f"policy_kwargs.{key}: {brief(name)} is not one of {sorted(table)}")
    return table[name]


#: The scalar ``policy_kwargs`` a record may allow -> their converter.
_POLICY_SCALARS: dict[str, Callable[[str, object], bool | int | float]] = {
    **dict.fromkeys(
        ("share_features_extractor", "normalize_images", "use_expln", "ortho_init", "full_std", "batch_norm"),
        _as_bool,
    ),
    **dict.fromkeys(("log_std_init", "clip_mean", "batch_norm_momentum", "batch_norm_eps"), _as_float),
    "n_critics": functools.partial(_as_int, minimum=1, maximum=MAX_CRITICS),
    "n_quantiles": functools.partial(_as_int, minimum=1, maximum=MAX_QUANTILES),
    "renorm_warmup_steps": functools.partial(_as_int, minimum=1, maximum=MAX_RENORM_WARMUP_STEPS),
}


def model_spec(model: BaseAlgorithm) -> dict[str, object]:
    """
    Describe a live SB3 model as plain JSON, enough to rebuild it without unpickling anything.

    :param model: a model of exactly a registered algorithm's class (:data:`sb3_hddpg.algorithms.REGISTRY`)
        with ``MlpPolicy`` and ``Box`` or ``Discrete`` spaces.
    :return: a dict of strict JSON values.
    :raises ValueError: for any part of the model the spec cannot describe safely (the message names it).
    """
    algo = next((name for name, cls in ALGOS.items() if type(model) is cls), None)
    if algo is None:
        raise ValueError(f"algorithm: {type(model).__qualname__} is not one of {sorted(ALGOS)}")
    if model.policy_class is not type(model).policy_aliases["MlpPolicy"]:
        raise ValueError(f"policy: only MlpPolicy is supported, got {model.policy_class!r}")

    learning_rate = model.learning_rate
    learning_rate_constant = isinstance(learning_rate, (int, float)) and not isinstance(learning_rate, bool)
    if not learning_rate_constant:
        # A schedule is code, which the spec cannot carry: record its current value instead and say so.
        learning_rate = model.lr_schedule(model._current_progress_remaining)
    hparams = {
        key: _CONVERTERS[kind](key, learning_rate if key == "learning_rate" else getattr(model, key))
        for key, kind in SPEC_ALGORITHMS[algo].hyperparameters.items()
    }
    return {
        "format": SPEC_FORMAT,
        "version": SPEC_VERSION,
        "algorithm": algo,
        "policy": "MlpPolicy",
        "observation_space": _space_to_json(model.observation_space, "observation_space"),
        "action_space": _space_to_json(model.action_space, "action_space"),
        "policy_kwargs": _policy_kwargs(algo, model.policy_kwargs, to_json=True),
        "hyperparameters": hparams,
        "learning_rate_constant": learning_rate_constant,
    }


def build_from_spec(spec: object, device: th.device | str) -> BaseAlgorithm:
    """Validate ``spec`` (untrusted JSON) and build a fresh, untrained model from it; raises ValueError."""
    if not isinstance(spec, Mapping):
        raise ValueError(f"spec: expected an object, got {type(spec).__name__}")
    if spec.get("format") != SPEC_FORMAT or spec.get("version") != SPEC_VERSION:
        raise ValueError(
            f"spec: format/version {brief(spec.get('format'))}/{brief(spec.get('version'))} is not {SPEC_FORMAT!r}/{SPEC_VERSION}"
        )
    _check_keys(spec, _SPEC_KEYS, "spec")
    algo = spec.get("algorithm")
    if not isinstance(algo, str) or algo not in ALGOS:
        raise ValueError(f"algorithm: unknown algorithm {brief(algo)}; expected one of {sorted(ALGOS)}")
    if spec.get("policy") != "MlpPolicy":
        raise ValueError(f"policy: only 'MlpPolicy' is supported, got {brief(spec.get('policy'))}")

    observation_space = _space_from_json(spec.get("observation_space"), "observation_space")
    action_space = _space_from_json(spec.get("action_space"), "action_space")
    _check_action_space(SPEC_ALGORITHMS[algo], action_space)

    policy_kwargs = _policy_kwargs(algo, spec.get("policy_kwargs", {}), to_json=False)

    raw_hparams = spec.get("hyperparameters")
    if not isinstance(raw_hparams, Mapping):
        raise ValueError(f"hyperparameters: expected an object, got {brief(raw_hparams)}")
    record = SPEC_ALGORITHMS[algo]
    kinds = record.hyperparameters
    _check_keys(raw_hparams, kinds, f"hyperparameters (of {algo})")
    hparams = {
        key: _CONVERTERS[kinds[key]](f"hyperparameters.{key}", raw_hparams[key])
        for key in kinds
        if key in raw_hparams
    }
    obs_dim, act_dim = _flat_size(observation_space), _flat_size(action_space)
    # Each field has its own cap, but their product can still be tens of GB: bound the totals too.
    check_network_size(
        algo, policy_kwargs, obs_dim, act_dim, "policy_kwargs", MAX_SPEC_LAYERS, MAX_SPEC_LAYER_WIDTH
    )
    # A replay buffer holds buffer_size transitions, a rollout buffer n_steps: both are allocated at build.
    for key in ("buffer_size", "n_steps"):
        if key in hparams:
            check_buffer_size(hparams[key], obs_dim, act_dim, f"hyperparameters.{key}")
    if record.target_entropy:
        # "auto" would make _setup_model read self.env.action_space, and we have no env.
        target_entropy = hparams.get("target_entropy")
        hparams["target_entropy"] = float(-act_dim) if target_entropy is None else target_entropy

    return build_without_env(ALGOS[algo], observation_space, action_space, hparams, policy_kwargs, device)


def build_without_env(
    cls: type[BaseAlgorithm],
    observation_space: spaces.Space,
    action_space: spaces.Space,
    hparams: Mapping[str, Any],
    policy_kwargs: Mapping[str, object],
    device: th.device | str = "cpu",
    seed: int | None = None,
) -> BaseAlgorithm:
    """
    A fresh ``MlpPolicy`` model of ``cls`` with no env, built as ``BaseAlgorithm.load`` builds one: the spaces
    (and ``n_envs``) set by hand before the networks are created.

    :param cls: the SB3 algorithm class.
    :param observation_space: the policy's observation space.
    :param action_space: its action space.
    :param hparams: the algorithm's constructor arguments.
    :param policy_kwargs: the policy's.
    :param device: where the networks live.
    :param seed: the model's seed (``None``: unseeded).
    """
    model = cls(  # type: ignore[call-arg]  # every concrete algorithm takes _init_setup_model
        "MlpPolicy",
        env=None,  # type: ignore[arg-type]
        policy_kwargs=dict(policy_kwargs),
        device=device,
        seed=seed,
        _init_setup_model=False,
        **hparams,
    )
    model.observation_space = observation_space
    model.action_space = action_space
    model.n_envs = 1
    model._setup_model()
    return model


def _flat_size(space: spaces.Space) -> int:
    """A Box's elements, a Discrete's actions: what sizes the networks' inputs and outputs."""
    return int(space.n) if isinstance(space, spaces.Discrete) else math.prod(space.shape or ())


def _check_action_space(record: Algorithm, action_space: spaces.Space) -> None:
    """SB3 checks an action space against its algorithm when an env is given; we build without one."""
    if not record.takes(action_space):
        raise ValueError(
            f"action_space: {record.class_name} acts in {sorted(record.action_spaces)}, "
            f"got {type(action_space).__name__}"
        )
    if isinstance(action_space, spaces.Box):
        if not np.issubdtype(action_space.dtype, np.floating):
            raise ValueError(f"action_space: expected a float Box, got dtype {action_space.dtype}")
        if not (np.all(np.isfinite(action_space.low)) and np.all(np.isfinite(action_space.high))):
            raise ValueError("action_space: bounds must be finite")

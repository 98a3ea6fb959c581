"""
SBX models beside their SB3 twins: SB3 constructor arguments translated into SBX's, an SBX model built from
the weights SB3 draws for the same seed, the jitted functions models of one architecture share, and the
export of a trained SBX model to an ordinary SB3 model of the same algorithm.

Imported only where an SBX model is built or exported (:mod:`sb3_hddpg.training.models`); nothing here imports
``jax`` or ``sbx`` at import time.
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Mapping
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm

from sb3_hddpg.algorithms import REGISTRY, Algorithm, algorithm
from sb3_hddpg.artifacts.spec import build_without_env
from sb3_hddpg.training.backends import SBX_ALGOS, BackendError, sbx_class, scheduled_adam
from sb3_hddpg.training.sbx_weights import layout_of, sbx_to_state_dict, state_dict_to_sbx


def _sbx_record(model: object) -> Algorithm:
    import sbx  # lazily: optional, and jax is slow to import (only SBX models get here)

    # The first registered class in the model's MRO, the most derived (SBX's DDPG is a TD3; a model under the
    # action penalty is a subclass of its algorithm).
    records = {getattr(sbx, record.sbx): record for record in REGISTRY.values() if record.sbx is not None}
    found = next((records[cls] for cls in type(model).__mro__ if cls in records), None)
    if found is None:
        raise BackendError(
            f"Cannot export {type(model).__qualname__} to SB3; exportable: {sorted(SBX_ALGOS)}"
        )
    return found


def _activation_pairs() -> list[tuple[type[th.nn.Module], Any]]:
    """(torch activation class, the flax function computing the same) for every activation configs may name."""
    import flax.linen as fnn  # lazily: optional (the `fast` extra), slow to import, with jax

    return [
        (th.nn.ReLU, fnn.relu),
        (th.nn.Tanh, fnn.tanh),
        (th.nn.ELU, fnn.elu),
        (th.nn.LeakyReLU, fnn.leaky_relu),  # both slopes default to 0.01
        (th.nn.SiLU, fnn.silu),
        (th.nn.GELU, functools.partial(fnn.gelu, approximate=False)),  # torch's GELU is the exact one
        (th.nn.Sigmoid, fnn.sigmoid),
    ]


def _to_flax_activation(activation: object) -> Any:
    for torch_cls, flax_fn in _activation_pairs():
        if activation is torch_cls:
            return flax_fn
    raise BackendError(f"The sbx backend has no JAX counterpart of activation_fn {activation!r}")


def _to_torch_activation(activation: object) -> type[th.nn.Module]:
    for torch_cls, flax_fn in _activation_pairs():
        if activation is flax_fn or (
            getattr(activation, "func", None) is getattr(flax_fn, "func", flax_fn)
            and getattr(activation, "keywords", None) == getattr(flax_fn, "keywords", None)
        ):
            return torch_cls
    raise BackendError(f"No torch counterpart of the SBX activation_fn {activation!r}")


#: ``policy_kwargs`` both backends read the same way.
_SHARED_POLICY_KWARGS = {"net_arch", "activation_fn", "n_critics", "share_features_extractor"}
#: SBX policy options without an SB3 counterpart: only their defaults can be exported.
_SBX_ONLY_POLICY_DEFAULTS = {"dropout_rate": 0.0, "layer_norm": False, "use_sde": False}


def sbx_kwargs(algo: str, kwargs: Mapping[str, Any]) -> dict[str, Any]:
    """
    Translate SB3 constructor arguments (a config block's) into SBX's, refusing what SBX cannot honour.

    :param algo: an algorithm SBX trains (:data:`SBX_ALGOS`).
    :param kwargs: SB3 keyword arguments.
    :return: the SBX keyword arguments; raises :class:`BackendError` naming the key SBX lacks.
    """
    record = algorithm(algo)
    cls = sbx_class(algo)
    accepted = set(inspect.signature(cls.__init__).parameters)
    out = dict(kwargs)
    for key in out:
        if key not in accepted:
            raise BackendError(f"The sbx backend's {cls.__name__} has no argument {key!r}: use --backend sb3")
    policy_kwargs = dict(out.get("policy_kwargs") or {})
    if policy_kwargs.get("use_sde") is False:  # SB3 writes its default into the dict it was given
        del policy_kwargs["use_sde"]
    extra = sorted(set(policy_kwargs) - _SHARED_POLICY_KWARGS - layout_of(record).policy_kwargs)
    if extra:
        raise BackendError(f"The sbx backend cannot honour policy_kwargs {extra}: use --backend sb3")
    if "activation_fn" in policy_kwargs:
        policy_kwargs["activation_fn"] = _to_flax_activation(policy_kwargs["activation_fn"])
    if "batch_norm_momentum" in policy_kwargs:
        # torch's BatchRenorm moves its statistics by momentum, flax's keeps momentum of the old ones.
        policy_kwargs["batch_norm_momentum"] = 1.0 - float(policy_kwargs["batch_norm_momentum"])
    if "batch_norm" in policy_kwargs:  # one switch for actor and critic in torch, two in SBX
        policy_kwargs["batch_norm_actor"] = policy_kwargs["batch_norm"]
    out["policy_kwargs"] = policy_kwargs
    if "qf_learning_rate" in accepted:
        # SB3 trains the critic at learning_rate; SBX's DDPG defaults its critic to 1e-3 whatever that is.
        out["qf_learning_rate"] = None
    if callable(out.get("learning_rate")) and record.sbx_layout == "deterministic":
        # SBX's SAC-like algorithms keep their rates in the optimiser state, TD3 and DDPG on request.
        policy_kwargs["optimizer_class"] = scheduled_adam
    return out


#: SB3 constructor arguments that an SBX model holds as attributes of the same name, exported as they are.
_EXPORTED_SETTINGS = (
    "buffer_size",
    "learning_starts",
    "batch_size",
    "tau",
    "gamma",
    "gradient_steps",
    "policy_delay",
    "target_policy_noise",
    "target_noise_clip",
    "target_entropy",
)


def _sb3_hyperparams(model: Any, record: Algorithm) -> dict[str, Any]:
    """The SB3 constructor arguments that reproduce an SBX model's settings."""
    accepted = set(inspect.signature(record.cls.__init__).parameters)
    train_freq = model.train_freq
    hparams: dict[str, Any] = {
        "learning_rate": model.learning_rate,
        # SB3 turns train_freq into a TrainFreq(frequency, unit) named tuple; hand it back as a plain tuple.
        "train_freq": (int(train_freq.frequency), train_freq.unit.value)
        if hasattr(train_freq, "unit")
        else train_freq,
    }
    for key in _EXPORTED_SETTINGS:
        value = getattr(model, key, None)
        if key in accepted and value is not None:
            hparams[key] = value.item() if isinstance(value, np.generic) else value
    if "top_quantiles_to_drop_per_net" in accepted:  # SBX's TQC keeps it among the policy's settings
        hparams["top_quantiles_to_drop_per_net"] = int(model.policy_kwargs["top_quantiles_to_drop_per_net"])
    if "ent_coef" in accepted and hasattr(model, "ent_coef_init"):
        hparams["ent_coef"] = model.ent_coef_init
        hparams["target_entropy"] = float(model.target_entropy)
    if "target_update_interval" in accepted:
        # SBX's SAC and TQC update their targets after every gradient step, SB3's target_update_interval=1.
        hparams["target_update_interval"] = 1
    return hparams


def _sb3_policy_kwargs(model: Any, record: Algorithm) -> dict[str, Any]:
    policy_kwargs = dict(model.policy_kwargs)
    if policy_kwargs.get("optimizer_class") is scheduled_adam:
        # SB3's optimiser follows the schedule (learning_rate) by itself.
        del policy_kwargs["optimizer_class"]
    policy_kwargs.pop("top_quantiles_to_drop_per_net", None)  # an argument of SB3's TQC, not its policy's
    for key, default in _SBX_ONLY_POLICY_DEFAULTS.items():
        if key in policy_kwargs and policy_kwargs.pop(key) != default:
            raise BackendError(f"Cannot export an SBX model with {key}={model.policy_kwargs[key]!r} to SB3")
    if "batch_norm_actor" in policy_kwargs and policy_kwargs.pop("batch_norm_actor") != policy_kwargs.get(
        "batch_norm", True
    ):
        raise BackendError("Cannot export an SBX model with batch_norm_actor != batch_norm to SB3")
    if "batch_norm_momentum" in policy_kwargs:
        policy_kwargs["batch_norm_momentum"] = 1.0 - float(policy_kwargs["batch_norm_momentum"])
    extra = sorted(set(policy_kwargs) - _SHARED_POLICY_KWARGS - layout_of(record).policy_kwargs)
    if extra:
        raise BackendError(f"Cannot export an SBX model with policy_kwargs {extra} to SB3")
    if "activation_fn" in policy_kwargs:
        policy_kwargs["activation_fn"] = _to_torch_activation(policy_kwargs["activation_fn"])
    if policy_kwargs.get("n_critics") == record.default_n_critics:
        # SBX's DDPG writes its default of one critic into policy_kwargs; SB3's has the same default.
        policy_kwargs.pop("n_critics")
    return policy_kwargs


def sbx_model(algo: str, env: Any, kwargs: Mapping[str, Any], seed: int | None, policy: str) -> BaseAlgorithm:
    """
    A fresh SBX model of ``algo`` on the weights SB3 draws for the same seed, as
    :func:`~sb3_hddpg.training.models.make_model` describes.

    :param algo: an algorithm SBX trains.
    :param env: the (vectorised) training env.
    :param kwargs: SB3 constructor arguments, ``policy_kwargs`` among them (a copy: SB3 writes into it).
    :param seed: the training seed.
    :param policy: the policy name (``MlpPolicy``).
    """
    record = algorithm(algo)
    # Any: SBX's SAC adds attributes (target_entropy) that BaseAlgorithm does not declare.
    model: Any = sbx_class(algo)(policy, env, seed=seed, device="cpu", verbose=0, **sbx_kwargs(algo, kwargs))
    sb3_kwargs = {k: v for k, v in kwargs.items() if k not in ("action_noise", "policy_kwargs")}
    if record.target_entropy:  # "auto" reads an env the twin does not have; the SBX model has resolved it
        sb3_kwargs["target_entropy"] = float(model.target_entropy)
    twin = build_without_env(
        record.cls,
        model.observation_space,
        model.action_space,
        sb3_kwargs,
        kwargs["policy_kwargs"],
        seed=seed,
    )
    state_dict_to_sbx(model, twin, record)
    share_compiled(model)
    return model


#: One set of jitted functions and optimisers per architecture and optimiser setting, shared by models.
_SHARED: dict[tuple[Any, ...], dict[str, tuple[Any, Any]]] = {}


def share_compiled(model: Any) -> None:
    """
    Make ``model`` reuse the apply functions and optimisers of an earlier model of the same architecture.

    The ``apply_fn`` and ``tx`` of SBX's train states are static parts of the jitted update's cache key, and
    every model creates its own, so each new model would recompile the update. Both are pure functions of
    the architecture and the optimiser's settings, so models that agree on those can share them.

    :param model: an SBX model (modified in place).
    """
    policy = model.policy
    key = (
        type(model).__qualname__,
        repr(policy.actor),
        repr(policy.qf),
        float(model.lr_schedule(1)),
        float(model.qf_learning_rate),
        policy.optimizer_class,
        repr(sorted(policy.optimizer_kwargs.items())),
        repr(getattr(model, "ent_coef_init", None)),
    )
    states = {"actor_state": policy, **{name: policy for name in layout_of(_sbx_record(model)).critic_states}}
    if hasattr(model, "ent_coef_state"):
        states["ent_coef_state"] = model
    shared = _SHARED.setdefault(
        key,
        {name: (getattr(owner, name).apply_fn, getattr(owner, name).tx) for name, owner in states.items()},
    )
    for name, owner in states.items():
        apply_fn, tx = shared[name]
        setattr(owner, name, getattr(owner, name).replace(apply_fn=apply_fn, tx=tx))


def export_to_sb3(model: Any) -> BaseAlgorithm:
    """
    An SB3 model of the same algorithm and settings as an SBX model (no env attached), with its actor,
    critics, their targets and its entropy coefficient; optimiser moments are not copied (continue training
    from the run's native checkpoint).

    :param model: an SBX model.
    """
    record = _sbx_record(model)
    # No seed: it would re-seed the global random state (SB3's set_random_seed) mid-run.
    sb3_model: Any = build_without_env(
        record.cls,
        model.observation_space,
        model.action_space,
        _sb3_hyperparams(model, record),
        _sb3_policy_kwargs(model, record),
    )
    sb3_model.seed = model.seed
    state = sbx_to_state_dict(model, sb3_model, record)
    sb3_model.policy.load_state_dict(state, strict=True)
    if getattr(sb3_model, "log_ent_coef", None) is not None and hasattr(model, "ent_coef_state"):
        # SBX keeps a learned entropy coefficient in a flax train state BaseAlgorithm does not declare.
        log_ent_coef = float(np.asarray(model.ent_coef_state.params["log_ent_coef"]))
        sb3_model.log_ent_coef.data.fill_(log_ent_coef)
    sb3_model.num_timesteps = int(model.num_timesteps)
    sb3_model._n_updates = int(model._n_updates)
    return sb3_model

"""
The algorithm registry: the SB3 classes sb3-hddpg trains, rebuilds and exports, which of them the SBX (JAX)
backend trains too, and the activation functions their networks may use. Everything else (training, safe
loading, the SBX backend, config parsing, frozen workers) reads these tables instead of keeping its own.
"""

from __future__ import annotations

import torch as th
from sb3_contrib import TQC
from stable_baselines3 import DDPG, SAC, TD3
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

#: Algorithm name (as ``--algo`` and configs spell it) -> its SB3 class. Exact classes only: a subclass may
#: change the networks in ways a rebuild spec cannot describe.
ALGORITHMS: dict[str, type[OffPolicyAlgorithm]] = {"ddpg": DDPG, "td3": TD3, "sac": SAC, "tqc": TQC}

#: The algorithms the SBX backend trains and exports (SBX has classes of the same names).
SBX_ALGORITHMS = ("ddpg", "td3", "sac")

#: Activation name -> torch class, for every activation a saved model's spec may name. A name outside this
#: table is refused rather than looked up in ``torch.nn``: specs and configs are data and must not be able
#: to pick arbitrary callables.
ACTIVATIONS: dict[str, type[th.nn.Module]] = {
    cls.__name__: cls
    for cls in (
        th.nn.ReLU,
        th.nn.Tanh,
        th.nn.ELU,
        th.nn.LeakyReLU,
        th.nn.SiLU,
        th.nn.GELU,
        th.nn.Sigmoid,
        th.nn.Softplus,
        th.nn.Mish,
        th.nn.SELU,
        th.nn.CELU,
        th.nn.Hardtanh,
        th.nn.ReLU6,
        th.nn.Identity,
    )
}

#: The activations a training config may name: those both backends compute alike (SBX has each in flax).
CONFIG_ACTIVATIONS = ("ReLU", "Tanh", "ELU", "LeakyReLU", "SiLU", "GELU", "Sigmoid")


def algorithm_class(name: str) -> type[OffPolicyAlgorithm]:
    """
    The SB3 class of an algorithm name, any case (``ddpg``, ``td3``, ``sac``, ``tqc``).

    :param name: the algorithm.
    """
    key = name.lower() if isinstance(name, str) else name
    if key not in ALGORITHMS:
        raise ValueError(f"Unknown algorithm {name!r}; choose from {list(ALGORITHMS)}")
    return ALGORITHMS[key]


def algorithm_name(model_or_class: object) -> str | None:
    """The registry name of an SB3 model or class of exactly a registered type, else ``None``."""
    cls = model_or_class if isinstance(model_or_class, type) else type(model_or_class)
    return next((name for name, registered in ALGORITHMS.items() if cls is registered), None)

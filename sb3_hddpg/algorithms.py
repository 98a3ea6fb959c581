"""
The algorithm registry: one frozen record per algorithm sb3-hddpg trains, rebuilds and exports, and the
activation functions their networks may use. The rest of the package reads the record instead of branching
on the algorithm's name, so adding an algorithm is one :class:`Algorithm` in :data:`REGISTRY`, one config
block in ``zoo_configs/`` and tests.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import torch as th
from sb3_contrib import QRDQN, TQC, CrossQ
from stable_baselines3 import DDPG, DQN, PPO, SAC, TD3
from stable_baselines3.common.base_class import BaseAlgorithm

#: The roles an algorithm can play in a hierarchy.
ROLES = ("worker", "flat", "manager")
#: The action spaces a record may declare (gymnasium class names).
ACTION_SPACES = ("Box", "Discrete")


def mlp_parameters(sizes: Sequence[int]) -> int:
    """Weights and biases of an MLP with these layer sizes (input first, output last)."""
    return sum((a + 1) * b for a, b in itertools.pairwise(sizes))


@dataclass(frozen=True)
class NetworkShape:
    """
    What a parameter-count rule needs to know about the networks a spec or config would build.

    :param obs_dim: flattened observation size.
    :param act_dim: action dimensions (a Box's size) or actions (a Discrete's ``n``).
    :param pi: the actor's (or Q-network's) hidden layers.
    :param qf: the critics' (or value function's) hidden layers.
    :param n_critics: critics (``None``: the algorithm's default).
    :param n_quantiles: quantiles per critic output (distributional critics only).
    """

    obs_dim: int
    act_dim: int
    pi: Sequence[int]
    qf: Sequence[int]
    n_critics: int | None = None
    n_quantiles: int = 25


def _deterministic_actor_critic(shape: NetworkShape, n_critics: int) -> int:
    # DDPG/TD3: a tanh actor and Q-critics, each with a target copy.
    actor = mlp_parameters([shape.obs_dim, *shape.pi, shape.act_dim])
    critic = n_critics * mlp_parameters([shape.obs_dim + shape.act_dim, *shape.qf, 1])
    return 2 * (actor + critic)


def _gaussian_actor_critic(shape: NetworkShape, n_critics: int, critic_outputs: int = 1) -> int:
    # SAC (TQC: a quantile per critic output): a mean and a log-std head, critics with target copies.
    actor = mlp_parameters([shape.obs_dim, *shape.pi, 2 * shape.act_dim])
    critic = n_critics * mlp_parameters([shape.obs_dim + shape.act_dim, *shape.qf, critic_outputs])
    return actor + 2 * critic


def _quantile_actor_critic(shape: NetworkShape, n_critics: int) -> int:
    return _gaussian_actor_critic(shape, n_critics, shape.n_quantiles)


def _batch_renorm_actor_critic(shape: NetworkShape, n_critics: int) -> int:
    # CrossQ: no target networks; a batch renormalisation (4 values per input) before every linear layer.
    actor = mlp_parameters([shape.obs_dim, *shape.pi, 2 * shape.act_dim])
    actor += 4 * (shape.obs_dim + sum(shape.pi))
    critic_in = shape.obs_dim + shape.act_dim
    critic = mlp_parameters([critic_in, *shape.qf, 1]) + 4 * (critic_in + sum(shape.qf))
    return actor + n_critics * critic


def _q_network(shape: NetworkShape, n_critics: int, outputs_per_action: int = 1) -> int:
    # DQN (QR-DQN: a quantile per output): one Q-network with one output per action, and its target copy.
    return 2 * mlp_parameters([shape.obs_dim, *shape.pi, shape.act_dim * outputs_per_action])


def _quantile_q_network(shape: NetworkShape, n_critics: int) -> int:
    return _q_network(shape, n_critics, shape.n_quantiles)


def _actor_and_value(shape: NetworkShape, n_critics: int) -> int:
    # PPO: the policy (a mean or logit per action, plus a log-std) and the value function; no targets.
    return (
        mlp_parameters([shape.obs_dim, *shape.pi, shape.act_dim])
        + shape.act_dim
        + mlp_parameters([shape.obs_dim, *shape.qf, 1])
    )


#: Policy kwargs every ``MlpPolicy`` here understands and a spec may carry; not ``use_sde``, which the
#: constructors overwrite from their own argument, so it lives with the hyperparameters.
_MLP_POLICY_KWARGS = frozenset(
    {"net_arch", "activation_fn", "normalize_images", "optimizer_class", "optimizer_kwargs"}
    | {"features_extractor_class", "features_extractor_kwargs"}
)
_ACTOR_CRITIC_POLICY_KWARGS = _MLP_POLICY_KWARGS | {"n_critics", "share_features_extractor"}
_GAUSSIAN_POLICY_KWARGS = _ACTOR_CRITIC_POLICY_KWARGS | {"log_std_init", "use_expln", "clip_mean"}

# Constructor hyperparameters a spec records, with their JSON kind: what shapes the rebuilt model, not
# training-time choices of whoever continues (exploration noise, train_freq...).
_COMMON_HPARAMS = {
    **dict.fromkeys(("learning_rate", "gamma", "tau"), "float"),
    "buffer_size": "int",
    "batch_size": "int",
}
_ENTROPY_HPARAMS = {
    "ent_coef": "ent_coef",
    "target_entropy": "float",
    "use_sde": "bool",
    "sde_sample_freq": "int",
}
_TD3_HPARAMS = {"policy_delay": "int", "target_policy_noise": "float", "target_noise_clip": "float"}


@dataclass(frozen=True)
class Algorithm:
    """
    Everything sb3-hddpg knows about one algorithm.

    :param name: the name ``--algo`` and configs use (lower case).
    :param cls: the SB3 or sb3-contrib class every saved model is, whichever backend trained it.
    :param colour: its colour in figures (a matplotlib colour name).
    :param parameter_rule: the parameters (targets included) its networks have, given a
        :class:`NetworkShape` and the critics to count.
    :param policy_kwargs: the ``policy_kwargs`` keys a saved model's spec may carry.
    :param hyperparameters: the constructor arguments a spec records, with their JSON kind (``float``,
        ``int``, ``bool``, ``ent_coef``).
    :param sampler: the Optuna sampler's key (``None``: not tunable).
    :param sbx: the SBX class's name (``None``: SBX cannot train it here).
    :param sbx_layout: how SBX lays out its networks (the weight conversion): ``deterministic``,
        ``gaussian``, ``quantile`` or ``batch_renorm``.
    :param roles: of :data:`ROLES`.
    :param action_spaces: of :data:`ACTION_SPACES`.
    :param on_policy: learns from rollouts (``n_steps``, a rollout buffer) rather than a replay buffer.
    :param default_net_arch: the hidden layers SB3 builds when ``net_arch`` is not given.
    :param default_n_critics: the critics SB3 builds when ``n_critics`` is not given.
    :param action_penalty: the actor is deterministic, so the ``ActionL2Penalty`` callback applies.
    :param target_entropy: its ``target_entropy`` may be ``"auto"``, which needs the action space to resolve.
    :param critic_layers: the key of ``net_arch`` naming the critic's layers (``qf``; PPO: ``vf``).
    """

    name: str
    cls: type[BaseAlgorithm]
    colour: str
    parameter_rule: Callable[[NetworkShape, int], int]
    policy_kwargs: frozenset[str]
    hyperparameters: Mapping[str, str]
    sampler: str | None = None
    sbx: str | None = None
    sbx_layout: str | None = None
    roles: frozenset[str] = frozenset(ROLES)
    action_spaces: frozenset[str] = frozenset({"Box"})
    on_policy: bool = False
    default_net_arch: tuple[int, ...] = (256, 256)
    default_n_critics: int = 2
    action_penalty: bool = False
    target_entropy: bool = False
    critic_layers: str = "qf"

    @property
    def class_name(self) -> str:
        """The class name a saved spec records (``DDPG``, ``CrossQ``...)."""
        return self.cls.__name__

    def takes(self, action_space: Any) -> bool:
        """Whether this algorithm acts in ``action_space`` (a gymnasium space)."""
        return type(action_space).__name__ in self.action_spaces

    def parameter_count(self, shape: NetworkShape) -> int:
        """The parameters its networks (and their targets) would have for ``shape``."""
        n_critics = shape.n_critics if shape.n_critics is not None else self.default_n_critics
        return self.parameter_rule(shape, n_critics)


#: Every algorithm, by name, in the order ``--algo`` lists them.
REGISTRY: dict[str, Algorithm] = {
    record.name: record
    for record in (
        Algorithm(
            "ddpg",
            DDPG,
            colour="tab:blue",
            parameter_rule=_deterministic_actor_critic,
            policy_kwargs=_ACTOR_CRITIC_POLICY_KWARGS,
            # DDPG's constructor hard-codes policy_delay / target noise, so they are not arguments there.
            hyperparameters=_COMMON_HPARAMS,
            sampler="ddpg",
            sbx="DDPG",
            sbx_layout="deterministic",
            default_net_arch=(400, 300),
            default_n_critics=1,
            action_penalty=True,
        ),
        Algorithm(
            "td3",
            TD3,
            colour="tab:cyan",
            parameter_rule=_deterministic_actor_critic,
            policy_kwargs=_ACTOR_CRITIC_POLICY_KWARGS,
            hyperparameters={**_COMMON_HPARAMS, **_TD3_HPARAMS},
            sampler="td3",
            sbx="TD3",
            sbx_layout="deterministic",
            default_net_arch=(400, 300),
            action_penalty=True,
        ),
        Algorithm(
            "sac",
            SAC,
            colour="tab:purple",
            parameter_rule=_gaussian_actor_critic,
            policy_kwargs=_GAUSSIAN_POLICY_KWARGS,
            hyperparameters={**_COMMON_HPARAMS, **_ENTROPY_HPARAMS, "target_update_interval": "int"},
            sampler="sac",
            sbx="SAC",
            sbx_layout="gaussian",
            target_entropy=True,
        ),
        Algorithm(
            "tqc",
            TQC,
            colour="tab:brown",
            parameter_rule=_quantile_actor_critic,
            policy_kwargs=_GAUSSIAN_POLICY_KWARGS | {"n_quantiles"},
            hyperparameters={
                **_COMMON_HPARAMS,
                **_ENTROPY_HPARAMS,
                "target_update_interval": "int",
                "top_quantiles_to_drop_per_net": "int",
            },
            sampler="tqc",
            sbx="TQC",
            sbx_layout="quantile",
            target_entropy=True,
        ),
        Algorithm(
            "crossq",
            CrossQ,
            colour="tab:olive",
            parameter_rule=_batch_renorm_actor_critic,
            policy_kwargs=_GAUSSIAN_POLICY_KWARGS
            | {"batch_norm", "batch_norm_momentum", "batch_norm_eps", "renorm_warmup_steps"},
            # No target networks, so no tau.
            hyperparameters={
                **{k: v for k, v in _COMMON_HPARAMS.items() if k != "tau"},
                **_ENTROPY_HPARAMS,
                "policy_delay": "int",
            },
            sampler="crossq",
            sbx="CrossQ",
            sbx_layout="batch_renorm",
            target_entropy=True,
        ),
        Algorithm(
            "dqn",
            DQN,
            colour="slategray",
            parameter_rule=_q_network,
            policy_kwargs=_MLP_POLICY_KWARGS,
            hyperparameters={**_COMMON_HPARAMS, "target_update_interval": "int"},
            sampler="dqn",
            action_spaces=frozenset({"Discrete"}),
            default_net_arch=(64, 64),
            default_n_critics=1,
        ),
        Algorithm(
            "qrdqn",
            QRDQN,
            colour="orchid",
            parameter_rule=_quantile_q_network,
            policy_kwargs=_MLP_POLICY_KWARGS | {"n_quantiles"},
            hyperparameters={**_COMMON_HPARAMS, "target_update_interval": "int"},
            sampler="qrdqn",
            action_spaces=frozenset({"Discrete"}),
            default_net_arch=(64, 64),
            default_n_critics=1,
        ),
        Algorithm(
            "ppo",
            PPO,
            colour="teal",
            parameter_rule=_actor_and_value,
            policy_kwargs=_MLP_POLICY_KWARGS
            | {"share_features_extractor", "log_std_init", "ortho_init", "use_expln", "full_std"},
            hyperparameters={
                **dict.fromkeys(
                    ("learning_rate", "gamma", "gae_lambda", "ent_coef", "vf_coef", "max_grad_norm"), "float"
                ),
                **dict.fromkeys(("n_steps", "batch_size", "n_epochs", "sde_sample_freq"), "int"),
                **dict.fromkeys(("use_sde", "normalize_advantage"), "bool"),
            },
            sampler="ppo",
            action_spaces=frozenset({"Box", "Discrete"}),
            on_policy=True,
            default_net_arch=(64, 64),
            default_n_critics=1,
            critic_layers="vf",
        ),
    )
}

#: Algorithm name -> its SB3 class (the registry's classes, in its order).
ALGORITHMS: dict[str, type[BaseAlgorithm]] = {name: record.cls for name, record in REGISTRY.items()}

#: The algorithms the SBX backend trains and exports.
SBX_ALGORITHMS = tuple(name for name, record in REGISTRY.items() if record.sbx is not None)

#: The activations a training config may name, those both backends compute alike (SBX has each in flax).
CONFIG_ACTIVATIONS = ("ReLU", "Tanh", "ELU", "LeakyReLU", "SiLU", "GELU", "Sigmoid")
#: Activation name -> torch class, for every activation a saved model's spec may name; a name outside this
#: table is refused, so that specs and configs (data) cannot pick arbitrary callables.
ACTIVATIONS: dict[str, type[th.nn.Module]] = {
    name: getattr(th.nn, name)
    for name in (*CONFIG_ACTIVATIONS, "Softplus", "Mish", "SELU", "CELU", "Hardtanh", "ReLU6", "Identity")
}


def algorithm(name: str) -> Algorithm:
    """
    The record of an algorithm: by its name (any case: ``ddpg``, ``crossq``...) or the class name a spec
    records (``DDPG``, ``CrossQ``...).

    :param name: the algorithm.
    :return: its record; raises ``ValueError`` naming the choices otherwise.
    """
    key = name.lower() if isinstance(name, str) else name
    if key not in REGISTRY:
        raise ValueError(f"Unknown algorithm {name!r}; choose from {list(REGISTRY)}")
    return REGISTRY[key]


def algorithm_class(name: str) -> type[BaseAlgorithm]:
    """The SB3 class of an algorithm name, any case (``ddpg``, ``crossq``...)."""
    return algorithm(name).cls


def algorithms_for(role: str, action_space: Any | None = None) -> tuple[str, ...]:
    """
    The algorithms that can play ``role`` (and act in ``action_space``, when given), in registry order.

    :param role: one of :data:`ROLES`.
    :param action_space: a gymnasium space, or ``None`` for any.
    """
    if role not in ROLES:
        raise ValueError(f"Unknown role {role!r}; choose from {list(ROLES)}")
    return tuple(
        name
        for name, record in REGISTRY.items()
        if role in record.roles and (action_space is None or record.takes(action_space))
    )

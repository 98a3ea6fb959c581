"""
Search spaces of ``hddpg-cli tune``: one ``sample_*_params(trial)`` per level, in a registry, as in rl_zoo3's
``hyperparams_opt.py``; the flat level has one per algorithm (:data:`SAMPLERS`, named by each algorithm record), so that
every flat baseline can get the same tuning effort (trials and steps per trial) before a benchmark.

Each sampler returns the *changes* to a ``zoo_configs`` block, already in the file's format (``policy_kwargs``
as a string, ``noise_type`` ``None`` for no noise), so that one function serves twice: in a trial it shapes
the block that is trained, and replayed on ``optuna.trial.FixedTrial(best.params)`` it rebuilds the block
that ``--save-config`` writes. The ranges follow rl_zoo3's DDPG/TD3 spaces, narrowed where the full range
only wastes trials on this task and a CPU: learning rates above 1e-2 diverge, and batches above 512 or
replay buffers above 3e5 cost time and memory per trial process without changing a tuning-sized run.
The discount also offers 0.7 and 0.8 (below rl_zoo3's 0.9), and the buffer 2e5: the goal worker's
config found by hand (docs/WORKERS.md) uses both, and every method's base config is a study's first trial
(:func:`base_params`), which only reproduces values inside the space.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from typing import Protocol

from sb3_hddpg.algorithms import REGISTRY, ROLES, algorithms_for
from sb3_hddpg.hierarchy.selection import SELECTORS, DiscreteSelector
from sb3_hddpg.training.config_values import parse_policy_kwargs

#: ``net_arch`` choices by name (rl_zoo3's names and sizes).
NET_ARCHS: dict[str, list[int]] = {"small": [64, 64], "medium": [256, 256], "big": [400, 300]}

#: The initial entropy coefficient of SB3's and SBX's SAC under ``ent_coef: 'auto'`` (``'auto_X'`` starts at X).
SAC_ENT_COEF_INIT = 1.0

#: Largest HAM threshold: the observation's per-link obstacle clearances lie in [0, 1], so their sum over
#: the default six links lies in [0, 6].
HAM_THRESHOLD_MAX = 6.0


#: A categorical choice Optuna can store (its ``CategoricalChoiceType``).
Choice = None | bool | int | float | str
#: The keys of a ``zoo_configs`` block a sampler sets: plain values, and ``wrapper_kwargs`` a mapping of them.
SampledBlock = dict[str, "Choice | dict[str, Choice]"]


class Trial(Protocol):
    """What a sampler asks of a trial: ``optuna.Trial``, ``optuna.trial.FixedTrial`` and the space recorder."""

    def suggest_categorical(self, name: str, choices: Sequence[Choice]) -> Choice: ...

    def suggest_float(
        self, name: str, low: float, high: float, *, step: float | None = None, log: bool = False
    ) -> float: ...

    def suggest_int(self, name: str, low: int, high: int, *, step: int = 1, log: bool = False) -> int: ...


#: A sampler: a trial -> the block's sampled keys.
Sampler = Callable[[Trial], SampledBlock]


def _sample_learning(trial: Trial) -> SampledBlock:
    """The discount, learning rate and batch size every off-policy space shares, with the same choices."""
    return {
        "gamma": trial.suggest_categorical("gamma", [0.7, 0.8, 0.9, 0.95, 0.98, 0.99, 0.995, 0.999]),
        "learning_rate": trial.suggest_float("learning_rate", 1e-5, 1e-2, log=True),
        "batch_size": trial.suggest_categorical("batch_size", [32, 64, 128, 256, 512]),
    }


def _sample_shared(trial: Trial) -> SampledBlock:
    """
    The hyperparameters DDPG, TD3 and SAC share, with the same choices and sampled first, in this order:
    discount, learning rate, batch and buffer size, soft-update rate, update schedule.
    """
    block: SampledBlock = {
        **_sample_learning(trial),
        "buffer_size": trial.suggest_categorical("buffer_size", [10_000, 100_000, 200_000, 300_000]),
        "tau": trial.suggest_categorical("tau", [0.001, 0.005, 0.01, 0.02, 0.05, 0.08]),
        "train_freq": trial.suggest_categorical("train_freq", [1, 4, 8, 16, 32, 64]),
    }
    # As in rl_zoo3: as many gradient steps as env steps between updates, so the update-to-data ratio
    # stays 1 and only the update's granularity is tuned.
    block["gradient_steps"] = block["train_freq"]
    return block


def sample_ddpg_params(trial: Trial) -> SampledBlock:
    """
    DDPG's hyperparameters: discount, learning rate, batch and buffer size, soft-update rate, update
    schedule, exploration noise and network size.

    :param trial: an ``optuna.Trial`` (or ``FixedTrial``).
    :return: the keys of a ``zoo_configs`` block that the trial sets.
    """
    block = _sample_shared(trial)
    noise_type = trial.suggest_categorical("noise_type", ["normal", "ornstein-uhlenbeck", "none"])
    net_arch = trial.suggest_categorical("net_arch", list(NET_ARCHS))
    # "none" rather than None among the choices: every storage and the dashboard show it plainly.
    block["noise_type"] = None if noise_type == "none" else noise_type
    block["policy_kwargs"] = f"dict(net_arch={NET_ARCHS[str(net_arch)]})"
    if noise_type != "none":
        block["noise_std"] = trial.suggest_float("noise_std", 0.0, 1.0)
    return block


def sample_td3_params(trial: Trial) -> SampledBlock:
    """
    TD3's hyperparameters: DDPG's space (as rl_zoo3's ``sample_td3_params``), so that a difference between
    the tuned DDPG and TD3 is the algorithm's (twin critics, delayed actor, target smoothing), not the
    search's. TD3's own settings stay SB3's defaults, as in ``zoo_configs/td3.yml``.

    :param trial: an ``optuna.Trial`` (or ``FixedTrial``).
    """
    return sample_ddpg_params(trial)


def sample_sac_params(trial: Trial) -> SampledBlock:
    """
    SAC's hyperparameters: DDPG's shared ones (discount, learning rate, batch and buffer size, soft-update
    rate, update schedule, network size, same choices) plus, in place of DDPG's action noise, how much it
    explores at first: the starting value of its learned entropy coefficient (``ent_coef: 'auto_X'``).

    rl_zoo3 samples ``log_std_init`` instead. Without gSDE (``use_sde``, off here) neither SB3's nor SBX's
    SAC reads it, so it would be a search dimension that changes nothing (and SBX refuses it).

    :param trial: an ``optuna.Trial`` (or ``FixedTrial``).
    """
    block = _sample_shared(trial)
    ent_coef_init = trial.suggest_float("ent_coef_init", 0.01, 1.0, log=True)
    net_arch = trial.suggest_categorical("net_arch", list(NET_ARCHS))
    # 'auto' is 'auto_1.0': the bundled block's spelling is kept where it is the value.
    block["ent_coef"] = "auto" if ent_coef_init == SAC_ENT_COEF_INIT else f"auto_{ent_coef_init!r}"
    block["policy_kwargs"] = f"dict(net_arch={NET_ARCHS[str(net_arch)]})"
    return block


def sample_tqc_params(trial: Trial) -> SampledBlock:
    """
    TQC's hyperparameters: SAC's space plus how many of each critic's top quantiles it drops (its control of
    overestimation; SB3's default 2 of 25).

    :param trial: an ``optuna.Trial`` (or ``FixedTrial``).
    """
    block = sample_sac_params(trial)
    block["top_quantiles_to_drop_per_net"] = trial.suggest_categorical(
        "top_quantiles_to_drop_per_net", [2, 0, 1, 3, 5]
    )
    return block


def sample_crossq_params(trial: Trial) -> SampledBlock:
    """
    CrossQ's hyperparameters: SAC's space without the soft-update rate (CrossQ has no target networks),
    plus the actor's delay (sb3-contrib's and SBX's default 3 first).

    :param trial: an ``optuna.Trial`` (or ``FixedTrial``).
    """
    block = sample_sac_params(trial)
    del block["tau"]
    block["policy_delay"] = trial.suggest_categorical("policy_delay", [3, 1, 2, 5])
    return block


def _sample_q_network(trial: Trial, policy_extra: str = "") -> SampledBlock:
    """
    DQN's space: the shared discount, learning rate and batch size; its own buffer sizes (the bundled
    blocks' 50k among them), update period with one gradient step each (SB3's and the bundled blocks'
    schedule), target-network period and exploration schedule. No soft-update rate: DQN copies its target.
    """
    net_arch = trial.suggest_categorical("net_arch", list(NET_ARCHS))
    return {
        **_sample_learning(trial),
        "buffer_size": trial.suggest_categorical("buffer_size", [10_000, 50_000, 100_000, 200_000, 300_000]),
        "train_freq": trial.suggest_categorical("train_freq", [1, 4, 8, 16]),
        "gradient_steps": 1,
        "target_update_interval": trial.suggest_categorical(
            "target_update_interval", [1000, 1, 100, 250, 500, 5000]
        ),
        "exploration_fraction": trial.suggest_float("exploration_fraction", 0.0, 0.5),
        "exploration_final_eps": trial.suggest_float("exploration_final_eps", 0.0, 0.2),
        "policy_kwargs": f"dict(net_arch={NET_ARCHS[str(net_arch)]}{policy_extra})",
    }


def sample_dqn_params(trial: Trial) -> SampledBlock:
    """
    DQN's hyperparameters (rl_zoo3's space, narrowed as the others): discount, learning rate, batch and
    buffer size, update schedule, target update interval, exploration schedule, network size.

    :param trial: an ``optuna.Trial`` (or ``FixedTrial``).
    """
    return _sample_q_network(trial)


def sample_qrdqn_params(trial: Trial) -> SampledBlock:
    """
    QR-DQN's hyperparameters: DQN's space plus the number of quantiles.

    :param trial: an ``optuna.Trial`` (or ``FixedTrial``).
    """
    n_quantiles = trial.suggest_categorical("n_quantiles", [50, 10, 25, 100])
    return _sample_q_network(trial, f", n_quantiles={n_quantiles}")


def sample_ppo_params(trial: Trial) -> SampledBlock:
    """
    PPO's hyperparameters (rl_zoo3's space, narrowed as the others): discount, learning rate, rollout
    length, minibatch size, epochs, GAE's lambda, clipping, entropy bonus and network size.

    :param trial: an ``optuna.Trial`` (or ``FixedTrial``).
    """
    net_arch = trial.suggest_categorical("net_arch", list(NET_ARCHS))
    return {
        "gamma": trial.suggest_categorical("gamma", [0.7, 0.8, 0.9, 0.95, 0.98, 0.99, 0.995, 0.999]),
        "learning_rate": trial.suggest_float("learning_rate", 1e-5, 1e-2, log=True),
        "n_steps": trial.suggest_categorical("n_steps", [2048, 256, 512, 1024]),
        "batch_size": trial.suggest_categorical("batch_size", [64, 32, 128, 256]),
        "n_epochs": trial.suggest_categorical("n_epochs", [10, 1, 5, 20]),
        "gae_lambda": trial.suggest_categorical("gae_lambda", [0.95, 0.8, 0.9, 0.98, 1.0]),
        "clip_range": trial.suggest_categorical("clip_range", [0.2, 0.1, 0.3, 0.4]),
        "ent_coef": trial.suggest_float("ent_coef", 1e-8, 0.1, log=True),
        "policy_kwargs": f"dict(net_arch=dict(pi={NET_ARCHS[str(net_arch)]}, vf={NET_ARCHS[str(net_arch)]}))",
    }


#: An algorithm record's ``sampler`` -> its sampler, as rl_zoo3's one ``sample_*_params`` per algorithm.
SAMPLERS: dict[str, Sampler] = {
    "ddpg": sample_ddpg_params,
    "td3": sample_td3_params,
    "sac": sample_sac_params,
    "tqc": sample_tqc_params,
    "crossq": sample_crossq_params,
    "dqn": sample_dqn_params,
    "qrdqn": sample_qrdqn_params,
    "ppo": sample_ppo_params,
}


def sample_worker_params(trial: Trial) -> SampledBlock:
    """A worker is a plain DDPG on its own reward (the paper's): :func:`sample_ddpg_params`."""
    return sample_ddpg_params(trial)


def sample_flat_params(trial: Trial) -> SampledBlock:
    """The flat baseline is a plain DDPG on the combined reward: :func:`sample_ddpg_params`."""
    return sample_ddpg_params(trial)


def sample_manager_params(trial: Trial, algo: str = "ddpg") -> SampledBlock:
    """
    The manager's algorithm (its record's sampler in :data:`SAMPLERS`) plus how its action
    selects workers (``wrapper_kwargs``): the simplex map's temperature and floor, the selection mode and
    the option length.

    :param trial: an ``optuna.Trial`` (or ``FixedTrial``).
    :param algo: the manager's algorithm.
    """
    block = SAMPLERS[str(REGISTRY[algo].sampler)](trial)
    # Only the modes whose manager action this algorithm takes (a DQN manager picks a worker index).
    modes = [name for name, mode in SELECTORS.items() if REGISTRY[algo].takes(mode.action_space(2))]
    wrapper: dict[str, Choice] = {}
    if modes != [DiscreteSelector.name]:  # the simplex map's shape; an index has none
        wrapper["temperature"] = trial.suggest_float("temperature", 0.1, 2.0, log=True)
        # Below 1/n for any n <= 9 workers, as SimplexMap requires.
        wrapper["floor"] = trial.suggest_float("floor", 0.0, 0.1)
    wrapper["selection"] = trial.suggest_categorical("selection", modes)
    wrapper["option_steps"] = trial.suggest_categorical("option_steps", [1, 2, 4, 8])
    block["wrapper_kwargs"] = wrapper
    return block


def sample_ham_params(trial: Trial) -> SampledBlock:
    """
    HAM's switching threshold on the sum of obstacle clearances (paper Section 4); HAM trains nothing.

    :param trial: an ``optuna.Trial`` (or ``FixedTrial``).
    """
    return {"threshold": trial.suggest_float("threshold", 0.0, HAM_THRESHOLD_MAX)}


#: Level -> its sampler, as rl_zoo3's ``HYPERPARAMS_SAMPLER``.
HYPERPARAMS_SAMPLER: dict[str, Sampler] = {
    "worker": sample_worker_params,
    "manager": sample_manager_params,
    "flat": sample_flat_params,
    "ham": sample_ham_params,
}


def sampler_for(level: str, algo: str = "ddpg") -> Sampler:
    """
    The sampler of a level and, for ``worker``, ``flat`` and ``manager``, of an algorithm whose record plays
    that role and names a sampler (:data:`SAMPLERS`).

    :raises ValueError: naming the unknown level or algorithm, or an algorithm for level ``ham``.
    """
    if level not in HYPERPARAMS_SAMPLER:
        raise ValueError(f"Unknown level {level!r}; choose from {list(HYPERPARAMS_SAMPLER)}")
    if level not in ROLES:
        if algo != "ddpg":
            raise ValueError(f"Level {level!r} trains nothing; an algorithm applies to levels {list(ROLES)}")
        return HYPERPARAMS_SAMPLER[level]
    tunable = tunable_algorithms(level)
    if algo not in tunable:
        raise ValueError(f"Unknown algorithm {algo!r} for level {level!r}; choose from {list(tunable)}")
    if level == "manager":
        return functools.partial(sample_manager_params, algo=algo)
    return SAMPLERS[str(REGISTRY[algo].sampler)]


def tunable_algorithms(level: str) -> tuple[str, ...]:
    """The algorithms ``tune --level LEVEL --algo`` takes: those whose record plays the role and has a sampler."""
    return tuple(name for name in algorithms_for(level) if REGISTRY[name].sampler is not None)


#: A parameter's domain: ``("choices", [...])`` or ``("range", (low, high))``.
Domain = tuple[str, "list[Choice] | tuple[float, float]"]


class _SpaceRecorder:
    """A stand-in trial that records every parameter a sampler asks for and its distribution."""

    def __init__(self) -> None:
        self.space: dict[str, Domain] = {}

    def suggest_categorical(self, name: str, choices: Sequence[Choice]) -> Choice:
        self.space[name] = ("choices", list(choices))
        return choices[0]

    def suggest_float(
        self, name: str, low: float, high: float, *, step: float | None = None, log: bool = False
    ) -> float:
        self.space[name] = ("range", (low, high))
        return low

    def suggest_int(self, name: str, low: int, high: int, *, step: int = 1, log: bool = False) -> int:
        self.space[name] = ("range", (low, high))
        return low


class _Replay(_SpaceRecorder):
    """A stand-in trial that answers with given values (else a parameter's first choice or low end)."""

    def __init__(self, values: Mapping[str, object]) -> None:
        super().__init__()
        self.values = values

    def suggest_categorical(self, name: str, choices: Sequence[Choice]) -> Choice:
        value = self.values.get(name, choices[0])
        return value if value in choices else choices[0]  # type: ignore[return-value]

    def suggest_float(
        self, name: str, low: float, high: float, *, step: float | None = None, log: bool = False
    ) -> float:
        value = self.values.get(name, low)
        return float(value) if isinstance(value, (int, float)) else low


def search_space(level: str, algo: str = "ddpg") -> dict[str, Domain]:
    """
    The parameters a level's sampler can suggest: name -> ``("choices", [...])`` or ``("range", (low, high))``
    (conditional ones included, as sampled with every earlier choice at its first value).
    """
    recorder = _SpaceRecorder()
    sampler_for(level, algo)(recorder)
    return recorder.space


def check_fixed_params(level: str, fixed: Mapping[str, object], algo: str = "ddpg") -> None:
    """
    Validate ``--fix`` values before a study starts: Optuna's ``PartialFixedSampler`` silently ignores
    unknown names, so a typo would tune what the user meant to hold fixed.

    :raises ValueError: naming the unknown parameter or the value outside its choices or range.
    """
    space = search_space(level, algo)
    for name, value in fixed.items():
        if name not in space:
            what = f"level {level!r}" + (f" ({algo})" if level in ("flat", "manager") else "")
            raise ValueError(f"Unknown parameter {name!r} for {what}; tunable: {sorted(space)}")
        kind, domain = space[name]
        if not _in_domain(value, kind, domain):
            expected = f"among {domain}" if kind == "choices" else f"in [{domain[0]}, {domain[1]}]"
            raise ValueError(f"Expected {name} {expected}, actually: {value!r}")


def base_params(
    level: str, block: Mapping[str, object], algo: str = "ddpg", ham_threshold: float | None = None
) -> tuple[dict[str, object], list[str]]:
    """
    The sampler's parameters that reproduce a base ``zoo_configs`` block: a study's first trial (``tune``
    enqueues it), so that every method's search starts from the config it had and its best trial is never
    worse than that config at the trial budget. Equal effort needs this as much as equal trial counts: a
    method whose hand-found values the search never tries starts behind.

    :param level: the level tuned.
    :param block: the base config's block (as in the file: ``policy_kwargs`` a string, ``noise_type``
        ``None`` for none).
    :param algo: the algorithm (levels ``flat`` and ``manager``).
    :param ham_threshold: HAM's default threshold (level ``ham``, which has no block).
    :return: the parameters whose base value lies in the search space, and the names of those whose value
        does not (or that the block cannot express, e.g. ``gradient_steps`` other than ``train_freq``):
        the trial samples those.
    """
    candidates: dict[str, object] = {
        key: block[key]
        for key in (
            "gamma",
            "learning_rate",
            "batch_size",
            "buffer_size",
            "tau",
            "train_freq",
            "target_update_interval",
            "exploration_fraction",
            "exploration_final_eps",
        )
        if key in block
    }
    candidates["noise_type"] = "none" if block.get("noise_type") is None else block["noise_type"]
    if "noise_std" in block:
        candidates["noise_std"] = block["noise_std"]
    policy_kwargs = block.get("policy_kwargs", {})
    if isinstance(policy_kwargs, str):
        policy_kwargs = parse_policy_kwargs(policy_kwargs, "the base block")
    net_arch = policy_kwargs.get("net_arch", []) if isinstance(policy_kwargs, Mapping) else []
    layers = list(net_arch) if isinstance(net_arch, (list, tuple)) else None
    names = [name for name, sizes in NET_ARCHS.items() if sizes == layers]
    if names:
        candidates["net_arch"] = names[0]
    candidates["ent_coef_init"] = _ent_coef_init(block.get("ent_coef", "auto"))
    wrapper = block.get("wrapper_kwargs")
    wrapper = wrapper if isinstance(wrapper, Mapping) else {}
    candidates.update(
        {k: wrapper[k] for k in ("temperature", "floor", "selection", "option_steps") if k in wrapper}
    )
    if ham_threshold is not None:
        candidates["threshold"] = ham_threshold
    space = search_space(level, algo)
    params = {
        name: candidates[name]
        for name, (kind, domain) in space.items()
        if name in candidates and _in_domain(candidates[name], kind, domain)
    }
    outside = [name for name in space if name not in params]
    replayed = sampler_for(level, algo)(_Replay(params))
    steps = replayed.get("gradient_steps")
    if steps is not None and block.get("gradient_steps", steps) != steps:
        outside.append("gradient_steps")  # the space sets it (e.g. tied to train_freq), not the block
    if params.get("noise_type") == "none":  # no noise: noise_std is not a parameter of that trial
        params.pop("noise_std", None)
        outside = [name for name in outside if name != "noise_std"]
    return params, outside


def _ent_coef_init(ent_coef: object) -> float | None:
    """The starting value of a learned entropy coefficient (``'auto'``, ``'auto_0.1'``); ``None`` for a fixed one."""
    if not isinstance(ent_coef, str) or not ent_coef.startswith("auto"):
        return None
    _, _, start = ent_coef.partition("_")
    try:
        return float(start) if start else SAC_ENT_COEF_INIT
    except ValueError:
        return None


def _in_domain(value: object, kind: str, domain: list[Choice] | tuple[float, float]) -> bool:
    """Whether a value is one of a categorical parameter's choices, or a number in a range's bounds."""
    if kind == "choices":
        return value in domain
    low, high = domain
    return (
        isinstance(value, (int, float))
        and not isinstance(value, bool)
        and isinstance(low, (int, float))
        and isinstance(high, (int, float))
        and low <= value <= high
    )

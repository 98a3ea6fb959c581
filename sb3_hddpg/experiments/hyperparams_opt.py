"""
Search spaces of ``hddpg-cli tune``: one ``sample_*_params(trial)`` per level, in a registry, as in rl_zoo3's
``hyperparams_opt.py``; the flat level has one per algorithm (:data:`FLAT_SAMPLERS`: DDPG, TD3, SAC), so that
every flat baseline can get the same tuning effort (trials and steps per trial) before a benchmark.

Each sampler returns the *changes* to a ``zoo_configs`` block, already in the file's format (``policy_kwargs``
as a string, ``noise_type`` ``None`` for no noise), so that one function serves twice: in a trial it shapes
the block that is trained, and replayed on ``optuna.trial.FixedTrial(best.params)`` it rebuilds the block
that ``--save-config`` writes. The ranges follow rl_zoo3's DDPG/TD3 spaces, narrowed where the full range
only wastes trials on this task and a CPU: learning rates above 1e-2 diverge, and batches above 512 or
replay buffers above 3e5 cost time and memory per trial process without changing a tuning-sized run.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from sb3_hddpg.hierarchy.selection import SELECTORS

#: ``net_arch`` choices by name (rl_zoo3's names and sizes).
NET_ARCHS: dict[str, list[int]] = {"small": [64, 64], "medium": [256, 256], "big": [400, 300]}

#: Largest HAM threshold: the observation's per-link obstacle clearances lie in [0, 1], so their sum over
#: the default six links lies in [0, 6].
HAM_THRESHOLD_MAX = 6.0


def _sample_shared(trial: Any) -> dict[str, Any]:
    """
    The hyperparameters DDPG, TD3 and SAC share, with the same choices and sampled first, in this order:
    discount, learning rate, batch and buffer size, soft-update rate, update schedule.
    """
    block = {
        "gamma": trial.suggest_categorical("gamma", [0.9, 0.95, 0.98, 0.99, 0.995, 0.999]),
        "learning_rate": trial.suggest_float("learning_rate", 1e-5, 1e-2, log=True),
        "batch_size": trial.suggest_categorical("batch_size", [32, 64, 128, 256, 512]),
        "buffer_size": trial.suggest_categorical("buffer_size", [10_000, 100_000, 300_000]),
        "tau": trial.suggest_categorical("tau", [0.001, 0.005, 0.01, 0.02, 0.05, 0.08]),
        "train_freq": trial.suggest_categorical("train_freq", [1, 4, 8, 16, 32, 64]),
    }
    # As in rl_zoo3: as many gradient steps as env steps between updates, so the update-to-data ratio
    # stays 1 and only the update's granularity is tuned.
    block["gradient_steps"] = block["train_freq"]
    return block


def sample_ddpg_params(trial: Any) -> dict[str, Any]:
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
    block["policy_kwargs"] = f"dict(net_arch={NET_ARCHS[net_arch]})"
    if noise_type != "none":
        block["noise_std"] = trial.suggest_float("noise_std", 0.0, 1.0)
    return block


def sample_td3_params(trial: Any) -> dict[str, Any]:
    """
    TD3's hyperparameters: DDPG's space (as rl_zoo3's ``sample_td3_params``), so that a difference between
    the tuned DDPG and TD3 is the algorithm's (twin critics, delayed actor, target smoothing), not the
    search's. TD3's own settings stay SB3's defaults, as in ``zoo_configs/td3.yml``.

    :param trial: an ``optuna.Trial`` (or ``FixedTrial``).
    """
    return sample_ddpg_params(trial)


def sample_sac_params(trial: Any) -> dict[str, Any]:
    """
    SAC's hyperparameters: DDPG's shared ones (discount, learning rate, batch and buffer size, soft-update
    rate, update schedule, network size, same choices) plus, in place of action noise, the initial log std
    of its stochastic policy (rl_zoo3's ``log_std_init``); the entropy coefficient stays ``auto``.

    :param trial: an ``optuna.Trial`` (or ``FixedTrial``).
    """
    block = _sample_shared(trial)
    log_std_init = trial.suggest_float("log_std_init", -4.0, 1.0)
    net_arch = trial.suggest_categorical("net_arch", list(NET_ARCHS))
    block["ent_coef"] = "auto"
    block["policy_kwargs"] = f"dict(net_arch={NET_ARCHS[net_arch]}, log_std_init={log_std_init!r})"
    return block


#: Flat algorithm -> its sampler (``--level flat --algo NAME``).
FLAT_SAMPLERS: dict[str, Callable[[Any], dict[str, Any]]] = {
    "ddpg": sample_ddpg_params,
    "td3": sample_td3_params,
    "sac": sample_sac_params,
}


def sample_worker_params(trial: Any) -> dict[str, Any]:
    """A worker is a plain DDPG on its own reward: :func:`sample_ddpg_params`."""
    return sample_ddpg_params(trial)


def sample_flat_params(trial: Any) -> dict[str, Any]:
    """The flat baseline is a plain DDPG on the combined reward: :func:`sample_ddpg_params`."""
    return sample_ddpg_params(trial)


def sample_manager_params(trial: Any) -> dict[str, Any]:
    """
    The manager's DDPG plus how its action selects workers (``wrapper_kwargs``): the simplex map's
    temperature and floor, the selection mode and the option length.

    :param trial: an ``optuna.Trial`` (or ``FixedTrial``).
    """
    block = sample_ddpg_params(trial)
    block["wrapper_kwargs"] = {
        "temperature": trial.suggest_float("temperature", 0.1, 2.0, log=True),
        # Below 1/n for any n <= 9 workers, as SimplexMap requires.
        "floor": trial.suggest_float("floor", 0.0, 0.1),
        "selection": trial.suggest_categorical("selection", list(SELECTORS)),
        "option_steps": trial.suggest_categorical("option_steps", [1, 2, 4, 8]),
    }
    return block


def sample_ham_params(trial: Any) -> dict[str, Any]:
    """
    HAM's switching threshold on the sum of obstacle clearances (paper Section 4); HAM trains nothing.

    :param trial: an ``optuna.Trial`` (or ``FixedTrial``).
    """
    return {"threshold": trial.suggest_float("threshold", 0.0, HAM_THRESHOLD_MAX)}


#: Level -> its sampler, as rl_zoo3's ``HYPERPARAMS_SAMPLER``.
HYPERPARAMS_SAMPLER: dict[str, Callable[[Any], dict[str, Any]]] = {
    "worker": sample_worker_params,
    "manager": sample_manager_params,
    "flat": sample_flat_params,
    "ham": sample_ham_params,
}


def sampler_for(level: str, algo: str = "ddpg") -> Callable[[Any], dict[str, Any]]:
    """
    The sampler of a level (and, for ``flat``, of an algorithm among :data:`FLAT_SAMPLERS`).

    :raises ValueError: naming the unknown level or algorithm, or an algorithm for a DDPG-only level.
    """
    if level not in HYPERPARAMS_SAMPLER:
        raise ValueError(f"Unknown level {level!r}; choose from {list(HYPERPARAMS_SAMPLER)}")
    if level == "flat":
        if algo not in FLAT_SAMPLERS:
            raise ValueError(
                f"Unknown algorithm {algo!r} for level 'flat'; choose from {list(FLAT_SAMPLERS)}"
            )
        return FLAT_SAMPLERS[algo]
    if algo != "ddpg":
        raise ValueError(f"Level {level!r} is tuned for DDPG only; an algorithm applies to level 'flat'")
    return HYPERPARAMS_SAMPLER[level]


class _SpaceRecorder:
    """A stand-in trial that records every parameter a sampler asks for and its distribution."""

    def __init__(self) -> None:
        self.space: dict[str, tuple[str, Any]] = {}

    def suggest_categorical(self, name: str, choices: Any) -> Any:
        self.space[name] = ("choices", list(choices))
        return choices[0]

    def suggest_float(self, name: str, low: float, high: float, **_: Any) -> float:
        self.space[name] = ("range", (low, high))
        return low

    def suggest_int(self, name: str, low: int, high: int, **_: Any) -> int:
        self.space[name] = ("range", (low, high))
        return low


def search_space(level: str, algo: str = "ddpg") -> dict[str, tuple[str, Any]]:
    """
    The parameters a level's sampler can suggest: name -> ``("choices", [...])`` or ``("range", (low, high))``
    (conditional ones included, as sampled with every earlier choice at its first value).
    """
    recorder = _SpaceRecorder()
    sampler_for(level, algo)(recorder)
    return recorder.space


def check_fixed_params(level: str, fixed: dict[str, Any], algo: str = "ddpg") -> None:
    """
    Validate ``--fix`` values before a study starts: Optuna's ``PartialFixedSampler`` silently ignores
    unknown names, so a typo would tune what the user meant to hold fixed.

    :raises ValueError: naming the unknown parameter or the value outside its choices or range.
    """
    space = search_space(level, algo)
    for name, value in fixed.items():
        if name not in space:
            what = f"level {level!r}" + (f" ({algo})" if level == "flat" else "")
            raise ValueError(f"Unknown parameter {name!r} for {what}; tunable: {sorted(space)}")
        kind, domain = space[name]
        if kind == "choices" and value not in domain:
            raise ValueError(f"Expected {name} among {domain}, actually: {value!r}")
        if kind == "range" and not (
            isinstance(value, (int, float))
            and not isinstance(value, bool)
            and domain[0] <= value <= domain[1]
        ):
            raise ValueError(f"Expected {name} in [{domain[0]}, {domain[1]}], actually: {value!r}")

"""The limits on a network and its replay buffer, checked from a config file or a saved spec before SB3 allocates."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from sb3_hddpg.algorithms import NetworkShape, algorithm
from sb3_hddpg.artifacts.limits import (
    MAX_BUFFER_BYTES,
    MAX_BUFFER_SIZE,
    MAX_CRITICS,
    MAX_LAYER_SIZE,
    MAX_LAYERS,
    MAX_PARAMETERS,
    MAX_QUANTILES,
    STAND_IN_ACT_DIM,
    STAND_IN_OBS_DIM,
    LimitError,
    brief,
)


def check_buffer_size(buffer_size: object, obs_dim: int, act_dim: int, what: str) -> None:
    """A replay buffer's size: at most :data:`MAX_BUFFER_SIZE` transitions and :data:`MAX_BUFFER_BYTES` (float32)."""
    if isinstance(buffer_size, bool) or not isinstance(buffer_size, int) or buffer_size < 1:
        raise LimitError(f"{what}: expected an integer >= 1, got {brief(buffer_size)}")
    size = buffer_size * (2 * obs_dim + act_dim + 3) * 4
    if buffer_size > MAX_BUFFER_SIZE or size > MAX_BUFFER_BYTES:
        raise LimitError(
            f"{what}: {buffer_size} transitions ({size / 2**30:.1f} GiB) is over the limit of "
            f"{MAX_BUFFER_SIZE} transitions and {MAX_BUFFER_BYTES >> 30} GiB"
        )


def check_parameter_count(
    algo: str,
    obs_dim: int,
    act_dim: int,
    pi_layers: Sequence[int],
    qf_layers: Sequence[int],
    n_critics: int | None = None,
    n_quantiles: int = 25,
    what: str = "policy_kwargs.net_arch",
) -> int:
    """
    The total parameters a spec or config would build (by the algorithm record's rule), refused over
    :data:`MAX_PARAMETERS`: each layer may be within bounds and the product not.

    :param algo: a registered algorithm, by name or spec class name (any case).
    :param obs_dim: the flattened observation size.
    :param act_dim: action dimensions (a Box's size) or actions (a Discrete's ``n``).
    :param pi_layers: the actor's (or Q-network's) hidden layers.
    :param qf_layers: the critics' (or value function's) hidden layers.
    :param n_critics: the critics (``None``: the algorithm's default).
    :param n_quantiles: quantiles per critic output (distributional critics only).
    :param what: the field, for the message.
    :return: the count; raises :class:`LimitError` otherwise.
    """
    shape = NetworkShape(obs_dim, act_dim, pi_layers, qf_layers, n_critics, n_quantiles)
    total = algorithm(algo).parameter_count(shape)
    if total > MAX_PARAMETERS:
        raise LimitError(
            f"{what}: the networks would have {total:,} parameters, over the limit of {MAX_PARAMETERS:,}"
        )
    return total


def check_network_size(
    algo: str,
    policy_kwargs: object,
    obs_dim: int = STAND_IN_OBS_DIM,
    act_dim: int = STAND_IN_ACT_DIM,
    what: str = "policy_kwargs",
    max_layers: int = MAX_LAYERS,
    max_layer_size: int = MAX_LAYER_SIZE,
) -> int:
    """
    The one check of a network's shape before SB3 allocates it, for config files and saved specs alike: the
    layers, ``n_critics``, ``n_quantiles`` and the total parameters (:func:`check_parameter_count`).

    :param algo: a registered algorithm, by name or spec class name (any case).
    :param policy_kwargs: the policy's keyword arguments (anything but a mapping: nothing to check).
    :param obs_dim: the observation's width (default: a stand-in when the env is not known yet).
    :param act_dim: the action's width.
    :param what: where the value comes from, for the message.
    :param max_layers: most hidden layers (a config's :data:`MAX_LAYERS`, a spec's :data:`MAX_SPEC_LAYERS`).
    :param max_layer_size: widest hidden layer.
    :return: the parameter count; raises :class:`LimitError` naming the first value over its limit.
    """
    if not isinstance(policy_kwargs, Mapping):
        return 0
    record = algorithm(algo)
    net_arch = policy_kwargs.get("net_arch", list(record.default_net_arch))
    if isinstance(net_arch, Mapping):
        pi, qf = net_arch.get("pi", []), net_arch.get(record.critic_layers, [])
    else:
        pi = qf = net_arch
    if not all(
        isinstance(layers, (list, tuple)) and len(layers) <= max_layers for layers in (pi, qf)
    ) or not all(_is_int_in(size, max_layer_size) for size in (*pi, *qf)):
        raise LimitError(
            f"{what}: expected net_arch to be lists of at most {max_layers} layer sizes in "
            f"[1, {max_layer_size}], actually: {brief(net_arch)}"
        )
    n_critics = policy_kwargs.get("n_critics", record.default_n_critics)
    n_quantiles = policy_kwargs.get("n_quantiles", 25)
    if not _is_int_in(n_critics, MAX_CRITICS) or not _is_int_in(n_quantiles, MAX_QUANTILES):
        raise LimitError(
            f"{what}: expected n_critics in [1, {MAX_CRITICS}] and n_quantiles in [1, {MAX_QUANTILES}], "
            f"actually: {brief(n_critics)} and {brief(n_quantiles)}"
        )
    return check_parameter_count(
        algo, obs_dim, act_dim, pi, qf, n_critics=n_critics, n_quantiles=n_quantiles, what=f"{what}.net_arch"
    )


def _is_int_in(value: object, maximum: int) -> bool:
    """``value`` is an int (not a bool) in ``[1, maximum]``."""
    return isinstance(value, int) and not isinstance(value, bool) and 1 <= value <= maximum

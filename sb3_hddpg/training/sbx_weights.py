"""
Weights between an SBX (JAX) model and the SB3 model of the same algorithm, both ways.

SBX keeps each network's parameters in a flax train state, with layers named by kind and creation order
(``Dense_0``, ``BatchRenorm_1``...); SB3 keeps them in torch modules. Both build a network's layers in the
same forward order, so the conversion pairs the k-th torch ``Linear`` (``BatchRenorm1d``) of a network with
its flax ``Dense_k`` (``BatchRenorm_k``): one rule for every algorithm. What differs between algorithms is
where SBX keeps its networks, which the algorithm record names as its ``sbx_layout`` and :data:`LAYOUTS`
describes: whether the actor has a target copy, whether the critics are one state stacked by ``vmap`` or one
state each, and whether batch renormalisation statistics travel with the weights.

Nothing here imports ``jax`` at import time.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch as th
from sb3_contrib.common.torch_layers import BatchRenorm

from sb3_hddpg.algorithms import Algorithm


@dataclass(frozen=True)
class SbxLayout:
    """
    Where an SBX algorithm keeps its networks.

    :param actor_target: the actor has target parameters (DDPG, TD3).
    :param critic_states: the policy's critic train states: one (critics stacked by ``vmap``) or one each.
    :param critic_target: the critics have target parameters (all but CrossQ).
    :param batch_stats: the train states carry batch renormalisation statistics (CrossQ).
    :param policy_kwargs: ``policy_kwargs`` both backends read the same way, beyond the common ones.
    """

    actor_target: bool = False
    critic_states: tuple[str, ...] = ("qf_state",)
    critic_target: bool = True
    batch_stats: bool = False
    policy_kwargs: frozenset[str] = frozenset()


#: ``sbx_layout`` of an algorithm record -> where SBX keeps its networks.
LAYOUTS: dict[str, SbxLayout] = {
    "deterministic": SbxLayout(actor_target=True),
    "gaussian": SbxLayout(),
    "quantile": SbxLayout(critic_states=("qf1_state", "qf2_state"), policy_kwargs=frozenset({"n_quantiles"})),
    "batch_renorm": SbxLayout(
        critic_target=False,
        batch_stats=True,
        policy_kwargs=frozenset({"batch_norm", "batch_norm_momentum", "renorm_warmup_steps"}),
    ),
}


def layout_of(record: Algorithm) -> SbxLayout:
    """The SBX layout of an algorithm SBX trains."""
    if record.sbx_layout is None:
        raise ValueError(f"SBX does not train {record.name!r} here")
    return LAYOUTS[record.sbx_layout]


def _layers(module: th.nn.Module) -> Iterator[tuple[str, th.nn.Module, str]]:
    """(name in ``module``, layer, its flax name) of every Linear and BatchRenorm, in forward order."""
    counts = {"Dense": 0, "BatchRenorm": 0}
    for name, layer in module.named_modules():
        kind = "Dense" if isinstance(layer, th.nn.Linear) else None
        if isinstance(layer, BatchRenorm):
            kind = "BatchRenorm"
        if kind is not None:
            yield name, layer, f"{kind}_{counts[kind]}"
            counts[kind] += 1


def _critic_networks(critic: th.nn.Module) -> list[str]:
    """The names of a critic's Q-networks (``qf0``, ``qf1``; TQC: ``quantile_critics.0``...)."""
    return [name for name, module in critic.named_modules() if isinstance(module, th.nn.Sequential)]


def _params(tree: Mapping[str, Any]) -> Mapping[str, Any]:
    """The layer dict of a train state's parameters (SBX nests most, not CrossQ's, under ``params``)."""
    return tree.get("params", tree)


def _stacked(tree: Mapping[str, Any]) -> Mapping[str, Any]:
    """The layers of critics stacked by ``vmap`` (its one submodule), or a single critic's own layers."""
    vmapped = [key for key in tree if key.startswith("Vmap")]
    return tree[vmapped[0]] if vmapped else tree


# ----------------------------------------------------------------------------------------------- SBX -> SB3
def _read_layers(
    state: dict[str, th.Tensor],
    prefix: str,
    module: th.nn.Module,
    params: Mapping[str, Any],
    stats: Mapping[str, Any] | None,
    index: int | None,
) -> None:
    def value(tree: Mapping[str, Any], key: str) -> th.Tensor:
        array = np.asarray(tree[key])
        return th.tensor(np.array(array if index is None else array[index]))

    for name, layer, flax_name in _layers(module):
        if isinstance(layer, th.nn.Linear):
            # flax Dense computes x @ kernel (in, out); torch Linear x @ weight.T with weight (out, in).
            state[f"{prefix}.{name}.weight"] = value(params[flax_name], "kernel").float().T.contiguous()
            state[f"{prefix}.{name}.bias"] = value(params[flax_name], "bias").float()
            continue
        state[f"{prefix}.{name}.scale"] = value(params[flax_name], "scale").float()
        state[f"{prefix}.{name}.bias"] = value(params[flax_name], "bias").float()
        if stats is not None:
            state[f"{prefix}.{name}.ra_mean"] = value(stats[flax_name], "mean").float()
            state[f"{prefix}.{name}.ra_var"] = value(stats[flax_name], "var").float()
            state[f"{prefix}.{name}.steps"] = value(stats[flax_name], "steps").long().reshape(())


def sbx_to_state_dict(model: Any, sb3_model: Any, record: Algorithm) -> dict[str, th.Tensor]:
    """
    SB3's ``policy.state_dict()`` of ``sb3_model`` (same algorithm and architecture), read from the SBX
    ``model``'s flax parameters (and batch statistics).
    """
    layout = layout_of(record)
    policy, sb3_policy = model.policy, sb3_model.policy
    state: dict[str, th.Tensor] = {}
    actor = policy.actor_state
    stats = actor.batch_stats if layout.batch_stats else None
    _read_layers(state, "actor", sb3_policy.actor, _params(actor.params), stats, None)
    if layout.actor_target:
        _read_layers(state, "actor_target", sb3_policy.actor_target, _params(actor.target_params), None, None)
    targets = [("critic", "params")] + ([("critic_target", "target_params")] if layout.critic_target else [])
    for root, attribute in targets:
        networks = _critic_networks(getattr(sb3_policy, root))
        for k, network in enumerate(networks):
            separate = len(layout.critic_states) > 1
            train_state = getattr(policy, layout.critic_states[k if separate else 0])
            params = _stacked(_params(getattr(train_state, attribute)))
            stats = _stacked(train_state.batch_stats) if layout.batch_stats else None
            module = getattr(sb3_policy, root).get_submodule(network)
            _read_layers(state, f"{root}.{network}", module, params, stats, None if separate else k)
    return state


# ----------------------------------------------------------------------------------------------- SB3 -> SBX
def _write_layers(
    state: Mapping[str, th.Tensor], prefix: str, module: th.nn.Module, params: dict[str, Any], stats: Any
) -> None:
    def array(key: str) -> np.ndarray:
        return state[f"{prefix}.{key}"].detach().cpu().numpy()

    for name, layer, flax_name in _layers(module):
        if isinstance(layer, th.nn.Linear):
            params[flax_name] = {"kernel": array(f"{name}.weight").T, "bias": array(f"{name}.bias")}
            continue
        params[flax_name] = {"scale": array(f"{name}.scale"), "bias": array(f"{name}.bias")}
        if stats is not None:
            stats[flax_name] = {
                **stats[flax_name],
                "mean": array(f"{name}.ra_mean"),
                "var": array(f"{name}.ra_var"),
                "steps": np.asarray(
                    array(f"{name}.steps"), dtype=np.asarray(stats[flax_name]["steps"]).dtype
                ),
            }


def _stack(trees: list[dict[str, Any]]) -> dict[str, Any]:
    """One tree whose leaves stack the critics' (``vmap``'s leading axis)."""
    return {
        key: _stack([tree[key] for tree in trees])
        if isinstance(trees[0][key], dict)
        else np.stack([tree[key] for tree in trees])
        for key in trees[0]
    }


def _critic_trees(
    state: Mapping[str, th.Tensor], root: str, sb3_critic: th.nn.Module, stats_template: Any
) -> list[tuple[dict[str, Any], dict[str, Any] | None]]:
    trees = []
    for network in _critic_networks(sb3_critic):
        params: dict[str, Any] = {}
        stats = None
        if stats_template is not None:
            stats = {
                key: {k: np.asarray(v)[0] for k, v in value.items()} for key, value in stats_template.items()
            }
        _write_layers(state, f"{root}.{network}", sb3_critic.get_submodule(network), params, stats)
        trees.append((params, stats))
    return trees


def _replace_layers(template: Any, layers: Mapping[str, Any]) -> Any:
    """``template`` (a train state's parameters or statistics) with its layer dict replaced, as jax arrays."""
    import jax  # lazily: optional (the `fast` extra); only SBX models get here
    from flax.core import freeze, unfreeze

    tree = unfreeze(template)
    layers = jax.tree_util.tree_map(jax.numpy.asarray, dict(layers))
    if "params" in tree:
        inner = tree["params"]
        vmapped = [key for key in inner if key.startswith("Vmap")]
        if vmapped:
            inner[vmapped[0]] = layers
        else:
            tree["params"] = layers
    else:
        vmapped = [key for key in tree if key.startswith("Vmap")]
        tree = {vmapped[0]: layers} if vmapped else dict(layers)
    return tree if isinstance(template, dict) else freeze(tree)


def state_dict_to_sbx(model: Any, sb3_model: Any, record: Algorithm) -> None:
    """
    Set the SBX ``model``'s flax parameters, targets and batch statistics from ``sb3_model``'s policy (same
    algorithm and architecture): the inverse of :func:`sbx_to_state_dict`. Optimiser states start fresh
    (Adam's moments at zero, as in a new torch optimiser).
    """
    layout = layout_of(record)
    policy, sb3_policy = model.policy, sb3_model.policy
    state = sb3_policy.state_dict()

    actor_layers: dict[str, Any] = {}
    actor_stats = dict(policy.actor_state.batch_stats) if layout.batch_stats else None
    _write_layers(state, "actor", sb3_policy.actor, actor_layers, actor_stats)
    actor_params = _replace_layers(policy.actor_state.params, actor_layers)
    changes: dict[str, Any] = {"params": actor_params, "opt_state": policy.actor_state.tx.init(actor_params)}
    if layout.actor_target:
        target_layers: dict[str, Any] = {}
        _write_layers(state, "actor_target", sb3_policy.actor_target, target_layers, None)
        changes["target_params"] = _replace_layers(policy.actor_state.target_params, target_layers)
    if actor_stats is not None:
        changes["batch_stats"] = _replace_layers(policy.actor_state.batch_stats, actor_stats)
    policy.actor_state = policy.actor_state.replace(**changes)

    first = getattr(policy, layout.critic_states[0])
    template = _stacked(first.batch_stats) if layout.batch_stats else None
    roots = ["critic"] + (["critic_target"] if layout.critic_target else [])
    trees = {root: _critic_trees(state, root, getattr(sb3_policy, root), template) for root in roots}
    separate = len(layout.critic_states) > 1
    for k, name in enumerate(layout.critic_states):
        train_state = getattr(policy, name)
        # One state per critic holds that critic's own layers; one state for all stacks them.
        picked = {root: [trees[root][k]] if separate else trees[root] for root in roots}

        def combine(found: list[dict[str, Any]]) -> dict[str, Any]:
            return found[0] if separate else _stack(found)

        params = _replace_layers(train_state.params, combine([p for p, _ in picked["critic"]]))
        changes = {"params": params, "opt_state": train_state.tx.init(params)}
        if layout.critic_target:
            changes["target_params"] = _replace_layers(
                train_state.target_params, combine([p for p, _ in picked["critic_target"]])
            )
        if layout.batch_stats:
            stats = combine([s for _, s in picked["critic"] if s is not None])
            changes["batch_stats"] = _replace_layers(train_state.batch_stats, stats)
        setattr(policy, name, train_state.replace(**changes))

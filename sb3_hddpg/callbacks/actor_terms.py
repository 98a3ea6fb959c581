"""
Extra terms of a DDPG or TD3 actor's loss, on SB3 (torch) and SBX (JAX): the one place that changes it.

An actor term adds a penalty to ``-Q(s, pi(s))``, the loss DDPG and TD3 minimise over the actor. Two exist:
:class:`ActionL2Term` (the action penalty, :class:`~sb3_hddpg.callbacks.ActionL2Penalty`) and
:class:`ControllerTerm` (the distance to a hand-written controller's command,
:class:`~sb3_hddpg.callbacks.ControllerPrior`). A model holds at most one term of each kind, and any set of
them applies together:

- on SB3, ``TD3.train`` (DDPG's too) uses ``critic.q1_forward`` only for the actor's loss, so the terms are
  subtracted there, on this model's critic instance: the critic's own loss, the targets and the saved files
  are untouched (a model trained with them is a plain SB3 zip);
- on SBX, ``_train`` calls the class's jitted ``update_actor`` with the class as a static argument, so the
  model's class becomes a subclass compiled with the terms in its update (its name and module kept).
"""

from __future__ import annotations

import functools
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.td3.td3 import TD3

#: Where a torch critic keeps its original ``q1_forward`` and its terms (not parameters: never saved).
_ORIGINAL = "_sb3_hddpg_q1_forward"
_TERMS = "_sb3_hddpg_actor_terms"
#: How close to ±1 an action is taken before ``atanh``: float32 resolves it, and ``atanh`` stays finite.
_ATANH_EDGE = 1.0 - 1e-6


@dataclass(frozen=True)
class ActionL2Term:
    """
    ``coefficient * mean(a ** 2)``, or with ``margin`` the mean squared excess of ``|atanh(a)|`` over it.

    :param coefficient: the weight, > 0.
    :param margin: the pre-activation margin (``None``: the action itself is penalised).
    """

    coefficient: float
    margin: float | None = None
    kind: str = field(default="action_l2", init=False)

    def torch_penalty(self, observations: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        """Per sample, shape ``(batch, 1)``."""
        return self.coefficient * action_penalty(actions, self.margin)

    def jax_penalty(self, observations: Any, actions: Any) -> Any:
        """Over the batch, a scalar."""
        import jax.numpy as jnp

        if self.margin is None:
            return self.coefficient * jnp.mean(actions**2)
        pre = jnp.arctanh(jnp.clip(actions, -_ATANH_EDGE, _ATANH_EDGE))
        return self.coefficient * jnp.mean(jnp.maximum(jnp.abs(pre) - self.margin, 0.0) ** 2)


@dataclass(frozen=True, eq=False)
class ControllerTerm:
    """
    ``coefficient * mean((a - c(s)) ** 2)``: the squared distance of the actor's action to a controller's
    command ``c(s)`` for the same observation (a constant target: no gradient flows through the controller).

    :param coefficient: the weight, > 0.
    :param command: observations ``(batch, obs)`` -> commands ``(batch, actions)`` in the actions' range,
        as NumPy arrays.
    """

    coefficient: float
    command: Callable[[np.ndarray], np.ndarray]
    kind: str = field(default="controller", init=False)

    def torch_penalty(self, observations: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        """Per sample, shape ``(batch, 1)``."""
        target = self.command(observations.detach().cpu().numpy())
        target_tensor = torch.as_tensor(np.asarray(target), dtype=actions.dtype, device=actions.device)
        return self.coefficient * (actions - target_tensor).pow(2).mean(dim=-1, keepdim=True)

    def jax_penalty(self, observations: Any, actions: Any) -> Any:
        """Over the batch, a scalar (the command runs on the host, through ``jax.pure_callback``)."""
        import jax
        import jax.numpy as jnp

        def host(obs: Any) -> np.ndarray:
            return np.asarray(self.command(np.asarray(obs)), dtype=np.float32)

        target = jax.pure_callback(host, jax.ShapeDtypeStruct(actions.shape, jnp.float32), observations)
        return self.coefficient * jnp.mean((actions - jax.lax.stop_gradient(target)) ** 2)


ActorTerm = ActionL2Term | ControllerTerm


def action_penalty(actions: torch.Tensor, margin: float | None) -> torch.Tensor:
    """
    The action penalty per sample before its coefficient: ``mean(a ** 2)``, or with ``margin`` the mean
    squared excess of ``|atanh(a)|`` over it.

    :param actions: a batch of actions in ``[-1, 1]``, shape ``(batch, n_actions)``.
    :param margin: the pre-activation margin, or ``None``.
    :return: shape ``(batch, 1)``.
    """
    if margin is None:
        return actions.pow(2).mean(dim=-1, keepdim=True)
    pre = torch.atanh(actions.clamp(-_ATANH_EDGE, _ATANH_EDGE))
    return torch.relu(pre.abs() - margin).pow(2).mean(dim=-1, keepdim=True)


def checked_coefficient(coefficient: object) -> float:
    """An actor term's weight as a float: a finite number >= 0, else a one-line ``ValueError``."""
    if (
        isinstance(coefficient, bool)
        or not isinstance(coefficient, (int, float))
        or not (math.isfinite(coefficient) and coefficient >= 0)
    ):
        raise ValueError(f"Expected `coefficient` to be a finite number >= 0, actually: {coefficient!r:.100}")
    return float(coefficient)


def set_actor_term(model: BaseAlgorithm, kind: str, term: ActorTerm | None, why_not: str = "") -> None:
    """
    Give a DDPG/TD3 model's actor loss the term of ``kind`` (replacing one it had), or remove it (``None``).

    :param model: an SB3 or SBX ``DDPG`` or ``TD3`` (or a subclass).
    :param kind: ``action_l2`` or ``controller``.
    :param term: the term, or ``None``.
    :param why_not: what the error says to a model of another algorithm.
    :raises ValueError: a model of another algorithm.
    """
    if _is_sbx_td3(model):
        base: type = getattr(type(model), "_actor_terms_base", type(model))
        terms = {t.kind: t for t in getattr(type(model), "_actor_terms", ())}
        _set(terms, kind, term)
        model.__class__ = _sbx_class(base, tuple(terms.values())) if terms else base
        return
    if not isinstance(model, TD3):
        raise ValueError(
            f"The actor's loss terms apply to DDPG and TD3 actors, not {type(model).__name__}{why_not}"
        )
    critic = model.critic
    original = getattr(critic, _ORIGINAL, None) or critic.q1_forward
    terms = dict(getattr(critic, _TERMS, {}))
    _set(terms, kind, term)
    setattr(critic, _ORIGINAL, original)
    setattr(critic, _TERMS, terms)
    if not terms:
        critic.q1_forward = original  # type: ignore[method-assign]
        return
    active = tuple(terms.values())

    def penalised_q1(observations: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        value = original(observations, actions)
        for each in active:
            value = value - each.torch_penalty(observations, actions)
        return value

    # Replacing the bound method on this one critic instance is the point (see the module's note), which
    # mypy flags as assigning to a method.
    critic.q1_forward = penalised_q1  # type: ignore[method-assign,assignment]


def actor_terms(model: BaseAlgorithm) -> dict[str, ActorTerm]:
    """The terms a model's actor loss has, by kind."""
    if _is_sbx_td3(model):
        return {t.kind: t for t in getattr(type(model), "_actor_terms", ())}
    return dict(getattr(getattr(model, "critic", None), _TERMS, {}))


def _set(terms: dict[str, ActorTerm], kind: str, term: ActorTerm | None) -> None:
    if term is None:
        terms.pop(kind, None)
    else:
        terms[kind] = term


def _is_sbx_td3(model: object) -> bool:
    """Whether ``model`` is SBX's (JAX) TD3 or DDPG, without importing SBX when it is not in use."""
    sbx = sys.modules.get("sbx")
    return sbx is not None and isinstance(model, sbx.TD3)


@functools.cache
def _sbx_class(base: type, terms: tuple[ActorTerm, ...]) -> type:
    """
    ``base`` (SBX's TD3 or DDPG) with ``terms`` in its jitted actor update. SBX's ``_train`` calls
    ``cls.update_actor`` with the class as a static argument, so a subclass is compiled with its own update.
    """
    # Lazily: only an SBX model gets here (jax is optional and slow to import).
    import jax
    import jax.numpy as jnp

    @jax.jit
    def update_actor(actor_state: Any, qf_state: Any, observations: Any, key: Any) -> Any:
        # SBX's TD3.update_actor with the terms added to the loss.
        key, dropout_key = jax.random.split(key, 2)

        def actor_loss(params: Any) -> Any:
            actions = actor_state.apply_fn(params, observations)
            qf_pi = qf_state.apply_fn(qf_state.params, observations, actions, rngs={"dropout": dropout_key})
            loss = -jnp.min(qf_pi, axis=0).mean()
            for term in terms:
                loss = loss + term.jax_penalty(observations, actions)
            return loss

        loss, grads = jax.value_and_grad(actor_loss)(actor_state.params)
        return actor_state.apply_gradients(grads=grads), qf_state, loss, key

    # The module of the base, so that code telling SBX models from SB3 ones by module still does.
    return type(
        base.__name__,
        (base,),
        {
            "update_actor": staticmethod(update_actor),
            "_actor_terms_base": base,
            "_actor_terms": terms,
            "__module__": base.__module__,
        },
    )


__all__ = [
    "ActionL2Term",
    "ActorTerm",
    "ControllerTerm",
    "action_penalty",
    "actor_terms",
    "set_actor_term",
]

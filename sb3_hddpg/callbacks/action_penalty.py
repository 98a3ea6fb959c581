"""A penalty on the actor's actions for DDPG and TD3: keeps a deterministic actor out of tanh saturation."""

from __future__ import annotations

import functools
import math
import sys
from typing import Any

import torch
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.td3.td3 import TD3

#: Marks a critic whose ``q1_forward`` already carries the penalty (so that learning again adds none).
_MARK = "_sb3_hddpg_action_l2"


class ActionL2Penalty(BaseCallback):
    """
    Add ``coefficient * mean(a ** 2)`` to the actor's loss of a DDPG or TD3 model (``a`` = the actor's action in
    ``[-1, 1]``), as OpenAI Baselines' HER DDPG does with its ``action_l2`` for the same reason.

    **Why.** A deterministic actor's output is ``tanh`` of a linear layer, and DDPG pushes it along the
    critic's action gradient. Where that gradient keeps one sign (far from a goal, "faster is better"; or
    for a manager whose return is linear in its worker probabilities) the pre-activation grows until the
    ``tanh`` saturates at ±1 and its gradient vanishes: the actor ends bang-bang everywhere and can neither
    hold a goal within a touch radius (a bang-bang version of an IK reacher that touches on 76 % of steps
    touches on 4 %, docs/WORKERS.md) nor switch to another choice in other states. The penalty gives the
    actor's objective an interior optimum wherever the critic's slope is below ``2 * coefficient``.

    **A margin.** An L2 penalty also pulls small actions towards 0: where the critic's slope is below
    ``2 * coefficient * |a|`` the actor stops short. Near a goal the slope is small, so a penalised reacher
    stops just outside the touch radius instead of closing the last gap. With ``margin=m`` the penalty is on
    the actor's pre-activation ``u = atanh(a)`` beyond ``m`` instead: ``coefficient * mean(relu(|u| - m) ** 2)``.
    Actions within ``tanh(m)`` pay nothing (``m = 1.5``: ``|a| <= 0.905``), so the interior is the critic's
    alone, while the tanh's flat ends stay as costly as before.

    **How.** SB3's ``TD3.train`` (DDPG's too) uses ``critic.q1_forward`` only for the actor's loss, so the
    penalty is applied by wrapping that one method on this model's critic at the start of training: the
    critic's own loss, the targets and the saved files are untouched (a model trained with it is a plain
    SB3 zip). A callback, so that RL Zoo runs it from a config unchanged
    (``callback: [{sb3_hddpg.callbacks.ActionL2Penalty: {coefficient: 0.1}}]``).

    :param coefficient: the penalty's weight, finite and >= 0 (0: no penalty).
    :param margin: penalise the pre-activation beyond this (> 0) instead of the action (default: the action).
    :param verbose: SB3's verbosity.
    """

    def __init__(self, coefficient: float = 0.1, margin: float | None = None, verbose: int = 0) -> None:
        super().__init__(verbose)
        if (
            isinstance(coefficient, bool)
            or not isinstance(coefficient, (int, float))
            or not (math.isfinite(coefficient) and coefficient >= 0)
        ):
            raise ValueError(
                f"Expected `coefficient` to be a finite number >= 0, actually: {coefficient!r:.100}"
            )
        self.coefficient = float(coefficient)
        self.margin = _checked_margin(margin)

    def _on_training_start(self) -> None:
        apply_action_l2(self.model, self.coefficient, self.margin)

    def _on_step(self) -> bool:
        return True


#: How close to ±1 an action is taken before ``atanh``: float32 resolves it, and ``atanh`` stays finite.
_ATANH_EDGE = 1.0 - 1e-6


def _checked_margin(margin: object) -> float | None:
    """``margin`` as a finite float > 0, or ``None``."""
    if margin is None:
        return None
    if (
        isinstance(margin, bool)
        or not isinstance(margin, (int, float))
        or not (math.isfinite(margin) and margin > 0)
    ):
        raise ValueError(f"Expected `margin` to be a finite number > 0, actually: {margin!r:.100}")
    return float(margin)


def action_penalty(actions: torch.Tensor, margin: float | None) -> torch.Tensor:
    """
    The penalty per sample before its coefficient: ``mean(a ** 2)``, or with ``margin`` the mean squared
    excess of ``|atanh(a)|`` over it (see :class:`ActionL2Penalty`).

    :param actions: a batch of actions in ``[-1, 1]``, shape ``(batch, n_actions)``.
    :param margin: the pre-activation margin, or ``None``.
    :return: shape ``(batch, 1)``.
    """
    if margin is None:
        return actions.pow(2).mean(dim=-1, keepdim=True)
    pre = torch.atanh(actions.clamp(-_ATANH_EDGE, _ATANH_EDGE))
    return torch.relu(pre.abs() - margin).pow(2).mean(dim=-1, keepdim=True)


def apply_action_l2(model: BaseAlgorithm, coefficient: float, margin: float | None = None) -> None:
    """
    Give a DDPG/TD3 model's actor loss the action penalty (see :class:`ActionL2Penalty`); idempotent.

    :param model: an SB3 ``DDPG`` or ``TD3`` (or a subclass).
    :param coefficient: the penalty's weight (0 removes it).
    :param margin: penalise the pre-activation beyond this instead of the action (default: the action).
    """
    margin = _checked_margin(margin)
    if _is_sbx_td3(model):
        base: type = getattr(type(model), "_action_l2_base", type(model))
        model.__class__ = base if coefficient == 0 else _penalised_sbx_class(base, float(coefficient), margin)
        return
    if not isinstance(model, TD3):
        raise ValueError(
            f"The action_l2 penalty applies to DDPG and TD3 actors, not {type(model).__name__} "
            "(SAC's entropy term already keeps its actions from saturating)"
        )
    critic = model.critic
    original = getattr(critic, _MARK, None) or critic.q1_forward
    # Replacing the bound method on this one critic instance is the point (see ActionL2Penalty's "How"),
    # which mypy flags as assigning to a method.
    if coefficient == 0:
        critic.q1_forward = original  # type: ignore[method-assign]
        return

    def penalised_q1(observations: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        return original(observations, actions) - coefficient * action_penalty(actions, margin)

    critic.q1_forward = penalised_q1  # type: ignore[method-assign,assignment]
    setattr(critic, _MARK, original)


def _is_sbx_td3(model: object) -> bool:
    """Whether ``model`` is SBX's (JAX) TD3 or DDPG, without importing SBX when it is not in use."""
    sbx = sys.modules.get("sbx")
    return sbx is not None and isinstance(model, sbx.TD3)


@functools.cache
def _penalised_sbx_class(base: type, coefficient: float, margin: float | None = None) -> type:
    """
    ``base`` (SBX's TD3 or DDPG) with the penalty in its jitted actor update. SBX's ``_train`` calls
    ``cls.update_actor`` with the class as a static argument, so a subclass is compiled with its own update.
    """
    # Lazily: only an SBX model gets here (jax is optional and slow to import).
    import jax
    import jax.numpy as jnp

    def penalty(actions: Any) -> Any:
        if margin is None:
            return jnp.mean(actions**2)
        pre = jnp.arctanh(jnp.clip(actions, -_ATANH_EDGE, _ATANH_EDGE))
        return jnp.mean(jnp.maximum(jnp.abs(pre) - margin, 0.0) ** 2)

    @jax.jit
    def update_actor(actor_state: Any, qf_state: Any, observations: Any, key: Any) -> Any:
        # SBX's TD3.update_actor with the penalty added to the loss.
        key, dropout_key = jax.random.split(key, 2)

        def actor_loss(params: Any) -> Any:
            actions = actor_state.apply_fn(params, observations)
            qf_pi = qf_state.apply_fn(qf_state.params, observations, actions, rngs={"dropout": dropout_key})
            return -jnp.min(qf_pi, axis=0).mean() + coefficient * penalty(actions)

        loss, grads = jax.value_and_grad(actor_loss)(actor_state.params)
        return actor_state.apply_gradients(grads=grads), qf_state, loss, key

    # The module of the base, so that code telling SBX models from SB3 ones by module still does.
    return type(
        base.__name__,
        (base,),
        {"update_actor": staticmethod(update_actor), "_action_l2_base": base, "__module__": base.__module__},
    )

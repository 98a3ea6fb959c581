"""A penalty on the actor's actions for DDPG and TD3: keeps a deterministic actor out of tanh saturation."""

from __future__ import annotations

import math

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback

from sb3_hddpg.callbacks.actor_terms import ActionL2Term, action_penalty, checked_coefficient, set_actor_term


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

    **How.** At the start of training, as a term of the actor's loss (:mod:`.actor_terms`, on SB3 and SBX):
    the critic's own loss, the targets and the saved files are untouched (a model trained with it is a
    plain SB3 zip). A callback, so that RL Zoo runs it from a config unchanged
    (``callback: [{sb3_hddpg.callbacks.ActionL2Penalty: {coefficient: 0.1}}]``).

    :param coefficient: the penalty's weight, finite and >= 0 (0: no penalty).
    :param margin: penalise the pre-activation beyond this (> 0) instead of the action (default: the action).
    :param verbose: SB3's verbosity.
    """

    def __init__(self, coefficient: float = 0.1, margin: float | None = None, verbose: int = 0) -> None:
        super().__init__(verbose)
        self.coefficient = checked_coefficient(coefficient)
        self.margin = _checked_margin(margin)

    def _on_training_start(self) -> None:
        apply_action_l2(self.model, self.coefficient, self.margin)

    def _on_step(self) -> bool:
        return True


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


def apply_action_l2(model: BaseAlgorithm, coefficient: float, margin: float | None = None) -> None:
    """
    Give a DDPG/TD3 model's actor loss the action penalty (see :class:`ActionL2Penalty`); idempotent.

    :param model: an SB3 or SBX ``DDPG`` or ``TD3`` (or a subclass).
    :param coefficient: the penalty's weight (0 removes it).
    :param margin: penalise the pre-activation beyond this instead of the action (default: the action).
    """
    margin = _checked_margin(margin)
    term = ActionL2Term(float(coefficient), margin) if coefficient else None
    set_actor_term(
        model,
        "action_l2",
        term,
        why_not=" (SAC's entropy term already keeps its actions from saturating)",
    )


__all__ = ["ActionL2Penalty", "action_penalty", "apply_action_l2"]

"""A prior towards a hand-written controller for a DDPG or TD3 actor: learns a skill the controller shows."""

from __future__ import annotations

from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from sb3_hddpg.callbacks.actor_terms import ControllerTerm, checked_coefficient, set_actor_term
from sb3_hddpg.envs.snake.controllers import CONTROLLERS, DEFAULT_MAX_JOINT_SPEED, make_controller


class ControllerPrior(BaseCallback):
    """
    Add ``coefficient * mean((a - c(s)) ** 2)`` to the actor's loss of a DDPG or TD3 model: ``c(s)`` is a
    hand-written controller's command for the same observation (the snake arm's ``ik`` or ``jacobian``
    reacher, or its ``field`` avoider: :mod:`sb3_hddpg.envs.snake.controllers`), so the actor maximises the critic's value while it is
    pulled towards what the controller would do, on every replayed observation (with hindsight goals too:
    the controller reads the relabelled goal).

    **Why.** A goal worker learned from scratch reaches the goal but does not hold it: it swings through the
    touch radius with large commands (docs/WORKERS.md), while a damped-least-squares IK reacher holds a
    moving goal with small ones. The controller knows the kinematics the learner has to discover; the prior
    hands that knowledge over and the critic keeps what pays. This is policy regularisation towards a
    reference controller, as behaviour-regularised actor-critic methods do with a demonstrator's actions
    (TD3+BC, DDPG from demonstrations), except that the controller answers for any observation, so no
    demonstrations are stored. The learned worker is still an ordinary network: the controller is needed
    to train it, never to run it.

    **How.** At the start of training, as a term of the actor's loss (:mod:`.actor_terms`, on SB3 and SBX);
    the controller is built for the training env's observation (an ``observe`` view's own layout) and joint
    speed. The saved model is a plain SB3 zip. A callback, so that RL Zoo runs it from a config unchanged
    (``callback: [{sb3_hddpg.callbacks.ControllerPrior: {controller: ik, coefficient: 5.0}}]``).

    :param controller: the controller's name (``ik``, ``jacobian`` or ``field``).
    :param coefficient: the prior's weight, finite and >= 0 (0: no prior).
    :param verbose: SB3's verbosity.
    """

    def __init__(self, controller: str = "ik", coefficient: float = 1.0, verbose: int = 0) -> None:
        super().__init__(verbose)
        if controller not in CONTROLLERS:
            raise ValueError(f"Unknown controller {controller!r:.100}; choose from {sorted(CONTROLLERS)}")
        self.controller = controller
        self.coefficient = checked_coefficient(coefficient)

    def _on_training_start(self) -> None:
        env = self.model.get_env()
        if env is None:
            raise ValueError("The controller prior needs the model's training env, to read its observation")
        try:
            layout = _first(env.get_attr("state_layout"))
            observed = _first(env.get_attr("observed_components"))
            speed = float(_first(env.get_attr("max_joint_speed")) or DEFAULT_MAX_JOINT_SPEED)
        except AttributeError:
            raise ValueError(
                f"The {self.controller} controller drives the snake arm; the training env has no snake state layout"
            ) from None
        command = make_controller(self.controller, layout.view(observed) if observed else layout, speed)

        def commands(observations: np.ndarray) -> np.ndarray:
            return np.asarray(command.predict(np.atleast_2d(observations))[0], dtype=np.float32)

        term = ControllerTerm(self.coefficient, commands) if self.coefficient else None
        set_actor_term(self.model, "controller", term)

    def _on_step(self) -> bool:
        return True


def _first(values: list[Any]) -> Any:
    """The first env's value of a ``VecEnv.get_attr`` (every copy of one env has the same)."""
    return values[0] if values else None


__all__ = ["ControllerPrior"]

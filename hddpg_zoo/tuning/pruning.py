"""Optuna pruning during training: report each evaluation to a trial and stop when told (rl_zoo3's TrialEvalCallback)."""

from __future__ import annotations

import math
from typing import Protocol, runtime_checkable

import numpy as np
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback


def parameters_finite(model: BaseAlgorithm) -> bool:
    """Whether every weight of ``model`` (actor, critics and their targets, on either backend) is finite."""
    if type(model).__module__.split(".")[0] != "sbx":
        with th.no_grad():
            return all(bool(th.isfinite(p).all()) for p in model.policy.parameters())
    import jax  # only an SBX model gets here, and then jax is loaded already

    policy: object = model.policy
    # Every train state of the policy (the actor's and the critics', one or one per critic), and its targets.
    states = [
        value for name, value in vars(policy).items() if name.endswith("_state") and hasattr(value, "params")
    ]
    trees = [tree for state in states for tree in (state.params, getattr(state, "target_params", None))]
    leaves = [leaf for tree in trees if tree is not None for leaf in jax.tree_util.tree_leaves(tree)]
    return all(bool(np.isfinite(np.asarray(leaf)).all()) for leaf in leaves)


class Trial(Protocol):
    """What the pruner asks of an Optuna trial (``optuna.Trial``)."""

    def report(self, value: float, step: int) -> None: ...

    def should_prune(self) -> bool: ...


@runtime_checkable
class _Evaluator(Protocol):
    """What the pruner reads of its parent: the last evaluation's mean reward (``EvalCallback`` has it)."""

    last_mean_reward: float


class TrialPruningCallback(BaseCallback):
    """
    Report every evaluation of its parent :class:`~sb3_hddpg.callbacks.MetricsEvalCallback` to an Optuna trial,
    and stop training when the trial's pruner says so or when the agent has diverged.

    Like rl_zoo3's ``TrialEvalCallback``, but hooked as the evaluator's ``callback_after_eval`` instead of
    subclassing the evaluator, so that evaluation, history and best-model keeping stay in one place and
    the same training code runs with or without Optuna. Training stops by returning ``False``; the
    objective then reads :attr:`is_pruned` and :attr:`diverged` and raises ``optuna.TrialPruned``, since
    raising inside SB3's loop would skip the clean-up of ``train_agent``.

    The ``step`` of each report is the evaluation's index (1, 2, ...), as in rl_zoo3, so that pruners'
    warm-up settings read in evaluations whatever the budget.

    :param trial: the Optuna trial to report to.
    :param step_offset: added to each report's step: a trial that trains several seeds reports its k-th run
        from ``k * (n_evaluations + 1) + 1`` on, so that no step is reported twice.
    :param verbose: SB3's verbosity.
    """

    def __init__(self, trial: Trial, step_offset: int = 0, verbose: int = 0) -> None:
        super().__init__(verbose)
        self.trial = trial
        self.step_offset = step_offset
        self.eval_idx = 0
        self.is_pruned = False
        #: Why the agent counts as diverged (``None`` while it has not).
        self.diverged: str | None = None

    def _on_step(self) -> bool:
        evaluator = self.parent
        if not isinstance(evaluator, _Evaluator):
            raise RuntimeError("TrialPruningCallback must be a MetricsEvalCallback's callback_after_eval")
        mean_reward = float(evaluator.last_mean_reward)
        self.eval_idx += 1
        # A NaN reward or weight never recovers; stopping now saves the rest of the budget.
        if not math.isfinite(mean_reward):
            self.diverged = f"mean evaluation reward is {mean_reward} at {self.num_timesteps} steps"
            return False
        if not parameters_finite(self.model):
            self.diverged = f"non-finite weights at {self.num_timesteps} steps"
            return False
        self.trial.report(mean_reward, self.step_offset + self.eval_idx)
        if self.trial.should_prune():
            self.is_pruned = True
            return False
        return True

    def check_divergence(self) -> str | None:
        """Why the model has diverged, looking at its weights now (for exceptions raised mid-training)."""
        # SB3 sets ``model`` only in ``init_callback``: training may have failed before that.
        model = getattr(self, "model", None)
        if self.diverged is None and model is not None and not parameters_finite(model):
            self.diverged = f"non-finite weights at {self.num_timesteps} steps"
        return self.diverged

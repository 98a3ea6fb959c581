"""One episode's metrics (:class:`EpisodeMetrics`), counted one env step at a time (:class:`EpisodeTally`)."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sb3_hddpg.envs.contract import TermNormaliser

#: An action entry at least this far out in [-1, 1] counts as saturated: a tanh actor there has almost no
#: gradient left (``1 - 0.99**2`` = 2 % of its slope at 0), so it has stopped learning that output.
SATURATION_LEVEL = 0.99


@dataclass
class EpisodeMetrics:
    """The metrics of one episode."""

    seed: int
    reward: float
    length: int
    #: Per reward term, its raw episode sum.
    term_rewards: dict[str, float]
    #: Per step every reward term normalised to [0, 1] with the env's bounds and summed (the common metric).
    reach_reward: float
    #: The snake env's touch and collision metrics, ``None`` where ``info`` does not report them.
    goal_touch_rate: float | None = None
    goal_touched: bool | None = None
    collisions: int | None = None
    success: bool | None = None
    min_clearance: float | None = None
    selections: dict[str, int] = field(default_factory=dict)
    #: The share of the deciding network's outputs (a hierarchy's manager's) with ``|a| >= SATURATION_LEVEL``;
    #: ``None`` where that output is an index.
    action_saturation: float | None = None
    #: Worker choices made with the nearest obstacle within ``near_clearance``, and with none within
    #: ``clear_clearance`` (see :func:`~sb3_hddpg.evaluation.evaluate`).
    selections_near: dict[str, int] = field(default_factory=dict)
    selections_clear: dict[str, int] = field(default_factory=dict)
    #: A hierarchy's contact steps by the worker that acted in them (where the env reports collisions).
    collisions_by_worker: dict[str, int] = field(default_factory=dict)


def finite_episode(metrics: EpisodeMetrics) -> EpisodeMetrics:
    """``metrics`` if its rewards are finite; else a ``ValueError`` naming the first that is not (never averaged)."""
    values = {"reward": metrics.reward, "reach_reward": metrics.reach_reward, **metrics.term_rewards}
    for name, value in values.items():
        if not math.isfinite(value):
            raise ValueError(
                f"evaluation: episode with seed {metrics.seed} has {name} = {value} (the env's rewards or its "
                "term bounds give non-finite values); nothing was written"
            )
    return metrics


class EpisodeTally:
    """One episode's sums for :func:`~sb3_hddpg.evaluation.evaluate`, one env step (and one decision) at a time."""

    def __init__(
        self,
        normaliser: TermNormaliser,
        worker_names: list[str],
        near_clearance: float | None,
        clear_clearance: float | None,
        reset_info: dict[str, Any],
    ) -> None:
        self.normaliser = normaliser
        self.every_term = [(term, 1.0) for term in normaliser.bounds]
        self.near_clearance = near_clearance
        self.clear_clearance = clear_clearance
        self.reward = self.reach = 0.0
        self.term_sums = dict.fromkeys(normaliser.bounds, 0.0)
        self.touches = self.collisions = self.steps = self.saturated = self.entries = 0
        # The snake env's metrics, counted only where the env reports them.
        self.reports_touches = self.reports_clearance = False
        self.min_clearance = np.inf
        # A hierarchy's every worker gets a share, 0 for one never chosen (an argmax manager may pick one).
        self.selections: Counter[str] = Counter(dict.fromkeys(worker_names, 0))
        self.near: Counter[str] = Counter()
        self.clear: Counter[str] = Counter()
        self.contacts: Counter[str] = Counter()
        # The clearance of the state the policy acts in: the previous step's (or the reset's) info.
        self.clearance = float(reset_info.get("min_clearance", math.nan))

    def add_decision(self, decision: np.ndarray) -> None:
        """The deciding network's output: how many of its entries are saturated (none counted for an index)."""
        if not np.issubdtype(decision.dtype, np.floating):
            return
        self.saturated += int(np.count_nonzero(np.abs(decision) >= SATURATION_LEVEL))
        self.entries += decision.size

    def add_env_step(self, reward: float, info: dict[str, Any], selected: str | None) -> None:
        """
        One ``env.step``: each env step of a manager's option is counted with its undiscounted reward.

        :param selected: the worker a hierarchy chose (``None``: not a hierarchy; a wrapper's ``info`` says).
        """
        selected = info.get("selected_worker") or selected
        if "option_infos" in info:
            for step_reward, step_info in zip(info["option_rewards"], info["option_infos"], strict=True):
                self.add_step(float(step_reward), step_info, selected)
        else:
            self.add_step(reward, info, selected)

    def add_step(self, reward: float, info: dict[str, Any], selected: str | None) -> None:
        """One env step: its reward, the env's ``info`` and the worker that acted (``None``: not a hierarchy)."""
        self.steps += 1
        self.reward += reward
        terms = info["reward_terms"]
        for term in self.term_sums:
            self.term_sums[term] += terms[term]
        self.reach += self.normaliser.weighted_sum(terms, self.every_term)
        if "goal_touched" in info and "collision" in info:
            self.reports_touches = True
            self.touches += bool(info["goal_touched"])
            self.collisions += bool(info["collision"])
        if "min_clearance" in info:
            self.reports_clearance = True
            self.min_clearance = min(self.min_clearance, info["min_clearance"])
        if selected is not None:
            self.selections[selected] += 1
            self.contacts[selected] += bool(info.get("collision", False))
            if self.near_clearance is not None and self.clearance <= self.near_clearance:
                self.near[selected] += 1
            if self.clear_clearance is not None and self.clearance >= self.clear_clearance:
                self.clear[selected] += 1
        self.clearance = float(info.get("min_clearance", math.nan))

    def metrics(self, seed: int) -> EpisodeMetrics:
        """The episode's metrics."""
        touched = self.reports_touches
        return EpisodeMetrics(
            seed=seed,
            reward=self.reward,
            length=self.steps,
            term_rewards={term: float(v) for term, v in self.term_sums.items()},
            reach_reward=self.reach,
            goal_touch_rate=self.touches / self.steps if touched else None,
            goal_touched=self.touches > 0 if touched else None,
            collisions=self.collisions if touched else None,
            success=self.touches > 0 and self.collisions == 0 if touched else None,
            min_clearance=float(self.min_clearance) if self.reports_clearance else None,
            selections=dict(self.selections),
            action_saturation=self.saturated / self.entries if self.entries else None,
            selections_near=dict(self.near),
            selections_clear=dict(self.clear),
            collisions_by_worker=dict(self.contacts) if touched else {},
        )

"""
What a front is made of, on any env: its points, the planes they are placed in, and a set's hypervolume.

A front is measured on an env described by a :class:`FrontSpec`: its terms (one worker each), the planes its
points are placed in, each plane's fixed reference point, the preferences swept (``ratio-sweep`` over the
terms) and the env's hand-written rule, if it has one (HAM on the snake arm, the time-to-collision switch on
highway-env). The planes:

- ``outcomes`` (the snake arm only): goal touch rate, to maximise; contacts per episode, to minimise;
- ``terms``: per term, the per-step mean of its normalised reward (each in [0, 1], to maximise);
- ``returns`` (another env): per term, its mean episode sum in the env's own units (the vector return a
  MORL library scores), to maximise; its reference is each term's lower bound times the episode's steps,
  the least return the declared bounds allow.

A set's hypervolume is pymoo's (:class:`pymoo.indicators.hv.HV`), in as many dimensions as the plane has.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import cast

import numpy as np

from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID
from sb3_hddpg.hierarchy.conditioning import PreferenceSpace

#: One objective of a plane: the point's key, and whether larger is better.
Objective = tuple[str, bool]

#: The snake's planes: per plane, its objectives.
PLANES: dict[str, tuple[Objective, ...]] = {
    "outcomes": (("goal_touch_rate", True), ("contacts_per_episode", False)),
    "terms": (("goal_term", True), ("avoid_term", True)),
}
#: Per env, each plane's reference point (the worst point counted): fixed, so hypervolumes compare across
#: runs. The snake: no touch and 20 contacts per episode (the goal worker alone makes about 14); both
#: normalised terms at 0 (their least value per step).
REFERENCE_POINTS: dict[str, dict[str, tuple[float, ...]]] = {
    SNAKE_REACH_ENV_ID: {"outcomes": (0.0, 20.0), "terms": (0.0, 0.0)},
}
#: The safe end of the snake's trade-off: a front's most goal touch with at most this many contacts.
SAFE_CONTACTS = 2.0


@dataclass(frozen=True)
class FrontSpec:
    """
    What a front measures on one env.

    :param terms: the env's terms, one worker each, in the manager's action order.
    :param planes: plane -> its objectives (:data:`Objective`).
    :param references: plane -> its reference point, in the objectives' own units.
    :param rule: the env's hand-written switch whose threshold sweep is a member (``ham``, ``ttc``), if any.
    :param sweep_form: the preferences the managers are trained over and measured at, as
        :meth:`PreferenceSpace.parse <sb3_hddpg.hierarchy.conditioning.PreferenceSpace.parse>` reads them.
    """

    terms: tuple[str, ...]
    planes: Mapping[str, tuple[Objective, ...]]
    references: Mapping[str, tuple[float, ...]]
    rule: str | None = None
    sweep_form: str = "ratio-sweep"
    sweep: PreferenceSpace = field(init=False, compare=False)

    def __post_init__(self) -> None:
        if len(self.terms) < 2:
            raise ValueError(f"A front needs at least two terms, actually: {list(self.terms)}")
        if set(self.planes) != set(self.references):
            raise ValueError(
                f"Expected a reference per plane {list(self.planes)}, actually: {list(self.references)}"
            )
        object.__setattr__(self, "sweep", PreferenceSpace.parse(self.sweep_form, self.terms))

    @property
    def members(self) -> tuple[str, ...]:
        """The members of a front, in the order of the tables and figures: managers, rule, workers alone."""
        return ("conditioned", "per-preference", *((self.rule,) if self.rule else ()), *self.terms)

    @property
    def pairs(self) -> tuple[tuple[str, str], ...]:
        """The paired comparisons: the conditioned manager against every other member."""
        return tuple(("conditioned", member) for member in self.members[1:])


#: The snake arm's front: HAM's threshold sweep as its rule.
SNAKE_FRONT = FrontSpec(("goal", "avoid"), PLANES, REFERENCE_POINTS[SNAKE_REACH_ENV_ID], rule="ham")


def env_front(
    terms: Sequence[str],
    bounds: Mapping[str, Sequence[float]],
    episode_steps: int | None,
    rule: str | None = None,
) -> FrontSpec:
    """
    The front of another env: the ``terms`` plane and, when episodes have a known length, the ``returns``
    plane referenced at each term's least return the declared ``bounds`` allow over ``episode_steps``.
    """
    terms = tuple(terms)
    planes: dict[str, tuple[Objective, ...]] = {"terms": tuple((f"{t}_term", True) for t in terms)}
    references: dict[str, tuple[float, ...]] = {"terms": (0.0,) * len(terms)}
    if episode_steps:
        planes["returns"] = tuple((f"{t}_return", True) for t in terms)
        references["returns"] = tuple(float(bounds[t][0]) * episode_steps for t in terms)
    return FrontSpec(terms, planes, references, rule=rule)


@dataclass(frozen=True)
class FrontPoint:
    """
    One policy's point on a front.

    :param label: what it is (a preference, a threshold, a worker).
    :param values: the point's figures: ``mean_reach_reward`` (the episode sum of the normalised terms, the
        benchmark's metric); per term ``TERM_term`` (the per-step mean of its normalised reward) and
        ``TERM_return`` (its mean episode sum); on the snake also ``goal_touch_rate`` and
        ``contacts_per_episode``.
    """

    label: str
    values: Mapping[str, float]

    @classmethod
    def of(
        cls,
        label: str,
        summary: Mapping[str, float],
        bounds: Mapping[str, Sequence[float]],
        terms: Sequence[str] = SNAKE_FRONT.terms,
    ) -> FrontPoint:
        """The point of an evaluation summary (:meth:`~sb3_hddpg.evaluation.EvaluationResult.summary`)."""
        values: dict[str, float] = {}
        if "goal_touch_rate" in summary:
            values["goal_touch_rate"] = float(summary["goal_touch_rate"])
            values["contacts_per_episode"] = float(summary["collisions_per_episode"])
        for term in terms:
            low, high = bounds[term]
            episode_sum = float(summary[f"mean_{term}_reward"])
            values[f"{term}_term"] = (episode_sum / summary["mean_length"] - low) / (high - low)
            values[f"{term}_return"] = episode_sum
        values["mean_reach_reward"] = float(summary["mean_reach_reward"])
        return cls(label, values)

    def record(self) -> dict[str, float | str]:
        """The point as a record writes it: ``{"label": ..., key: value, ...}``."""
        return {"label": self.label, **self.values}


def _objective_matrix(
    points: Sequence[FrontPoint | Mapping[str, object]], objectives: Sequence[Objective]
) -> np.ndarray:
    """The points' objectives, each negated where larger is better (pymoo minimises)."""
    rows = [p.values if isinstance(p, FrontPoint) else p for p in points]
    sign = np.array([-1.0 if larger else 1.0 for _, larger in objectives])
    values = np.array(
        [[float(cast(float, row[key])) for key, _ in objectives] for row in rows], dtype=np.float64
    )
    return values.reshape(len(rows), len(objectives)) * sign


def hypervolume(
    points: Sequence[FrontPoint | Mapping[str, object]],
    objectives: Sequence[Objective],
    reference: Sequence[float],
) -> float:
    """
    The hypervolume of a set of points in one plane, against ``reference`` (pymoo's exact indicator).

    :param points: the set's points (dominated ones add nothing; points worse than the reference neither).
    :param objectives: the plane's objectives (e.g. ``PLANES["outcomes"]``).
    :param reference: the plane's reference point, in the objectives' own units.
    """
    from pymoo.indicators.hv import HV  # imported when measured: pymoo loads numba-free but not instantly

    if not points:
        return 0.0
    sign = np.array([-1.0 if larger else 1.0 for _, larger in objectives])
    return float(
        HV(ref_point=sign * np.asarray(reference, dtype=np.float64))(_objective_matrix(points, objectives))
    )


def non_dominated(
    rows: Sequence[Mapping[str, object]], objectives: Sequence[Objective]
) -> list[Mapping[str, object]]:
    """The rows no other row dominates in ``objectives`` (at least as good in each, better in one)."""
    values = _objective_matrix(rows, objectives)  # minimised
    return [
        row
        for row, own in zip(rows, values)
        if not any(np.all(other <= own) and np.any(other < own) for other in values)
    ]


def member_fields(points: Sequence[FrontPoint], spec: FrontSpec = SNAKE_FRONT) -> dict[str, object]:
    """A member's record: its points and its hypervolume in each of ``spec``'s planes."""
    return {
        "points": [p.record() for p in points],
        "hypervolume": {
            plane: hypervolume(points, objectives, spec.references[plane])
            for plane, objectives in spec.planes.items()
        },
    }


def preference_label(factors: Mapping[str, float]) -> str:
    """A preference as the front's records and exports write it: ``goal=1.6,avoid=0.4``."""
    return ",".join(f"{name}={float(value):.4g}" for name, value in factors.items())


def sweep_labels(space: PreferenceSpace = SNAKE_FRONT.sweep) -> list[str]:
    """A sweep's preferences as text, ``goal=1.6,avoid=0.4`` ..."""
    return [preference_label(dict(zip(space.names, p))) for p in space.points]


def label_factors(label: str) -> dict[str, float]:
    """The factors of a preference label (:func:`preference_label`'s inverse)."""
    return {name: float(value) for name, _, value in (part.partition("=") for part in label.split(","))}


def safe_touch(points: Sequence[Mapping[str, object]], contacts: float = SAFE_CONTACTS) -> float | None:
    """
    The most goal touch among a snake front's ``points`` with at most ``contacts`` contacts per episode: what
    the front offers a user who cannot afford more (``None``: no point is that safe, or not a snake front).
    """
    touches = [
        float(cast(float, p["goal_touch_rate"]))
        for p in points
        if "contacts_per_episode" in p and float(cast(float, p["contacts_per_episode"])) <= contacts
    ]
    return max(touches) if touches else None


def safe_best_reach(
    points: Sequence[Mapping[str, object]], contacts: float = SAFE_CONTACTS
) -> dict[str, float] | None:
    """
    The point of highest reach reward among a snake front's ``points`` with at most ``contacts`` contacts per
    episode, as ``{"reach": ..., "touch": ...}``: what the safe end costs in reward, and the touch it keeps
    (``None``: no point is that safe, or not a snake front).
    """
    safe = [
        p
        for p in points
        if "contacts_per_episode" in p and float(cast(float, p["contacts_per_episode"])) <= contacts
    ]
    if not safe:
        return None
    best = max(safe, key=lambda p: float(cast(float, p["mean_reach_reward"])))
    return {
        "reach": float(cast(float, best["mean_reach_reward"])),
        "touch": float(cast(float, best["goal_touch_rate"])),
    }


__all__ = [
    "PLANES",
    "REFERENCE_POINTS",
    "SAFE_CONTACTS",
    "SNAKE_FRONT",
    "FrontPoint",
    "FrontSpec",
    "Objective",
    "env_front",
    "hypervolume",
    "label_factors",
    "member_fields",
    "non_dominated",
    "preference_label",
    "safe_best_reach",
    "safe_touch",
    "sweep_labels",
]

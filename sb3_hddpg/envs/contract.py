"""
The env contract: what an environment declares so that workers and a manager can be trained on it.

- ``reward_bounds``: term name -> its per-step ``(low, high)``, finite, ``low < high``;
- ``normalise_terms(terms)``: each raw term min-max normalised to [0, 1] (:class:`TermNormaliser`);
- ``info["reward_terms"]`` at every step: term name -> raw value;
- optionally ``state_layout``: a :class:`~sb3_hddpg.envs.layout.StateLayout` naming slices of the
  observation (absent: the whole observation is one component, ``"state"``);
- optionally ``proximity``: a :class:`Proximity` (absent: no clearance bands nor clearance panels).

:func:`env_contract` resolves any env, wrapped or not, to the object that declares the contract.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol, TypeVar, runtime_checkable

import gymnasium as gym
import numpy as np

from sb3_hddpg.envs.layout import StateLayout

T = TypeVar("T")


@runtime_checkable
class RewardTermsEnv(Protocol):
    """
    An env with named reward terms (see the module docstring): the contract every env of a hierarchy meets.
    A class complies by having the two members below and putting its raw terms in ``info["reward_terms"]``.
    """

    #: term name -> per-step ``(low, high)`` of the raw term.
    reward_bounds: Mapping[str, tuple[float, float]]

    def normalise_terms(self, terms: Mapping[str, float]) -> dict[str, float]:
        """Each raw term min-max normalised to [0, 1] with :attr:`reward_bounds`."""
        ...


@dataclass(frozen=True)
class Proximity:
    """
    An optional capability of an env: at every step (and reset) ``info["min_clearance"]`` holds the gap
    between the agent and the nearest obstacle surface, and ``info["distance_to_goal"]`` the distance to its
    goal. The snake arm declares it; an env without obstacles does not.

    :param sensor_range: the range of the proximity sensors: at a clearance at or beyond it nothing is
        sensed, so a state there has "no obstacle in range" (:func:`~sb3_hddpg.evaluation.clearance_bands`).
    :param touch_radius: within this distance the goal counts as touched (``None``: no such radius).
    """

    sensor_range: float
    touch_radius: float | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.sensor_range) and self.sensor_range > 0):
            raise ValueError(f"Expected `sensor_range` finite and > 0, actually: {self.sensor_range}")
        if self.touch_radius is not None and not (
            math.isfinite(self.touch_radius) and self.touch_radius >= 0
        ):
            raise ValueError(f"Expected `touch_radius` finite and >= 0, actually: {self.touch_radius}")


def check_bounds(
    bounds: Mapping[str, Sequence[float]], what: str = "reward_bounds"
) -> dict[str, tuple[float, float]]:
    """
    Per-term bounds, checked: at least one term, names non-empty strings, ``low < high``, both finite.

    :param bounds: term name -> ``(low, high)``.
    :param what: the argument named in messages.
    :return: a copy as ``{name: (float(low), float(high))}``; raises ``ValueError`` otherwise.
    """
    if not isinstance(bounds, Mapping) or not bounds:
        raise ValueError(
            f"Expected `{what}` to map at least one term name to (low, high), actually: {bounds!r}"
        )
    checked: dict[str, tuple[float, float]] = {}
    for name, pair in bounds.items():
        if not isinstance(name, str) or not name:
            raise ValueError(f"Expected `{what}` term names to be non-empty strings, actually: {name!r}")
        try:
            low, high = (float(v) for v in pair)
        except (TypeError, ValueError):
            raise ValueError(
                f"Expected `{what}[{name!r}]` to be a pair (low, high), actually: {pair!r}"
            ) from None
        if not (math.isfinite(low) and math.isfinite(high) and low < high):
            raise ValueError(f"Expected `{what}[{name!r}]` finite with low < high, actually: ({low}, {high})")
        if not normalisable(low, high):
            raise ValueError(
                f"Expected `{what}[{name!r}]` to span a normal float width whose inverse is finite (so that "
                f"normalising neither overflows nor underflows), actually: ({low}, {high})"
            )
        checked[name] = (low, high)
    return checked


def normalisable(low: float, high: float) -> bool:
    """Whether the width is a normal float with a finite inverse, so the normaliser's scale is finite and > 0."""
    width = high - low
    return math.isfinite(width) and width >= sys.float_info.min and math.isfinite(1.0 / width)


class TermNormaliser:
    """
    The one home of term normalisation: ``(value - low) / (high - low)`` per term, with fixed bounds (not
    running statistics, so a normalised term means the same at every step of training and evaluation).

    :param bounds: term name -> per-step ``(low, high)``, finite, ``low < high``.
    """

    def __init__(self, bounds: Mapping[str, Sequence[float]]) -> None:
        self.bounds = check_bounds(bounds)
        # Precomputed so that normalising a term in a step is one multiply-add.
        self._affine = {k: (lo, 1.0 / (hi - lo)) for k, (lo, hi) in self.bounds.items()}

    def __call__(self, terms: Mapping[str, float]) -> dict[str, float]:
        """Each raw term of ``terms`` normalised (to [0, 1] when within its bounds)."""
        affine = self._affine
        return {k: (v - affine[k][0]) * affine[k][1] for k, v in terms.items()}

    def weighted_sum(self, terms: Mapping[str, float], weights: Iterable[tuple[str, float]]) -> float:
        """
        ``sum_t weight_t * normalised(term_t)``: a preference-weighted scalarisation.

        :param terms: raw terms.
        :param weights: ``(term, weight)`` pairs; terms not listed weigh 0.
        """
        affine = self._affine
        total = 0.0
        for term, weight in weights:
            low, scale = affine[term]
            total += weight * (terms[term] - low) * scale
        return total

    def episode_sum(self, term: str, raw_sum: float, length: float) -> float:
        """
        The episode sum of a normalised term from the raw sum: normalisation is affine per step, so it is
        ``(raw_sum - length * low) / (high - low)`` (also for means of sums and of lengths).
        """
        low, scale = self._affine[term]
        return (raw_sum - length * low) * scale


def find_declared(env: gym.Env, read: Callable[[gym.Env], T | None]) -> T | None:
    """What ``read`` finds on the outermost layer of ``env`` (wrappers first, then the base env) that has it."""
    layer: gym.Env | None = env
    while layer is not None:
        found = read(layer)
        if found is not None:
            return found
        layer = getattr(layer, "env", None) if isinstance(layer, gym.Wrapper) else None
    return None


def env_contract(env: gym.Env) -> RewardTermsEnv:
    """
    The object that declares ``env``'s reward terms: the outermost wrapper that does, else the base env.

    :param env: any gymnasium env, wrapped or not.
    :return: an object with ``reward_bounds`` and ``normalise_terms``.
    :raises ValueError: one line naming the env when nothing in it declares the contract.
    """
    contract = find_declared(env, lambda layer: layer if isinstance(layer, RewardTermsEnv) else None)
    if contract is None:
        raise ValueError(
            f"Expected an env that declares its reward terms (`reward_bounds` and `normalise_terms`, see "
            f"sb3_hddpg.envs.contract), actually: {env!r}; wrap an MO-Gymnasium env or an env with per-term "
            "rewards in `info` with sb3_hddpg.envs.adapters"
        )
    return contract


def state_layout_of(env: gym.Env) -> StateLayout:
    """``env``'s declared state layout, else one component ``"state"`` spanning the whole (flat) observation."""
    layout = find_declared(env, lambda layer: getattr(layer, "state_layout", None))
    if layout is None:
        return StateLayout([("state", int(np.prod(env.observation_space.shape or (0,))))])
    return layout


def proximity_of(env: gym.Env) -> Proximity | None:
    """``env``'s declared :class:`Proximity` (the outermost layer that declares one), else ``None``."""
    return find_declared(
        env, lambda layer: p if isinstance(p := getattr(layer, "proximity", None), Proximity) else None
    )


def mix_terms(
    specs: Mapping[str, str | Mapping[str, float]], preferences: Mapping[str, float]
) -> dict[str, float]:
    """
    Each term's coefficient in ``sum_w preference_w * reward_w``, the preference-weighted scalarisation of
    workers' rewards (each one term, or a mix of normalised terms over their weights' sum), so that
    :meth:`TermNormaliser.weighted_sum` computes it in one pass.

    :param specs: worker name -> its reward (a term name, or term -> weight >= 0 with a positive sum).
    :param preferences: worker name -> preference factor; missing names get 1.
    :return: term -> coefficient.
    """
    mix: dict[str, float] = {}
    for name, spec in specs.items():
        weights = {spec: 1.0} if isinstance(spec, str) else dict(spec)
        total = sum(weights.values())
        for term, weight in weights.items():
            mix[term] = mix.get(term, 0.0) + preferences.get(name, 1.0) * weight / total
    return mix

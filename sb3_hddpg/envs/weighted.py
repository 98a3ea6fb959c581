"""
Weightings of an env's reward terms (term -> weight >= 0, kept over their sum): a worker on any weighting
learns the weighted sum of the normalised terms (a per-term worker is a corner weight)::

    env = make_weighted_view("hddpg/SnakeReach-v0", {}, {"goal": 0.7, "avoid": 0.3})
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym

from sb3_hddpg.envs.contract import TermNormaliser, env_contract
from sb3_hddpg.names import MAX_NAME_CHARS

#: The prefix of a weighted worker's name (a per-term worker is named by its term).
WEIGHTED_PREFIX = "mix"


def check_term_weights(
    weights: Mapping[str, object], terms: Sequence[str], what: str = "weights"
) -> dict[str, float]:
    """
    A weighting of ``terms``, checked: known term names, each weight a finite number >= 0, a positive sum.

    :param weights: term name -> weight; terms not named weigh 0.
    :param terms: the env's terms, in order.
    :param what: the option or field named in messages.
    :return: term -> weight over the weights' sum, in the env's term order (terms of weight 0 included).
    :raises ValueError: one line naming ``what`` and the first problem.
    """
    if not isinstance(weights, Mapping) or not weights:
        raise ValueError(f"Expected `{what}` to map term names to weights, actually: {weights!r:.200}")
    unknown = sorted(str(name) for name in weights if name not in terms)
    if unknown:
        raise ValueError(f"`{what}` names unknown terms {unknown}; the env's terms are {list(terms)}")
    checked: dict[str, float] = {}
    for term in terms:
        value = weights.get(term, 0.0)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value < math.inf:
            raise ValueError(f"Expected `{what}[{term!r}]` to be a finite number >= 0, actually: {value!r}")
        checked[term] = float(value)
    total = sum(checked.values())
    if not total > 0:
        raise ValueError(f"Expected `{what}` to have a positive sum, actually: {dict(weights)}")
    return {term: value / total for term, value in checked.items()}


def parse_term_weights(text: str) -> dict[str, float]:
    """Parse ``"goal=0.7,avoid=0.3"`` into term -> number (:func:`check_term_weights` checks the values)."""
    result: dict[str, float] = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        name, sep, value = (piece.strip() for piece in part.partition("="))
        if not sep or not name:
            raise ValueError(f"Expected TERM=WEIGHT pairs separated by commas, got {part!r} in {text!r}")
        try:
            number = float(value)
        except ValueError:
            raise ValueError(f"Expected a number for the weight of {name!r}, got {value!r}") from None
        if name in result:
            raise ValueError(f"Term {name!r} weighted twice in {text!r}")
        result[name] = number
    if not result:
        raise ValueError(f"No term weights in {text!r}")
    return result


def corner_term(weights: Mapping[str, float]) -> str | None:
    """The term a weighting puts all its weight on (a per-term worker's), else ``None``."""
    heavy = [term for term, value in weights.items() if value > 0]
    return heavy[0] if len(heavy) == 1 else None


def weighted_name(weights: Mapping[str, float]) -> str:
    """
    The worker name of a checked weighting: its term for a corner weight, else ``mix-`` and each weighted
    term with its percentage (``.`` spelt ``p``: names are plain), e.g. ``mix-goal70-avoid30``.

    :raises ValueError: when the name would exceed the plain-name length.
    """
    corner = corner_term(weights)
    if corner is not None:
        return corner
    parts = [
        f"{term}{round(100 * value, 2):g}".replace(".", "p") for term, value in weights.items() if value > 0
    ]
    name = "-".join([WEIGHTED_PREFIX, *parts])
    if len(name) > MAX_NAME_CHARS:
        raise ValueError(
            f"The weighting {dict(weights)} names a worker of {len(name)} characters (at most {MAX_NAME_CHARS})"
        )
    return name


class WeightedTermsReward(gym.Wrapper[Any, Any, Any, Any]):
    """
    A contract env whose scalar reward is the weighted sum of its normalised terms: a weighted worker's view.

    :param env: an env that meets the env contract (its raw terms in ``info["reward_terms"]``).
    :param weights: term -> weight, checked by :func:`check_term_weights`.
    """

    def __init__(self, env: gym.Env, weights: Mapping[str, float]) -> None:
        contract = env_contract(env)
        self.weights = check_term_weights(weights, list(contract.reward_bounds))
        super().__init__(env)
        self._normaliser = TermNormaliser(contract.reward_bounds)
        self._pairs = tuple((term, value) for term, value in self.weights.items() if value > 0)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, _, terminated, truncated, info = self.env.step(action)
        reward = self._normaliser.weighted_sum(info["reward_terms"], self._pairs)
        return obs, float(reward), terminated, truncated, info


def make_weighted_view(env_id: str, env_kwargs: Mapping[str, Any], weights: Mapping[str, float]) -> gym.Env:
    """``gym.make(env_id, **env_kwargs)`` in a :class:`WeightedTermsReward` (module-level: picklable)."""
    return WeightedTermsReward(gym.make(env_id, **env_kwargs), weights)

"""
How a manager's action selects workers: the simplex map, one :class:`Selector` per registered mode, the
selection settings (:class:`SelectionConfig`) and the preference factors; shared by the training wrapper and
the loaded ``Hierarchy``, so that both select identically.
"""

from __future__ import annotations

import bisect
import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, fields
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np

from sb3_hddpg.artifacts.limits import (
    MAX_ITEMS,
    MAX_MANAGER_MOTION,
    MAX_PREFERENCE,
    SIMPLEX_TOLERANCE,
    LimitError,
    brief,
    check_name,
)
from sb3_hddpg.artifacts.values import WRAPPER_SETTINGS, Bound, is_finite_number
from sb3_hddpg.hierarchy.frozen import FrozenWorker
from sb3_hddpg.hierarchy.gpi import GPI_SELECTIONS
from sb3_hddpg.hierarchy.option_end import OptionEnd
from sb3_hddpg.names import PLAIN_NAME


@dataclass(frozen=True)
class SimplexMap:
    """
    Maps a manager action ``a in [-1, 1]^n`` to worker probabilities:
    ``p = floor + (1 - n * floor) * softmax(a / temperature)``.

    Because ``a`` is bounded, the softmax cannot saturate: with ``n`` workers the largest probability is
    at most ``e^(2/T) / (e^(2/T) + n - 1)`` (0.98 for two workers at the default ``T = 0.5``), and the
    floor keeps every worker selectable, so sampling keeps exploring and the manager's gradient through
    the critic never vanishes at a corner. Actions outside ``[-1, 1]`` are clipped first.

    :param n_workers: number of workers, at least 2.
    :param temperature: softmax temperature, > 0; lower is sharper.
    :param floor: the least probability of every worker, in ``[0, 1/n)``.
    """

    n_workers: int
    temperature: float = 0.5
    floor: float = 0.02

    def __post_init__(self) -> None:
        if not math.isfinite(self.temperature) or self.temperature <= 0:
            raise ValueError(
                f"Expected `temperature` to be a finite number > 0, actually: {self.temperature}"
            )
        if not (0.0 <= self.floor < 1.0 / self.n_workers):
            raise ValueError(
                f"Expected `floor` in [0, 1/n_workers) = [0, {1.0 / self.n_workers:.3g}), actually: {self.floor}"
            )

    def __call__(self, action: np.ndarray) -> np.ndarray:
        """Probabilities for an action of shape ``(n,)`` or ``(batch, n)``; rows sum to 1."""
        action = np.asarray(action, dtype=np.float64)
        rows = [self.single(row) for row in action.reshape(-1, action.shape[-1]).tolist()]
        return np.array(rows).reshape(action.shape)

    def single(self, action: list[float]) -> list[float]:
        """The same map for one action given as a list: plain Python, several times faster for a few workers."""
        inv_t = 1.0 / self.temperature
        logits = []
        for value in action:
            if not -math.inf < value < math.inf:
                raise ValueError(f"Expected a finite manager action, actually: {action}")
            logits.append((-1.0 if value < -1.0 else (1.0 if value > 1.0 else value)) * inv_t)
        top = max(logits)
        weights = [math.exp(v - top) for v in logits]
        scale = (1.0 - self.n_workers * self.floor) / sum(weights)
        return [self.floor + w * scale for w in weights]


#: A probability vector: a list (the wrapper's fast path) or an array (``Hierarchy``).
Probabilities = Sequence[float] | np.ndarray


def check_probabilities(probabilities: Probabilities, n_workers: int) -> None:
    """
    Check a selector's probabilities before a worker acts on them: one finite probability >= 0 per worker,
    summing to 1 within :data:`SIMPLEX_TOLERANCE` (a ``ValueError`` naming the shape or the sum otherwise).
    """
    values = np.asarray(probabilities, dtype=np.float64)
    if values.shape != (n_workers,):
        raise ValueError(f"Expected {n_workers} worker probabilities, actually: shape {values.shape}")
    if (
        not (np.all(np.isfinite(values)) and np.all(values >= 0))
        or abs(float(values.sum()) - 1.0) > SIMPLEX_TOLERANCE
    ):
        raise ValueError(
            f"Expected worker probabilities >= 0 summing to 1 (within {SIMPLEX_TOLERANCE}), actually: "
            f"{np.array2string(values, precision=4, threshold=8)} (sum {values.sum():.6g})"
        )


def most_probable(probabilities: Probabilities, rng: np.random.Generator) -> int:
    """
    The index of the most probable worker; an exact tie is drawn from ``rng``, never broken by position (a
    saturated manager's 0.5/0.5 states no preference, and the worker order must not decide). Only a tie draws,
    so untied choices consume no randomness.
    """
    top = max(probabilities)
    tied = [index for index, p in enumerate(probabilities) if p == top]
    return tied[0] if len(tied) == 1 else tied[int(rng.integers(len(tied)))]


class Selector:
    """
    One selection mode: which worker a probability vector chooses, and what the env receives. The base class
    is ``argmax`` (see :func:`most_probable`). A new mode is a subclass with a ``name`` decorated with
    :func:`register_selector`: the wrapper, bundles, the CLI and the tuner all read the registry.
    """

    #: The mode's name, as given to ``selection=`` and stored in bundles.
    name: ClassVar[str]

    def action_space(self, n_workers: int) -> gym.spaces.Space:
        """The manager's action space: one value per worker in ``[-1, 1]``, mapped onto the simplex."""
        return gym.spaces.Box(-1.0, 1.0, (n_workers,), dtype=np.float32)

    def probabilities(self, simplex: SimplexMap, action: object) -> list[float]:
        """
        The worker probabilities of one manager action.

        :param simplex: the map of a Box action onto the simplex (temperature and floor).
        :param action: the manager's action for one observation.
        """
        shape = np.shape(action)  # type: ignore[call-overload]
        if shape != (simplex.n_workers,):
            raise ValueError(
                f"Expected a manager action of shape ({simplex.n_workers},), one value per worker, actually: "
                f"shape {shape}"
            )
        return simplex.single(np.asarray(action, dtype=np.float64).tolist())

    def choose(self, probabilities: Probabilities, rng: np.random.Generator, deterministic: bool) -> int:
        """
        The index of the worker to run (and to report) for one probability vector.

        :param probabilities: shape ``(n,)``, summing to 1.
        :param rng: the generator to draw with (the caller's own, never the env's).
        :param deterministic: the caller asks for no sampling (an exact tie is still drawn from ``rng``).
        """
        return most_probable(probabilities, rng)

    def act(
        self, probabilities: Probabilities, chosen: int, workers: Sequence[FrozenWorker], obs: np.ndarray
    ) -> np.ndarray:
        """
        The env action for one observation.

        :param probabilities: the worker probabilities.
        :param chosen: what :meth:`choose` returned.
        :param workers: the frozen workers, in the manager's action order.
        :param obs: the shared state.
        """
        return workers[chosen].act(obs)


#: Mode name -> its selector, in registration order (the tuner's categorical choices keep this order).
SELECTORS: dict[str, Selector] = {}


def register_selector(cls: type[Selector]) -> type[Selector]:
    """Class decorator: make a :class:`Selector` subclass available by its ``name``."""
    if not isinstance(getattr(cls, "name", None), str) or not cls.name:
        raise ValueError(f"Expected a selector class with a non-empty `name`, actually: {cls!r}")
    if cls.name in SELECTORS:
        raise ValueError(f"Selection mode {cls.name!r} is already registered")
    SELECTORS[cls.name] = cls()
    return cls


def get_selector(mode: object) -> Selector:
    """The registered selector of ``mode``; a ``ValueError`` names the registered modes otherwise."""
    if not isinstance(mode, str) or mode not in SELECTORS:
        raise ValueError(f"Expected `selection` to be one of {list(SELECTORS)}, actually: {mode!r}")
    return SELECTORS[mode]


@register_selector
class SampleSelector(Selector):
    """``sample`` (the paper's): one worker drawn from the probabilities acts (the most probable if deterministic)."""

    name = "sample"

    def choose(self, probabilities: Probabilities, rng: np.random.Generator, deterministic: bool) -> int:
        if deterministic:
            return most_probable(probabilities, rng)
        # Inverse-CDF sampling with one uniform draw (no Generator.choice overhead).
        index = bisect.bisect_right(list(itertools.accumulate(probabilities)), rng.random())
        return min(index, len(probabilities) - 1)


@register_selector
class ArgmaxSelector(Selector):
    """``argmax``: the most probable worker acts (an exact tie: one of the tied at random)."""

    name = "argmax"


@register_selector
class MixSelector(Selector):
    """``mix``: every worker acts and the env gets the probability-weighted blend (the most probable is reported)."""

    name = "mix"

    def act(
        self, probabilities: Probabilities, chosen: int, workers: Sequence[FrozenWorker], obs: np.ndarray
    ) -> np.ndarray:
        return sum(p * w.act(obs) for p, w in zip(probabilities, workers))  # type: ignore[return-value]


@register_selector
class DiscreteSelector(Selector):
    """
    ``discrete``: the manager's action is the index of the worker to run (``Discrete(n)``, for DQN, QR-DQN or
    PPO managers); its choice is the corner of the simplex, probability 1 on that worker.
    """

    name = "discrete"

    def action_space(self, n_workers: int) -> gym.spaces.Space:
        return gym.spaces.Discrete(n_workers)

    def probabilities(self, simplex: SimplexMap, action: object) -> list[float]:
        index = np.asarray(action)
        if index.shape not in ((), (1,)) or not (
            np.issubdtype(index.dtype, np.integer)
            or (np.issubdtype(index.dtype, np.floating) and float(index.reshape(-1)[0]).is_integer())
        ):
            raise ValueError(
                f"Expected one worker index (a scalar integer) in [0, {simplex.n_workers}), actually: "
                f"{np.array2string(index, threshold=8)} of shape {index.shape}"
            )
        chosen = int(index.reshape(-1)[0])
        if not 0 <= chosen < simplex.n_workers:
            raise ValueError(f"Expected a worker index in [0, {simplex.n_workers}), actually: {chosen}")
        return [1.0 if i == chosen else 0.0 for i in range(simplex.n_workers)]

    def choose(self, probabilities: Probabilities, rng: np.random.Generator, deterministic: bool) -> int:
        return int(np.argmax(probabilities))


@dataclass
class SelectionConfig:
    """
    How the manager's action selects workers: the arguments of ``WorkerSelectionWrapper`` that a bundle keeps
    (see there), in JSON form.

    :param preferences: worker name -> preference factor (a conditioned manager's: the one it acts at now).
    :param selection: a registered selection mode (see :data:`SELECTORS`).
    :param option_steps: env steps per manager decision.
    :param temperature: the simplex map's temperature.
    :param floor: every worker's least probability.
    :param reward_terms: worker name -> its reward (term name or term weights).
    :param manager_state: state components the manager sees (``None``: all).
    :param worker_states: worker name -> state components it sees.
    :param option_gamma: discount inside an option.
    :param manager_preferences: a conditioned manager's :meth:`PreferenceSpace.to_json` (``None``: none).
    :param option_end: :meth:`OptionEnd.to_json` (``None``: options end after ``option_steps`` only).
    :param manager_motion: the scale of the state's change the manager observes (0: none).
    """

    preferences: dict[str, float]
    selection: str = "sample"
    option_steps: int = 1
    temperature: float = 0.5
    floor: float = 0.02
    reward_terms: dict[str, Any] = field(default_factory=dict)
    manager_state: list[str] | None = None
    worker_states: dict[str, list[str]] = field(default_factory=dict)
    option_gamma: float = 0.99
    manager_preferences: dict[str, Any] | None = None
    option_end: dict[str, Any] | None = None
    manager_motion: float = 0.0

    def wrapper_kwargs(self) -> dict[str, Any]:
        """Keyword arguments for ``WorkerSelectionWrapper`` (besides ``env`` and ``workers``)."""
        return asdict(self)


def preferences_from_bias(
    names: list[str], prefer: str | None = None, bias: float = 0.15
) -> dict[str, float]:
    """
    The paper's preference factors (Section 3.4): 1 for every worker, ``1 + bias`` for the preferred one.

    :param names: the worker names.
    :param prefer: the preferred worker (``None``: no preference).
    :param bias: the preferred worker's extra weight, e.g. 0.15 for the paper's 15 %.
    """
    if prefer is not None and prefer not in names:
        raise ValueError(f"Unknown worker {prefer!r} to prefer; workers: {names}")
    if not is_finite_number(bias) or not 0 < bias <= MAX_PREFERENCE - 1:
        raise ValueError(
            f"Expected `bias` to be a finite number at most {MAX_PREFERENCE - 1:g} and > 0, actually: {bias}"
        )
    return {name: (1.0 + bias if name == prefer else 1.0) for name in names}


def parse_preferences(text: str) -> dict[str, float]:
    """Parse ``"goal=1.15,avoid=1.0"`` into a mapping (values checked by the wrapper)."""
    result: dict[str, float] = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        name, sep, value = part.partition("=")
        name = name.strip()
        if not sep or not name:
            raise ValueError(f"Expected NAME=VALUE pairs separated by commas, got {part!r} in {text!r}")
        try:
            number = float(value)
        except ValueError:
            raise ValueError(f"Expected a number for preference {name!r}, got {value!r}") from None
        if name in result:
            raise ValueError(f"Preference {name!r} given twice in {text!r}")
        result[name] = number
    if not result:
        raise ValueError(f"No preferences in {text!r}")
    return result


def check_preferences(
    preferences: dict[str, Any], names: list[str], max_factor: float | None = MAX_PREFERENCE
) -> dict[str, float]:
    """
    Validate preference factors: known names, finite and > 0, and at most ``max_factor`` so that a weighted
    reward cannot overflow (``None``: only the ratio is used); missing names default to 1.

    :param preferences: name -> factor.
    :param names: the known names, in order.
    :param max_factor: the largest factor.
    """
    unknown = sorted(set(preferences) - set(names))
    if unknown:
        raise ValueError(f"Preferences name unknown workers {unknown}; workers: {names}")
    checked = {}
    for name in names:
        value = preferences.get(name, 1.0)
        if not is_finite_number(value) or value <= 0:
            raise ValueError(
                f"Expected preference of {name!r} to be a finite number > 0, actually: {value!r}"
            )
        if max_factor is not None and value > max_factor:
            raise ValueError(
                f"Expected preference of {name!r} to be at most {max_factor:g} (it weights a reward that "
                f"is summed over steps; only the ratio between factors matters), actually: {value!r}"
            )
        checked[name] = float(value)
    return checked


#: The keys of a bundle's selection settings.
SELECTION_SETTINGS = tuple(f.name for f in fields(SelectionConfig))


def check_selection_settings(selection: object, names: Sequence[str], what: str) -> dict[str, Any]:
    """
    A bundle's selection settings (``SelectionConfig``'s fields from the manifest), each checked for type and
    range, so that ``temperature: "abc"`` is refused by name (``what``) instead of failing later.

    :return: the checked mapping.
    """
    if not isinstance(selection, Mapping):
        raise LimitError(f"{what}: expected a mapping, got {brief(selection)}")
    unknown = sorted(str(k) for k in set(selection) - set(SELECTION_SETTINGS))
    if unknown:
        raise LimitError(f"{what}: unknown key {brief(unknown[0])}")
    out = dict(selection)
    if "selection" in out and out["selection"] not in [*SELECTORS, *GPI_SELECTIONS]:
        raise LimitError(
            f"{what}.selection: expected one of {[*SELECTORS, *GPI_SELECTIONS]}, got {brief(out['selection'])}"
        )
    _check_numbers(out, len(names), what)
    if out.get("selection") in GPI_SELECTIONS:  # GPI's preference weighs the terms, not the workers
        _check_term_weights(out.get("preferences", {}), f"{what}.preferences")
    else:
        _check_preference_factors(out.get("preferences", {}), names, f"{what}.preferences")
    for key in ("reward_terms", "worker_states"):
        if not isinstance(out.get(key, {}), Mapping):
            raise LimitError(f"{what}.{key}: expected a mapping, got {brief(out[key])}")
    for name, spec in out.get("reward_terms", {}).items():
        _check_reward_spec(name, spec, names, f"{what}.reward_terms")
    states = {"manager_state": out["manager_state"]} if out.get("manager_state") is not None else {}
    states.update({f"worker_states.{n}": s for n, s in out.get("worker_states", {}).items()})
    for key, state in states.items():
        if not (isinstance(state, list) and all(isinstance(s, str) for s in state)):
            raise LimitError(f"{what}.{key}: expected a list of names, got {brief(state)}")
    recorded = out.get("manager_preferences")  # read by PreferenceSpace.from_json
    if recorded is not None and not isinstance(recorded, Mapping):
        raise LimitError(f"{what}.manager_preferences: expected a mapping, got {brief(recorded)}")
    if out.get("option_end") is not None:
        out["option_end"] = OptionEnd.from_json(out["option_end"], f"{what}.option_end").to_json()
    return out


def _check_numbers(out: dict[str, Any], n_workers: int, what: str) -> None:
    """The numeric selection settings of a bundle, each within its range (one line naming the field)."""
    bounds = {
        **WRAPPER_SETTINGS,  # a config's bounds; a bundle's floor also leaves room for each of its workers
        "floor": Bound(float, 0.0, 1.0 / max(n_workers, 1), high_open=True),  # SimplexMap refuses 1/n
        "manager_motion": Bound(float, 0.0, MAX_MANAGER_MOTION),
    }
    for key, bound in bounds.items():
        if key in out:
            out[key] = bound.check(out[key], f"{what}.{key}")


def _check_reward_spec(name: object, spec: object, names: Sequence[str], what: str) -> None:
    """
    One worker's reward in a bundle: a known worker, paid one term (a plain name) or a weighting of terms
    (plain names -> finite numbers >= 0 with a positive sum), so that NaN weights or nested mappings are
    refused when the bundle is read, not when the reward is computed.
    """
    if name not in names:
        raise LimitError(
            f"{what}: {brief(name)} is not one of the bundle's workers {list(names)[:MAX_ITEMS]}"
        )
    if isinstance(spec, str):
        if not PLAIN_NAME.match(spec):
            raise LimitError(f"{what}.{name}: expected a term name, got {brief(spec)}")
        return
    if not isinstance(spec, Mapping) or not spec:
        raise LimitError(f"{what}.{name}: expected a term name or term -> weight, got {brief(spec)}")
    for term, weight in spec.items():
        if not isinstance(term, str) or not PLAIN_NAME.match(term):
            raise LimitError(f"{what}.{name}: expected term names, got {brief(term)}")
        if not is_finite_number(weight) or not 0 <= weight <= MAX_PREFERENCE:
            raise LimitError(
                f"{what}.{name}.{term}: expected a finite weight in [0, {MAX_PREFERENCE:g}], got {brief(weight)}"
            )
    if not sum(spec.values()) > 0:
        raise LimitError(f"{what}.{name}: expected weights with a positive sum, got {brief(dict(spec))}")


def check_reward_terms(
    reward_terms: Mapping[str, Any], names: Sequence[str], terms: Sequence[str], what: str
) -> None:
    """
    Check that each worker's reward (its ``reward_terms`` entry, a term or term -> weight, else the term of its
    own name) is among the env's declared ``terms``: a ``LimitError`` naming the worker and the term otherwise.
    """
    for name in names:
        spec = reward_terms.get(name, name)
        for term in [spec] if isinstance(spec, str) else list(spec):
            if term not in terms:
                field = f"{what}.{name}" if name in reward_terms else f"{what} (no entry for worker {name!r})"
                raise LimitError(
                    f"{field}: {brief(term)} is not one of the env's reward terms {list(terms)[:MAX_ITEMS]}"
                )


def _check_preference_factors(preferences: object, names: Sequence[str], what: str) -> None:
    """A bundle's preference factors: worker name -> a number in (0, 1e6)."""
    if not isinstance(preferences, Mapping) or set(preferences) - set(names):
        raise LimitError(f"{what}: expected worker name -> factor, got {brief(preferences)}")
    for name, value in preferences.items():
        Bound(float, 0.0, 1e6, low_open=True, high_open=True).check(value, f"{what}.{name}")


def _check_term_weights(weights: object, what: str) -> None:
    """A GPI bundle's preference: term name -> a number in [0, 1e6), at most ``MAX_ITEMS`` terms."""
    if not isinstance(weights, Mapping) or len(weights) > MAX_ITEMS:
        raise LimitError(f"{what}: expected term name -> weight, got {brief(weights)}")
    for name, value in weights.items():
        check_name(name, what)
        Bound(float, 0.0, 1e6, high_open=True).check(value, f"{what}.{name}")

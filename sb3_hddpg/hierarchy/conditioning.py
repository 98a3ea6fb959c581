"""
``PreferenceSpace``: the preferences a preference-conditioned manager is trained over and may be asked for.

A conditioned manager observes the normalised weights ``w / sum(w)`` after its state and trains with a
preference drawn every episode, so one network serves every trade-off. Every preference keeps one sum
(``total``), since the sum would scale the manager's reward: only the ratio is the preference. Two kinds:

- ``set``: preferences drawn uniformly from a list (``ratio-sweep``); at run time any preference within
  each worker's trained range of weights is accepted (trained at 4:1 and 1:4, it acts at 2:1 too);
- ``dirichlet``: ``floor + (1 - n * floor) * Dirichlet(alpha)`` scaled to ``total``; any preference whose
  normalised weights are at least ``floor`` is accepted.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sb3_hddpg.artifacts.limits import MAX_SWEEP_RATIO, LimitError, brief
from sb3_hddpg.hierarchy.selection import check_preferences, parse_preferences

#: The ratios of the ``ratio-sweep`` preset: each worker in turn weighted this many times the others.
RATIO_SWEEP = (1.0, 2.0, 3.0, 4.0)
#: The least normalised weight of a ``dirichlet`` space by default (no worker ignored completely).
DIRICHLET_FLOOR = 0.05
#: Slack for comparing normalised weights read back from JSON.
_TOLERANCE = 1e-6
#: Slack for a preference as people write it: the labels of tables and records give each factor to 4
#: significant digits, which moves a normalised weight by up to about 1e-4 (an extreme of ``ratio-sweep:16``
#: written ``goal=1.882,avoid=0.1176`` is the trained one, not a preference outside them).
WRITTEN_SLACK = 2e-4


class PreferenceOutsideError(ValueError):
    """A run-time preference outside those a conditioned manager was trained over (or any for a fixed one)."""


@dataclass(frozen=True)
class PreferenceSpace:
    """
    A distribution over preference factors with a fixed sum.

    :param names: the workers, in the manager's action order.
    :param kind: ``"set"`` or ``"dirichlet"``.
    :param total: the sum of every preference's factors.
    :param points: ``set`` only: the preferences, each a list of factors in ``names`` order summing to ``total``.
    :param alpha: ``dirichlet`` only: the concentration (1: uniform on the simplex).
    :param floor: ``dirichlet`` only: the least normalised weight, in ``[0, 1/n)``.
    """

    names: tuple[str, ...]
    kind: str = "set"
    total: float = 2.0
    points: tuple[tuple[float, ...], ...] = field(default_factory=tuple)
    alpha: float = 1.0
    floor: float = DIRICHLET_FLOOR

    def __post_init__(self) -> None:
        n = len(self.names)
        if n < 2:
            raise ValueError(
                f"Expected at least 2 workers for a preference space, actually: {list(self.names)}"
            )
        if not (math.isfinite(self.total) and self.total > 0):
            raise ValueError(
                f"Expected the preferences' sum to be a finite number > 0, actually: {self.total}"
            )
        if self.kind == "set":
            if len(self.points) < 2:
                raise ValueError("A conditioned manager needs at least 2 preferences to train over")
            for point in self.points:
                if len(point) != n or not all(math.isfinite(v) and v > 0 for v in point):
                    raise ValueError(
                        f"Expected {n} finite factors > 0 per preference, actually: {list(point)}"
                    )
                if abs(sum(point) - self.total) > _TOLERANCE * max(1.0, self.total):
                    raise ValueError(
                        f"Every preference must sum to {self.total:g} (the sum scales a DDPG manager's reward; "
                        f"vary the ratio, keep the sum), actually {dict(zip(self.names, point))} sums to "
                        f"{sum(point):g}"
                    )
        elif self.kind == "dirichlet":
            if not (math.isfinite(self.alpha) and self.alpha > 0):
                raise ValueError(f"Expected a Dirichlet alpha > 0, actually: {self.alpha}")
            if not 0.0 <= self.floor < 1.0 / n:
                raise ValueError(f"Expected the Dirichlet floor in [0, 1/{n}), actually: {self.floor}")
        else:
            raise ValueError(f"Unknown preference space kind {self.kind!r}; expected 'set' or 'dirichlet'")

    @classmethod
    def parse(cls, text: str, names: Sequence[str], total: float | None = None) -> PreferenceSpace:
        """
        A space from its command-line form.

        - ``ratio-sweep``: every worker in turn weighted 1, 2, 3 and 4 times the others (4:1 ... 1:4);
        - ``ratio-sweep:MAX``: the ratios double from 1 up to ``MAX``, a power of two from 2 to 1024;
        - ``dirichlet`` or ``dirichlet:ALPHA``: the Dirichlet space;
        - preferences separated by ``;``, e.g. ``goal=1.6,avoid=0.4;goal=0.4,avoid=1.6`` (names not given get 1).

        :param text: the form above.
        :param names: the workers, in the manager's action order.
        :param total: the factors' sum (default: the number of workers, the sum of the unweighted
            preference; for a list, its own sum).
        """
        names = tuple(names)
        text = text.strip()
        default_total = float(len(names)) if total is None else float(total)
        kind, _, argument = text.partition(":")
        if kind == "ratio-sweep":
            sweep = _sweep_ratios(argument) if argument else RATIO_SWEEP
            ratios = sorted(
                {
                    tuple(ratio if i == j else 1.0 for j in range(len(names)))
                    for i in range(len(names))
                    for ratio in sweep
                },
                key=lambda p: [-v / sum(p) for v in p],
            )
            points = tuple(tuple(default_total * v / sum(p) for v in p) for p in ratios)
            return cls(names, "set", default_total, points)
        if kind == "dirichlet":
            try:
                alpha = float(argument) if argument else 1.0
            except ValueError:
                raise ValueError(f"Expected dirichlet:ALPHA with a number, got {text!r}") from None
            return cls(names, "dirichlet", default_total, alpha=alpha)
        parsed = [
            check_preferences(parse_preferences(part), list(names))
            for part in text.split(";")
            if part.strip()
        ]
        if not parsed:
            raise ValueError(
                f"Expected ratio-sweep[:MAX], dirichlet[:ALPHA] or preferences separated by ';', got {text!r}"
            )
        points = tuple(tuple(p[name] for name in names) for p in parsed)
        own_total = sum(points[0]) if total is None else float(total)
        return cls(names, "set", own_total, points)

    @classmethod
    def from_json(
        cls, data: object, names: Sequence[str], what: str = "manager_preferences"
    ) -> PreferenceSpace:
        """The space a bundle records (:meth:`to_json`), checked (a one-line ``LimitError`` otherwise)."""
        if not isinstance(data, Mapping):
            raise LimitError(f"{what}: expected a mapping, got {brief(data)}")
        unknown = sorted(str(k) for k in set(data) - {"kind", "total", "points", "alpha", "floor"})
        if unknown:
            raise LimitError(f"{what}: unknown key {brief(unknown[0])}")
        points = data.get("points", [])
        if not isinstance(points, list) or len(points) > 1000:
            raise LimitError(
                f"{what}.points: expected a list of at most 1000 preferences, got {brief(points)}"
            )
        rows = []
        for point in points:
            if not isinstance(point, Mapping) or set(point) != set(names):
                raise LimitError(f"{what}.points: expected worker name -> factor, got {brief(point)}")
            rows.append(tuple(point[name] for name in names))
        numbers = [data.get("total", 2.0), data.get("alpha", 1.0), data.get("floor", DIRICHLET_FLOOR)]
        numbers += [v for row in rows for v in row]
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in numbers):
            raise LimitError(f"{what}: expected numbers, got {brief(data)}")
        try:
            return cls(
                tuple(names),
                str(data.get("kind", "set")),
                float(data.get("total", 2.0)),
                tuple(tuple(float(v) for v in row) for row in rows),
                float(data.get("alpha", 1.0)),
                float(data.get("floor", DIRICHLET_FLOOR)),
            )
        except ValueError as error:
            raise LimitError(f"{what}: {error}") from None

    def to_json(self) -> dict[str, Any]:
        """The space as a bundle's manifest records it (``selection.manager_preferences``)."""
        if self.kind == "set":
            return {
                "kind": "set",
                "total": self.total,
                "points": [dict(zip(self.names, point)) for point in self.points],
            }
        return {"kind": "dirichlet", "total": self.total, "alpha": self.alpha, "floor": self.floor}

    @property
    def default(self) -> dict[str, float]:
        """The unweighted preference at this space's sum (every factor ``total / n``)."""
        return {name: self.total / len(self.names) for name in self.names}

    def sample(self, rng: np.random.Generator) -> dict[str, float]:
        """One preference (name -> factor, summing to ``total``) drawn from the space."""
        if self.kind == "set":
            point = self.points[int(rng.integers(len(self.points)))]
            return dict(zip(self.names, point))
        return dict(zip(self.names, self.total * self._dirichlet(rng, 1)[0]))

    def sample_weights(self, rng: np.random.Generator, size: int) -> np.ndarray:
        """``size`` normalised weight vectors (rows sum to 1) drawn from the space, shape ``(size, n)``."""
        if self.kind == "set":
            table = np.asarray(self.points, dtype=np.float64) / self.total
            return table[rng.integers(len(self.points), size=size)]
        return self._dirichlet(rng, size)

    def _dirichlet(self, rng: np.random.Generator, size: int) -> np.ndarray:
        n = len(self.names)
        return self.floor + (1.0 - n * self.floor) * rng.dirichlet(np.full(n, self.alpha), size=size)

    def weights(self, preferences: Mapping[str, float]) -> np.ndarray:
        """The normalised weights ``factor / sum`` in ``names`` order (what the manager observes)."""
        values = np.array([float(preferences[name]) for name in self.names], dtype=np.float64)
        values = values / values.max()  # first: the sum of factors near the largest float would overflow
        return values / values.sum()

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Per worker, the least and largest normalised weight the space trains on."""
        n = len(self.names)
        if self.kind == "set":
            table = np.asarray(self.points, dtype=np.float64) / self.total
            return table.min(axis=0), table.max(axis=0)
        return np.full(n, self.floor), np.full(n, 1.0 - (n - 1) * self.floor)

    def check(self, preferences: Mapping[str, float]) -> dict[str, float]:
        """
        A run-time preference for a manager trained over this space, rescaled to ``total`` (only the ratio is
        observed, so the factors' size is not bounded).

        :param preferences: worker name -> factor (finite, > 0); names not given get ``total / n``.
        :raises PreferenceOutsideError: one line naming the preference and the trained-over range.
        """
        filled = {**self.default, **dict(preferences)}
        checked = check_preferences(filled, list(self.names), max_factor=None)
        weights = self.weights(checked)
        low, high = self.bounds()
        if np.any(weights < low - WRITTEN_SLACK) or np.any(weights > high + WRITTEN_SLACK):
            shown = ",".join(f"{name}={checked[name]:g}" for name in self.names)
            trained = ", ".join(
                f"{name} in [{lo:.3g}, {hi:.3g}]" for name, lo, hi in zip(self.names, low, high)
            )
            raise PreferenceOutsideError(
                f"Preference {shown} is outside those the manager was trained over (normalised weights: "
                f"{trained})"
            )
        return dict(zip(self.names, (self.total * weights).tolist()))

    def describe(self) -> str:
        """A short human-readable form, e.g. ``7 preferences, goal:avoid from 4:1 to 1:4, sum 2``."""
        if self.kind == "dirichlet":
            return f"Dirichlet(alpha={self.alpha:g}) over the simplex, weights >= {self.floor:g}, sum {self.total:g}"
        shown = "; ".join(",".join(f"{n}={v:.3g}" for n, v in zip(self.names, p)) for p in self.points)
        return f"{len(self.points)} preferences with sum {self.total:g}: {shown}"


def _sweep_ratios(argument: str) -> tuple[float, ...]:
    """The ratios of ``ratio-sweep:MAX``: 1, 2, 4, ... up to ``MAX``, a power of two in [2, 1024]."""
    try:
        largest = int(argument)
    except ValueError:
        largest = 0
    if not 2 <= largest <= MAX_SWEEP_RATIO or largest & (largest - 1):
        raise ValueError(
            f"Expected ratio-sweep:MAX with MAX a power of two from 2 to {MAX_SWEEP_RATIO}, got {argument!r:.50}"
        )
    return tuple(float(2**k) for k in range(largest.bit_length()))

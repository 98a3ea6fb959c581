"""``workers/support.json``: the support ``grow`` built, worker by worker, for the docs and for ``--resume``."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from sb3_hddpg.artifacts.limits import MAX_WORKERS, brief, check_name, read_json_record
from sb3_hddpg.artifacts.records.base import JsonObject, JsonRecord, check_version

SUPPORT_VERSION = 1  #: Schema version of ``support.json``.


@dataclass(frozen=True)
class SupportStep:
    """
    One worker the support gained.

    :param name: the worker's name.
    :param weights: its weighting of the terms.
    :param gain: the optimistic gain at that corner weight when it was chosen.
    :param value: the front's scalarised value there before it was added.
    :param steps: env steps it trained.
    :param warm_start: the neighbour it started from (``None``: a cold start).
    :param replay: transitions of the neighbour it was given, relabelled with its weights.
    """

    name: str
    weights: Mapping[str, float]
    gain: float
    value: float
    steps: int
    warm_start: str | None = None
    replay: int = 0

    def to_json(self) -> JsonObject:
        return asdict(self)


@dataclass(frozen=True, eq=False)
class SupportRecord(JsonRecord):
    """
    The support a ``grow`` run built over a workers folder.

    :param terms: the reward terms, in order.
    :param budget: the total env steps its new workers may train.
    :param size: the most workers it grows to.
    :param tolerance: the relative gain below which it stops.
    :param start: the workers it started from.
    :param added: the workers it added, in order.
    :param worker_values: worker name -> its estimated vector value (discounted normalised terms, in term order).
    :param stopped: why it stopped (empty while it runs).
    :param schema_version: the file's schema version.
    """

    terms: Sequence[str]
    budget: int
    size: int
    tolerance: float
    start: Sequence[str]
    added: Sequence[SupportStep] = ()
    worker_values: Mapping[str, Sequence[float]] = field(default_factory=dict)
    stopped: str = ""
    schema_version: int = SUPPORT_VERSION

    @property
    def steps_used(self) -> int:
        """Env steps the added workers trained, together."""
        return sum(step.steps for step in self.added)

    def with_step(self, step: SupportStep) -> SupportRecord:
        """This record with ``step`` added (replacing an earlier step of the same worker)."""
        return replace(self, added=[*(s for s in self.added if s.name != step.name), step])

    def to_json(self) -> JsonObject:
        return {
            "schema_version": self.schema_version,
            "terms": list(self.terms),
            "budget": self.budget,
            "size": self.size,
            "tolerance": self.tolerance,
            "start": list(self.start),
            "added": [step.to_json() for step in self.added],
            "values": {name: list(value) for name, value in self.worker_values.items()},
            "stopped": self.stopped,
        }


def read_support_record(path: str | Path) -> SupportRecord:
    """Read ``support.json``, checked (names plain, numbers finite, at most :data:`MAX_WORKERS` workers)."""
    what = str(path)
    data = read_json_record(path, f"{what}: not a readable JSON file")
    if not isinstance(data, dict):
        raise ValueError(f"{what}: expected a support record")
    version = check_version(data.get("schema_version"), SUPPORT_VERSION, what)
    try:
        added = [_step(item, f"{what}: added") for item in _list(data.get("added", []), what)]
        terms = [check_name(t, f"{what}: terms") for t in _list(data.get("terms"), what)]
        start = [check_name(n, f"{what}: start") for n in _list(data.get("start"), what)]
        return SupportRecord(
            terms,
            _int(data.get("budget"), what),
            _int(data.get("size"), what),
            _number(data.get("tolerance"), what),
            start,
            added,
            _values(data.get("values", {}), what),
            str(data.get("stopped", ""))[:200],
            version,
        )
    except (TypeError, KeyError) as error:
        raise ValueError(f"{what}: not a support record ({brief(str(error))})") from None


def _list(value: object, what: str) -> list[Any]:
    if not isinstance(value, list) or len(value) > MAX_WORKERS:
        raise ValueError(f"{what}: expected a list of at most {MAX_WORKERS} entries, got {brief(value)}")
    return value


def _int(value: object, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError(f"{what}: expected a whole number >= 0, got {brief(value)}")
    return value


def _number(value: object, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{what}: expected a finite number, got {brief(value)}")
    return float(value)


def _step(item: object, what: str) -> SupportStep:
    if not isinstance(item, dict) or not isinstance(item.get("weights"), dict):
        raise ValueError(f"{what}: expected a worker entry, got {brief(item)}")
    warm = item.get("warm_start")
    return SupportStep(
        check_name(item.get("name"), what),
        {check_name(t, what): _number(v, what) for t, v in item["weights"].items()},
        _number(item.get("gain"), what),
        _number(item.get("value"), what),
        _int(item.get("steps"), what),
        check_name(warm, what) if warm is not None else None,
        _int(item.get("replay", 0), what),
    )


def _values(value: object, what: str) -> dict[str, list[float]]:
    if not isinstance(value, dict) or len(value) > MAX_WORKERS:
        raise ValueError(f"{what}: expected worker name -> value, got {brief(value)}")
    return {
        check_name(n, f"{what}: values"): [_number(x, what) for x in _list(v, what)] for n, v in value.items()
    }

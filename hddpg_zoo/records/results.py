"""
A benchmark's ``results.json``: per method the seed statistics of its final test and learning curve, the
paired comparisons, rliable's aggregates and the scenario's own figures (transfer, front).

The leaves (a summary over seeds, a paired difference, an interval, the transfer figure) stay the JSON
objects they are written as, typed by the :class:`~typing.TypedDict` of their shape; the parts a reader
walks (the record, a method's entry, a comparison, the run's facts) are frozen dataclasses. The reader checks
the structure down to those leaves (objects where objects belong, seeds and counts whole numbers); the
leaves' numbers are read by the tables and figures that print them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import cast

from hddpg_zoo.records.results_leaves import (
    Aggregates,
    ComparisonFamily,
    DependenceFigure,
    FrontResults,
    PairedDifference,
    Summary,
    TransferResults,
    TtcShares,
)
from sb3_hddpg.artifacts.limits import brief, read_json_record
from sb3_hddpg.artifacts.records.base import (
    BENCHMARK_RESULTS_VERSION,
    JsonObject,
    JsonRecord,
    JsonValue,
    check_version,
)

#: A learning curve's band over seeds: ``x``, ``mean``, ``low``, ``high``.
CurveBand = dict[str, list[float]]


@dataclass(frozen=True)
class MethodResults:
    """
    One run key's results over its seeds.

    :param seeds: the seeds, ascending.
    :param per_seed: seed (as text) -> metric -> value.
    :param stats: metric -> summary over the seeds.
    :param worker_timesteps: the mean steps its workers were trained for (0 for a flat method).
    :param own_timesteps: its own env steps (the manager's for a hierarchy).
    :param selection_rate: worker -> mean share of the decisions (hierarchies).
    :param state_dependence: seed -> :func:`~sb3_hddpg.evaluation.state_dependence`'s figure.
    :param decisions_by_ttc: seed -> each worker's share by time to collision (highway-env).
    """

    seeds: tuple[int, ...]
    per_seed: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    stats: Mapping[str, Summary] = field(default_factory=dict)
    worker_timesteps: int = 0
    own_timesteps: int = 0
    selection_rate: Mapping[str, float] | None = None
    state_dependence: Mapping[str, DependenceFigure | None] | None = None
    decisions_by_ttc: Mapping[str, dict[str, TtcShares]] | None = None

    def to_json(self) -> JsonObject:
        out: JsonObject = {
            "seeds": list(self.seeds),
            "per_seed": {seed: dict(values) for seed, values in self.per_seed.items()},
            "stats": dict(self.stats),
            "worker_timesteps": self.worker_timesteps,
            "own_timesteps": self.own_timesteps,
        }
        for key in ("selection_rate", "state_dependence", "decisions_by_ttc"):
            value = getattr(self, key)
            if value is not None:
                out[key] = dict(value)
        return out

    @classmethod
    def from_json(cls, value: object, what: str) -> MethodResults:
        """A method's entry, checked: an object with its seeds (whole numbers) and its statistics (objects)."""
        entry = _object(value, what)
        seeds = entry.get("seeds")
        if not isinstance(seeds, list) or not all(
            isinstance(s, int) and not isinstance(s, bool) for s in seeds
        ):
            raise ValueError(f"{what}.seeds: expected a list of seeds, got {brief(seeds)}")
        stats = _object(entry.get("stats", {}), f"{what}.stats")
        for key, summary in stats.items():
            _object(summary, f"{what}.stats.{brief(key)}")
        per_seed = _object(entry.get("per_seed", {}), f"{what}.per_seed")
        return cls(
            seeds=tuple(cast(list[int], seeds)),
            per_seed={k: cast(dict[str, float], _object(v, f"{what}.per_seed")) for k, v in per_seed.items()},
            stats=cast(dict[str, Summary], stats),
            worker_timesteps=_whole(entry.get("worker_timesteps", 0), f"{what}.worker_timesteps"),
            own_timesteps=_whole(entry.get("own_timesteps", 0), f"{what}.own_timesteps"),
            selection_rate=cast("dict[str, float] | None", _optional_object(entry, "selection_rate", what)),
            state_dependence=cast(
                "dict[str, DependenceFigure | None] | None", _optional_object(entry, "state_dependence", what)
            ),
            decisions_by_ttc=cast(
                "dict[str, dict[str, TtcShares]] | None", _optional_object(entry, "decisions_by_ttc", what)
            ),
        )


@dataclass(frozen=True)
class Comparison:
    """
    A paired comparison of two run keys over their common seeds (same seed: same workers, same episodes).

    :param seeds: the common seeds.
    :param metrics: metric -> the paired difference (metrics the env does not report are absent).
    :param slope_ratio: the ratio of the mean learning-curve slopes (``None`` when the baseline's is 0).
    """

    seeds: tuple[int, ...]
    metrics: dict[str, PairedDifference] = field(default_factory=dict)
    slope_ratio: float | None = None

    def to_json(self) -> JsonObject:
        return {"seeds": list(self.seeds), **self.metrics, "slope_ratio": self.slope_ratio}

    @classmethod
    def from_json(cls, value: object, what: str) -> Comparison:
        """A comparison, checked: its seeds, and every other field but the slope ratio an object."""
        entry = _object(value, what)
        seeds = entry.get("seeds", [])
        if not isinstance(seeds, list) or not all(isinstance(s, int) for s in seeds):
            raise ValueError(f"{what}.seeds: expected a list of seeds, got {brief(seeds)}")
        metrics = {
            key: cast(PairedDifference, _object(v, f"{what}.{brief(key)}"))
            for key, v in entry.items()
            if key not in ("seeds", "slope_ratio")
        }
        ratio = entry.get("slope_ratio")
        if ratio is not None and not isinstance(ratio, (int, float)):
            raise ValueError(f"{what}.slope_ratio: expected a number or null, got {brief(ratio)}")
        return cls(tuple(cast(list[int], seeds)), metrics, None if ratio is None else float(ratio))


@dataclass(frozen=True)
class RunFacts:
    """
    How a benchmark's results were produced: its wall time (this invocation, every invocation of a resumed
    benchmark), the runs that failed, and the machine.
    """

    wall_time_s_this_invocation: float
    wall_time_s_all_invocations: float | None = None
    invocations: int | None = None
    failures: Mapping[str, str] = field(default_factory=dict)
    machine: Mapping[str, JsonValue] | None = None

    def to_json(self) -> JsonObject:
        out: JsonObject = {"wall_time_s_this_invocation": self.wall_time_s_this_invocation}
        if self.wall_time_s_all_invocations is not None:
            out["wall_time_s_all_invocations"] = self.wall_time_s_all_invocations
        if self.invocations is not None:
            out["invocations"] = self.invocations
        out["failures"] = dict(self.failures)
        if self.machine is not None:
            out["machine"] = dict(self.machine)
        return out


_FIELDS = (
    "results_version",
    "settings",
    "scenario",
    "metric",
    "test_seeds",
    "test_episode_set",
    "curve_seeds",
    "curve_window",
    "slope_unit_steps",
    "methods",
    "comparisons",
    "comparison_families",
    "aggregates",
    "workers",
    "colours",
    "transfer",
    "front",
    "wall_time_s_this_invocation",
    "wall_time_s_all_invocations",
    "invocations",
    "failures",
    "machine",
    "curves",
)


@dataclass(frozen=True, eq=False)
class BenchmarkResults(JsonRecord):
    """
    A benchmark's ``results.json`` (:func:`benchmark_results` builds it, :func:`read_benchmark_results`
    reads it). Parts a file from an older version lacks are empty or ``None``.

    :param settings: the benchmark's settings, as written.
    :param scenario: ``standard``, ``transfer``, ``front``...
    :param metric: what ``mean_reach_reward`` is, in words.
    :param methods: run key -> :class:`MethodResults`, in the settings' order.
    :param comparisons: ``"A vs B"`` -> :class:`Comparison`.
    :param comparison_families: challenger -> its table's adjustment.
    :param aggregates: rliable's aggregates (``None``: no method finished).
    :param workers: worker -> ``validation_mean_reach_reward`` summary.
    :param colours: run key -> its method's colour.
    :param test_seeds: the first and last test episode seed.
    :param test_episode_set: the record of the test episodes.
    :param curve_seeds: the first and last learning-curve evaluation seed.
    :param curve_window: the own steps every method's curve statistics cover.
    :param slope_unit_steps: steps per unit of the slopes.
    :param transfer: the transfer scenario's figure.
    :param front: the front scenario's hypervolumes and comparisons (:func:`~hddpg_zoo.benchmark.front_statistics.front_results`).
    :param run: wall times, failures and machine (``None`` until the run adds them).
    :param curves: x key (``timesteps``, ``total_timesteps``) -> run key -> the curve's band.
    :param extra: fields this version does not know, kept as read.
    :param results_version: the file's schema version.
    """

    settings: Mapping[str, JsonValue]
    scenario: str | None
    metric: str
    methods: Mapping[str, MethodResults]
    comparisons: Mapping[str, Comparison] = field(default_factory=dict)
    comparison_families: Mapping[str, ComparisonFamily] | None = None
    aggregates: Aggregates | None = None
    workers: Mapping[str, dict[str, Summary]] = field(default_factory=dict)
    colours: Mapping[str, str] | None = None
    test_seeds: tuple[int, ...] = ()
    test_episode_set: Mapping[str, JsonValue] | None = None
    curve_seeds: tuple[int, ...] = ()
    curve_window: int | None = None
    slope_unit_steps: int = 1000
    transfer: TransferResults | None = None
    front: FrontResults | None = None
    run: RunFacts | None = None
    curves: Mapping[str, Mapping[str, CurveBand]] | None = None
    extra: Mapping[str, JsonValue] = field(default_factory=dict)
    results_version: int = BENCHMARK_RESULTS_VERSION

    def with_run(
        self,
        wall_time_s_this_invocation: float,
        wall_time_s_all_invocations: float | None = None,
        invocations: int | None = None,
        failures: Mapping[str, str] | None = None,
        machine: Mapping[str, JsonValue] | None = None,
    ) -> BenchmarkResults:
        """These results with how they were produced (see :class:`RunFacts`)."""
        facts = RunFacts(
            wall_time_s_this_invocation,
            wall_time_s_all_invocations,
            invocations,
            dict(failures or {}),
            machine,
        )
        return replace(self, run=facts)

    def with_curves(self, curves: Mapping[str, Mapping[str, CurveBand]]) -> BenchmarkResults:
        """These results with the learning curves' bands (for the figures)."""
        return replace(self, curves=curves)

    @property
    def failures(self) -> Mapping[str, str]:
        """Task label -> why it failed (empty when every run finished)."""
        return self.run.failures if self.run is not None else {}

    def to_json(self) -> JsonObject:
        out: JsonObject = {
            "results_version": self.results_version,
            "settings": dict(self.settings),
            "scenario": self.scenario,
            "metric": self.metric,
            "test_seeds": list(self.test_seeds),
            "test_episode_set": None if self.test_episode_set is None else dict(self.test_episode_set),
            "curve_seeds": list(self.curve_seeds),
            "curve_window": self.curve_window,
            "slope_unit_steps": self.slope_unit_steps,
            "methods": {key: entry.to_json() for key, entry in self.methods.items()},
            "comparisons": {key: comparison.to_json() for key, comparison in self.comparisons.items()},
            "comparison_families": self.comparison_families,
            "aggregates": self.aggregates,
            "workers": dict(self.workers),
            "colours": self.colours,
            "transfer": self.transfer,
            "front": self.front,
            **(self.run.to_json() if self.run is not None else {}),
            "curves": self.curves,
            **self.extra,
        }
        # A part this file has not got (an older file's, another scenario's) is left out, not written null.
        return {key: value for key, value in out.items() if value is not None}

    @classmethod
    def from_json(cls, value: object, what: str) -> BenchmarkResults:
        """
        The one reader of results (parsed by the limited JSON reader): an object with its settings, and its
        methods and comparisons as objects of entries (:meth:`MethodResults.from_json`,
        :meth:`Comparison.from_json`), at a version this library reads. Files from before a part existed
        (no aggregates, no episode set, no version) read with that part empty.

        :raises ValueError: one line naming ``what`` and the first problem.
        """
        data = _object(value, what)
        version = check_version(data.get("results_version"), BENCHMARK_RESULTS_VERSION, what)
        methods = _object(data.get("methods"), f"{what}: methods")
        comparisons = _object(data.get("comparisons", {}), f"{what}: comparisons")
        scenario, metric = data.get("scenario"), data.get("metric", "")
        if (scenario is not None and not isinstance(scenario, str)) or not isinstance(metric, str):
            raise ValueError(f"{what}: expected scenario and metric as text")
        run = None
        if "wall_time_s_this_invocation" in data:
            run = RunFacts(
                _number(data["wall_time_s_this_invocation"], f"{what}: wall_time_s_this_invocation"),
                _optional_number(
                    data.get("wall_time_s_all_invocations"), f"{what}: wall_time_s_all_invocations"
                ),
                _whole(data["invocations"], f"{what}: invocations") if "invocations" in data else None,
                {str(k): str(v) for k, v in _object(data.get("failures", {}), f"{what}: failures").items()},
                _optional_object(data, "machine", what),
            )
        curve_window = data.get("curve_window")
        return cls(
            settings=_object(data.get("settings", {}), f"{what}: settings"),
            scenario=scenario,
            metric=metric,
            methods={
                str(k): MethodResults.from_json(v, f"{what}: methods.{brief(k)}") for k, v in methods.items()
            },
            comparisons={
                str(k): Comparison.from_json(v, f"{what}: comparisons.{brief(k)}")
                for k, v in comparisons.items()
            },
            comparison_families=cast(
                "dict[str, ComparisonFamily] | None", _optional_object(data, "comparison_families", what)
            ),
            aggregates=cast("Aggregates | None", _optional_object(data, "aggregates", what)),
            workers=cast(
                "dict[str, dict[str, Summary]]", _object(data.get("workers", {}), f"{what}: workers")
            ),
            colours=cast("dict[str, str] | None", _optional_object(data, "colours", what)),
            test_seeds=_seeds(data.get("test_seeds", []), f"{what}: test_seeds"),
            test_episode_set=_optional_object(data, "test_episode_set", what),
            curve_seeds=_seeds(data.get("curve_seeds", []), f"{what}: curve_seeds"),
            curve_window=None if curve_window is None else _whole(curve_window, f"{what}: curve_window"),
            slope_unit_steps=_whole(data.get("slope_unit_steps", 1000), f"{what}: slope_unit_steps"),
            transfer=cast("TransferResults | None", _optional_object(data, "transfer", what)),
            front=cast("FrontResults | None", _optional_object(data, "front", what)),
            run=run,
            curves=cast("dict[str, dict[str, CurveBand]] | None", _optional_object(data, "curves", what)),
            extra={k: v for k, v in data.items() if k not in _FIELDS},
            results_version=version,
        )


def benchmark_results(
    settings: Mapping[str, JsonValue],
    scenario: str,
    metric: str,
    methods: Mapping[str, MethodResults],
    comparisons: Mapping[str, Comparison],
    comparison_families: Mapping[str, ComparisonFamily],
    aggregates: Aggregates | None,
    workers: Mapping[str, dict[str, Summary]],
    colours: Mapping[str, str],
    test_seeds: tuple[int, int],
    test_episode_set: Mapping[str, JsonValue],
    curve_seeds: tuple[int, int],
    curve_window: int,
    slope_unit_steps: int,
    transfer: TransferResults | None = None,
    front: FrontResults | None = None,
) -> BenchmarkResults:
    """The one builder of a benchmark's results, at this library's version (see :class:`BenchmarkResults`)."""
    return BenchmarkResults(
        settings=settings,
        scenario=scenario,
        metric=metric,
        methods=dict(methods),
        comparisons=dict(comparisons),
        comparison_families=dict(comparison_families),
        aggregates=aggregates,
        workers=dict(workers),
        colours=dict(colours),
        test_seeds=test_seeds,
        test_episode_set=test_episode_set,
        curve_seeds=curve_seeds,
        curve_window=curve_window,
        slope_unit_steps=slope_unit_steps,
        transfer=transfer,
        front=front,
        results_version=BENCHMARK_RESULTS_VERSION,
    )


def read_benchmark_results(path: str | Path) -> BenchmarkResults:
    """
    A benchmark's ``results.json``, through the JSON size and depth limits (:meth:`BenchmarkResults.from_json`).

    :raises ValueError: one line naming the file (a ``LimitError`` for one too big or too deep).
    """
    value = read_json_record(path, f"{path}: not readable benchmark results")
    return BenchmarkResults.from_json(value, str(path))


def _object(value: object, what: str) -> dict[str, JsonValue]:
    if not isinstance(value, dict):
        raise ValueError(f"{what}: expected an object, got {brief(value)}")
    return value


def _optional_object(data: Mapping[str, JsonValue], key: str, what: str) -> dict[str, JsonValue] | None:
    value = data.get(key)
    return None if value is None else _object(value, f"{what}: {key}")


def _whole(value: object, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{what}: expected a whole number, got {brief(value)}")
    return value


def _number(value: object, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{what}: expected a number, got {brief(value)}")
    return float(value)


def _optional_number(value: object, what: str) -> float | None:
    return None if value is None else _number(value, what)


def _seeds(value: object, what: str) -> tuple[int, ...]:
    if not isinstance(value, list):
        raise ValueError(f"{what}: expected a list of seeds, got {brief(value)}")
    return tuple(_whole(seed, what) for seed in value)

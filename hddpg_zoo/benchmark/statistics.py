"""
The benchmark's statistics over seeds: final test metrics, learning-curve statistics, the transfer figure,
and the paired comparisons (by the one decision rule of :mod:`~.comparisons`) gathered into the results.


Everything is measured with :func:`sb3_hddpg.evaluation.evaluate` on the env's combined
normalised reward, ``mean_reach_reward`` (per step the goal and avoid terms min-max normalised to
``[0, 1]`` and summed; at most 2 per step, 400 per episode), plus goal-touch rate, collisions, success
and clearance. The learning curves are the in-training evaluations (``evaluations/<name>.json``) on the
fixed seeds ``EVAL_SEED_BASE + k``; because ``train_agent`` keeps the best model by those evaluations,
the final scores are measured on a disjoint block of fixed test seeds (the benchmark's test episode set:
the development episodes, or the final test set in a run of record, :mod:`sb3_hddpg.episode_sets`), the same
for every method and seed (selecting and scoring on the same episodes would flatter the learned methods).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict
from typing import Any, TypedDict, cast

import numpy as np

from hddpg_zoo.benchmark.aggregates import (
    aggregate_intervals,
    improvement_probabilities,
    score_matrix,
)
from hddpg_zoo.benchmark.comparisons import adjust_for_comparisons, compare
from hddpg_zoo.benchmark.episodes import seed_metrics, term_sum_keys
from hddpg_zoo.benchmark.front import FRONT_METHOD
from hddpg_zoo.benchmark.front_statistics import front_results
from hddpg_zoo.benchmark.front_support import SUPPORT_METHOD
from hddpg_zoo.benchmark.methods import (
    METHOD_REGISTRY,
    WORKERS,
    method_key,
    split_key,
)
from hddpg_zoo.benchmark.settings import BenchmarkSettings
from hddpg_zoo.benchmark.tasks import Task, comparison_pairs
from hddpg_zoo.benchmark.workers_source import flat_baselines
from hddpg_zoo.records.results import (
    BenchmarkResults,
    CurveBand,
    MethodResults,
    benchmark_results,
)
from hddpg_zoo.records.results_leaves import (
    Aggregates,
    DependenceFigure,
    FrontResults,
    Summary,
    TransferComparison,
    TransferResults,
    TransferSeed,
)
from hddpg_zoo.stats import (
    bootstrap_ci,
    summarise,
    trend_slope,
)
from sb3_hddpg.artifacts.records import JsonObject
from sb3_hddpg.envs import SnakeArmEnv
from sb3_hddpg.envs.contract import TermNormaliser
from sb3_hddpg.episode_sets import DEVELOPMENT
from sb3_hddpg.evaluation import DEPENDENCE_WORKER, EVAL_SEED_BASE, state_dependence

#: The share of its final score (measured from a random policy's) a run must reach in the transfer figure.
TRANSFER_FRACTION = 0.9

#: The metrics reported for the final test evaluation.
FINAL_METRICS = (
    "mean_reach_reward",
    "goal_reach_reward",
    "avoid_reach_reward",
    "goal_touch_rate",
    "collisions_per_episode",
    "success_rate",
    "min_clearance",
    "mean_reward",
    "action_saturation",
    "crash_rate",
)


#: Steps per unit of the reported learning-curve slopes.
SLOPE_UNIT = 1000


#: Run key -> seed -> record.
RecordsByMethod = dict[str, dict[int, JsonObject]]


def normalised_term_sums(summary: Mapping[str, float]) -> tuple[float, float]:
    """
    The episode sums of the normalised goal and avoid terms, from an evaluation summary's raw means.

    Normalisation is affine per step, so the mean episode sum of a normalised term is
    ``(mean raw sum - mean length * low) / (high - low)`` with the env's fixed ``reward_bounds``.
    """

    normaliser = TermNormaliser(SnakeArmEnv().reward_bounds)
    length = summary["mean_length"]
    goal, avoid = (normaliser.episode_sum(t, summary[f"mean_{t}_reward"], length) for t in ("goal", "avoid"))
    return goal, avoid


def with_term_sums(summary: JsonObject) -> JsonObject:
    if "mean_goal_reward" not in summary or "mean_avoid_reward" not in summary:
        return summary  # another env: its normalised total is mean_reach_reward already
    goal, avoid = normalised_term_sums(summary)
    return {**summary, "goal_reach_reward": goal, "avoid_reach_reward": avoid}


def record_episode_set(record: JsonObject) -> JsonObject:
    """
    The episode set a record's test used: as recorded, or for a record from before sets were recorded, the
    development episodes (then the only test episodes) of its summary's length.
    """
    kept = record.get("test_episode_set")
    if isinstance(kept, dict):
        return kept
    return DEVELOPMENT.describe(int(record["test"]["episodes"]))


def check_episode_sets(settings: BenchmarkSettings, records: Iterable[JsonObject]) -> None:
    """
    Refuse records scored on other episodes than the benchmark's test set: one results table never mixes
    the final test set with development episodes (or with another number of them).

    :raises ValueError: naming the first run that differs, its episodes and the benchmark's.
    """
    expected = settings.test_episode_set
    for record in records:
        if record["method"] == WORKERS:
            continue
        used = record_episode_set(record)
        if used != expected:
            raise ValueError(
                f"The run {record['method']}/seed-{record['seed']} was tested on {used}, this benchmark tests on "
                f"{expected}: one benchmark folder holds one test episode set (start a new folder, or --redo "
                f"{record['method'].partition('@')[0]})"
            )


def test_values(record: JsonObject) -> dict[str, float]:
    """
    A run's per-seed test metrics: from its episodes (:func:`~.episodes.seed_metrics`) where the record
    holds them, else from its test summary (records from before episodes were kept).
    """
    rows = record.get("episodes")
    test = seed_metrics(rows) if rows else with_term_sums(record["test"])
    # Records of runs from before a metric existed (resumed) lack it: it is left out, not faked.
    return {key: float(test[key]) for key in metric_keys(test) if key in test}


def metric_keys(values: Mapping[str, object]) -> tuple[str, ...]:
    """:data:`FINAL_METRICS`, then another env's per-term normalised sums among ``values`` (each key once)."""
    return (*FINAL_METRICS, *(key for key in term_sum_keys(values) if key not in FINAL_METRICS))


def curve_statistics(history: Sequence[JsonObject], window: int) -> dict[str, float]:
    """
    A learning curve's mean and trend slope (paper Figure 9) over the evaluations at own steps <= ``window``.

    :param history: the run's evaluations (``timesteps`` and ``mean_reach_reward``).
    :param window: the last own step counted (the same for every method, so curves are compared alike).
    :return: ``curve_mean`` and ``slope`` (reach reward per :data:`SLOPE_UNIT` steps; 0 with < 2 points).
    """
    points = [p for p in history if p["timesteps"] <= window] or list(history[:1])
    x = np.array([p["timesteps"] for p in points], dtype=float) / SLOPE_UNIT
    y = np.array([p["mean_reach_reward"] for p in points], dtype=float)
    slope = trend_slope(x, y) if len(set(x.tolist())) >= 2 else 0.0
    return {"curve_mean": float(y.mean()), "slope": slope}


def compute_results(settings: BenchmarkSettings, records: Iterable[JsonObject]) -> BenchmarkResults:
    """
    Seed statistics of finished runs: per method the final test metrics (mean, 95 % bootstrap CI, IQM),
    the learning curve's mean and slope, and the paired comparisons of the paper's claims.

    :param settings: the benchmark's settings.
    :param records: finished records (``workers`` records are used for the worker summaries).
    :return: the results (``results.json``'s record).
    """
    records = list(records)
    check_episode_sets(settings, records)
    by_method: RecordsByMethod = {}
    worker_records = {}
    for record in records:
        if record["method"] == WORKERS:
            worker_records[record["seed"]] = record
        else:
            by_method.setdefault(record["method"], {})[record["seed"]] = record
    window = settings.manager_env_steps  # the manager's own env steps: the window every method shares
    methods: dict[str, MethodResults] = {}
    per_seed: dict[str, dict[int, dict[str, float]]] = {}
    for method in [m for m in settings.method_keys if m in by_method]:
        methods[method], per_seed[method] = method_statistics(by_method[method], window)
    # A paired interval needs two pairs at least: with one seed there is no comparison to report.
    pairs = [
        (a, b)
        for a, b in comparison_pairs(settings)
        if a in per_seed and b in per_seed and len(set(per_seed[a]) & set(per_seed[b])) >= 2
    ]
    comparisons = {f"{a} vs {b}": compare(per_seed[a], per_seed[b]) for a, b in pairs}
    families = adjust_for_comparisons(comparisons)
    workers = worker_statistics(worker_records.values())
    return benchmark_results(
        settings=asdict(settings),
        scenario=settings.scenario,
        metric="mean_reach_reward: episode sum of the normalised "
        + (
            f"terms {settings.env['terms']} (max {len(settings.env['terms'])} per step)"
            if settings.env is not None
            else "goal and avoid terms (max 2 per step)"
        ),
        test_seeds=(
            settings.test_set.seeds(settings.test_episodes or 1)[0],
            settings.test_set.seeds(settings.test_episodes or 1)[-1],
        ),
        test_episode_set=settings.test_episode_set,
        curve_seeds=(EVAL_SEED_BASE, EVAL_SEED_BASE + settings.eval_episodes - 1),
        curve_window=window,
        slope_unit_steps=SLOPE_UNIT,
        methods=methods,
        comparisons=comparisons,
        comparison_families=families,
        aggregates=aggregates({m: runs for m, runs in by_method.items() if m in methods}, pairs),
        workers=workers,
        colours={key: METHOD_REGISTRY[split_key(key)[0]].colour for key in methods},
        transfer=transfer_results(settings, by_method) if settings.scenario == "transfer" else None,
        front=_front_of(by_method, worker_records, settings),
    )


def _front_of(by_method: Mapping[str, Any], workers: Any, settings: BenchmarkSettings) -> FrontResults | None:
    """The front's statistics, of ``hddpg-front`` else ``hddpg-support``, with its copied flat runs (or ``None``)."""
    method = next((m for m in (FRONT_METHOD, SUPPORT_METHOD) if m in by_method), None)
    flat = {m: by_method[m] for m in flat_baselines() if m in by_method and m not in settings.method_keys}
    return front_results(by_method[method], workers, flat) if method is not None else None


def method_statistics(
    runs: dict[int, JsonObject], window: int
) -> tuple[MethodResults, dict[int, dict[str, float]]]:
    """
    One method's seed statistics: its final test metrics, learning curve and selections over its seeds.

    :param runs: seed -> the method's finished record.
    :param window: the last own step of the curves counted (the same for every method).
    :return: the method's results, and seed -> its values (for the paired comparisons).
    """
    seeds = sorted(runs)
    values: dict[int, dict[str, float]] = {}
    for seed in seeds:
        run = runs[seed]
        values[seed] = test_values(run)
        values[seed].update(curve_statistics(run["history"], window))
        values[seed]["final_curve_reward"] = float(run["history"][-1]["mean_reach_reward"])
        # The score the test reports (the normalised return), at the curve's best evaluation: what the kept
        # checkpoint promised on the curve episodes, beside what it scored on the test episodes.
        values[seed]["best_curve_reward"] = float(max(p["mean_reach_reward"] for p in run["history"]))
    stats: dict[str, Summary] = {
        key: summarise([values[s][key] for s in seeds])
        for key in (
            *metric_keys(values[seeds[0]]),
            "curve_mean",
            "slope",
            "final_curve_reward",
            "best_curve_reward",
        )
        if all(key in values[s] for s in seeds)
    }
    selection = [
        runs[s]["test"].get("selection_rate") for s in seeds if runs[s]["test"].get("selection_rate")
    ]
    # Per seed: does the hierarchy's choice depend on the state?
    dependence = {
        str(s): cast("DependenceFigure | None", state_dependence(runs[s]["test"], DEPENDENCE_WORKER))
        for s in seeds
    }
    # On highway-env: each worker's share of the decisions with a car close ahead and the road clear.
    by_ttc = {str(s): runs[s]["decisions_by_ttc"] for s in seeds if runs[s].get("decisions_by_ttc")}
    result = MethodResults(
        seeds=tuple(seeds),
        per_seed={str(s): values[s] for s in seeds},
        stats=stats,
        worker_timesteps=int(np.mean([runs[s]["worker_timesteps"] for s in seeds])),
        own_timesteps=int(max(runs[seeds[0]]["history"][-1]["timesteps"], 0)),
        selection_rate={
            name: float(np.mean([rates.get(name, 0.0) for rates in selection]))
            for name in sorted(set().union(*selection))
        }
        if selection
        else None,
        state_dependence=dependence if any(figure is not None for figure in dependence.values()) else None,
        decisions_by_ttc=by_ttc or None,
    )
    return result, values


def worker_statistics(worker_records: Iterable[JsonObject]) -> dict[str, dict[str, Summary]]:
    """Each snake worker's validation reach reward over the seeds that trained it."""
    worker_records = list(worker_records)
    workers: dict[str, dict[str, Summary]] = {}
    for name in ("goal", "avoid"):
        finals = [
            with_term_sums(r["workers"][name]["metrics"])["mean_reach_reward"]
            for r in worker_records
            if name in r["workers"]
        ]
        if finals:
            workers[name] = {"validation_mean_reach_reward": summarise(finals)}
    return workers


# --------------------------------------------------------------------------------------------- transfer
def preference_score(summary: Mapping[str, float], preferences: Mapping[str, float]) -> float:
    """
    An evaluation's score under preference factors: ``sum_t factor_t * (episode sum of normalised term t)``,
    the return of the manager (and of the flat agent) trained on that preference.

    :param summary: an evaluation summary (raw term means and ``mean_length``).
    :param preferences: term -> factor (terms not named: 1).
    """
    goal, avoid = normalised_term_sums(summary)
    parts = {"goal": goal, "avoid": avoid}
    unknown = sorted(set(preferences) - set(parts))
    if unknown:
        raise ValueError(f"Unknown reward terms {unknown} in the preferences; the terms: {list(parts)}")
    return float(sum(preferences.get(term, 1.0) * value for term, value in parts.items()))


def steps_to_fraction(
    history: Sequence[JsonObject],
    score: Callable[[JsonObject], float],
    fraction: float = TRANSFER_FRACTION,
    floor: float = 0.0,
    final: float | None = None,
) -> int | None:
    """
    The own steps at which a learning curve first reaches ``fraction`` of a final score, measured from
    ``floor``: the first evaluation with ``score >= floor + fraction * (final - floor)``, where ``final`` is
    the curve's last evaluation's score unless given. With ``floor`` a random policy's score this is "90 % of
    the way from random to where it ended"; with ``floor = 0`` it is 90 % of the final score itself. With
    another run's ``final``, it is how long this curve takes to get (nearly) as far as that run.

    :param history: the curve's evaluations, in order (``timesteps``: the run's own steps).
    :param score: the score of one evaluation.
    :param fraction: in (0, 1].
    :param floor: the score counted as no progress.
    :param final: the score to get 90 % of the way to (default: the curve's own last).
    :return: the steps, or ``None`` if ``final`` is at or below ``floor`` (nothing to reach) or the curve never
        gets there.
    """
    if not 0 < fraction <= 1:
        raise ValueError(f"Expected `fraction` in (0, 1], actually: {fraction}")
    if not history:
        raise ValueError("Expected a learning curve with at least one evaluation, actually: none")
    scores = [score(point) for point in history]
    final = scores[-1] if final is None else final
    if final <= floor:
        return None
    target = floor + fraction * (final - floor)
    return next((int(p["timesteps"]) for p, value in zip(history, scores) if value >= target), None)


class CensoredRatio(TypedDict):
    """A transfer comparison's steps to the common target and their ratio (:func:`censored_ratio`)."""

    manager_steps_to_target: int | None
    flat_steps_to_target: int | None
    ratio_to_target: float | None
    censored: str


def censored_ratio(
    manager_steps: int | None,
    flat_steps: int | None,
    manager_history: Sequence[JsonObject],
    flat_history: Sequence[JsonObject],
) -> CensoredRatio:
    """
    The transfer ratio to a common target, flat steps / manager steps, with a run that never reaches it
    censored at its curve's last evaluation: the ratio is then a bound, not a value.

    :param manager_steps: the manager's steps to the target (``None``: never).
    :param flat_steps: the flat agent's.
    :param manager_history: the manager's curve (its last evaluation: where a miss is censored).
    :param flat_history: the flat agent's curve.
    :return: ``manager_steps_to_target``, ``flat_steps_to_target``, ``ratio_to_target`` (at the censoring
        bound where one missed; ``None`` where both did or there is nothing to reach) and ``censored``:
        ``none``, ``flat`` (the ratio is at least the value), ``manager`` (at most) or ``both``.
    """
    censored = {
        (False, False): "none",
        (False, True): "flat",
        (True, False): "manager",
        (True, True): "both",
    }[(manager_steps is None, flat_steps is None)]
    manager_end = int(manager_history[-1]["timesteps"])
    flat_end = int(flat_history[-1]["timesteps"])
    manager_at = manager_end if manager_steps is None else manager_steps
    flat_at = flat_end if flat_steps is None else flat_steps
    return {
        "manager_steps_to_target": manager_steps,
        "flat_steps_to_target": flat_steps,
        "ratio_to_target": flat_at / manager_at if censored != "both" and manager_at > 0 else None,
        "censored": censored,
    }


def transfer_results(settings: BenchmarkSettings, by_method: RecordsByMethod) -> TransferResults:
    """
    The transfer figure: per preference, hierarchy (``hddpg`` and every challenger,
    e.g. ``hddpg-sac``) and flat method, per seed the own env steps each run needs to reach
    :data:`TRANSFER_FRACTION` of its final score on its learning curve (scored with the preference's
    factors, measured from a random policy's score on the same episodes), their ratio flat / manager (how
    many times fewer steps the manager over pre-trained workers needs), and the ratio's mean with a 95 %
    bootstrap CI over the seeds where both are defined. The per-seed fields named ``manager_*`` hold the
    figures of the comparison's ``manager`` (a hierarchy method), ``flat_*`` those of its ``flat`` method.

    :param settings: the benchmark's settings (transfer scenario).
    :param by_method: run key -> seed -> record.
    """
    out: TransferResults = {
        "fraction": TRANSFER_FRACTION,
        "definition": (
            f"own env steps until the learning curve (its evaluations on the curve episodes) first reaches "
            f"{TRANSFER_FRACTION:.0%} of the way from a random policy's score to the better of the two runs' "
            "final scores (both scored with the preference's factors); a run that never gets there is censored "
            "at its last evaluation; ratio = flat steps / manager steps (the manager's workers are trained "
            "once, before)"
        ),
        "eval_freq": settings.eval_freq_for(settings.manager_env_steps),
        "preferences": {},
    }
    hierarchies = [m for m in settings.methods if m == "hddpg" or METHOD_REGISTRY[m].challenger]
    flats = [m for m in settings.methods if m not in hierarchies]
    for preference in settings.preferences:
        factors = Task(method_key("hddpg", preference), 0).preferences or {}

        def score(point: JsonObject, factors: dict[str, float] = factors) -> float:
            return preference_score(point, factors)

        entry: dict[str, TransferComparison] = {}
        for hierarchy, flat in ((h, f) for h in hierarchies for f in flats):
            managers = by_method.get(method_key(hierarchy, preference), {})
            agents = by_method.get(method_key(flat, preference), {})
            per_seed: dict[str, TransferSeed] = {}
            for seed in sorted(set(managers) & set(agents)):
                manager, agent = managers[seed], agents[seed]
                floor = score(manager["reference"])
                manager_steps = steps_to_fraction(manager["history"], score, floor=floor)
                flat_steps = steps_to_fraction(agent["history"], score, floor=floor)
                manager_final = score(manager["history"][-1])
                flat_final = score(agent["history"][-1])
                # One target for both: 90 % of the way to the better final score, so that a run that never gets
                # there cannot win by it (a miss is censored at the run's last evaluation).
                target = max(manager_final, flat_final)
                manager_hit = steps_to_fraction(manager["history"], score, floor=floor, final=target)
                flat_hit = steps_to_fraction(agent["history"], score, floor=floor, final=target)
                per_seed[str(seed)] = {
                    "manager_steps": manager_steps,
                    "flat_steps": flat_steps,
                    "ratio": flat_steps / manager_steps if manager_steps and flat_steps else None,
                    # Own final scores can differ a lot: a flat agent that settles early on a low score
                    # "reaches 90 % of it" at once. So also: when (if ever) it gets as far as the manager.
                    "flat_steps_to_manager_final": steps_to_fraction(
                        agent["history"], score, floor=floor, final=manager_final
                    ),
                    "manager_final_score": manager_final,
                    "flat_final_score": score(agent["history"][-1]),
                    "random_score": floor,
                    "worker_timesteps": manager["worker_timesteps"],
                    **censored_ratio(manager_hit, flat_hit, manager["history"], agent["history"]),
                    "target_score": floor + TRANSFER_FRACTION * (target - floor) if target > floor else None,
                }
            ratios = [v["ratio"] for v in per_seed.values() if v["ratio"] is not None]
            # Keyed by the flat method against hddpg (as before other hierarchies took part), else "flat vs M".
            entry[flat if hierarchy == "hddpg" else f"{flat} vs {hierarchy}"] = {
                "manager": hierarchy,
                "flat": flat,
                "per_seed": per_seed,
                "ratio": summarise(ratios) if ratios else None,
                "seeds_with_ratio": len(ratios),
                "seeds_flat_reaches_manager": sum(
                    v["flat_steps_to_manager_final"] is not None for v in per_seed.values()
                ),
            }
        out["preferences"][preference] = entry
    return out


def score_matrices(by_method: RecordsByMethod) -> tuple[dict[str, np.ndarray], str]:
    """
    Per run key the score as rliable's runs-by-tasks matrix, with the seed (the independent training run) as
    the run and the benchmark's env as its one task: each cell is a seed's mean over its test episodes. The
    episodes of one seed share its workers and its trained model, so they are not independent tasks: a matrix
    with them as tasks resamples seeds per episode, loses the per-seed effect and gives intervals several
    times too narrow. Their spread is :func:`episode_spread`, a separate figure.

    :param by_method: run key -> seed -> record.
    :return: the matrices (seeds x 1) and their unit, ``seed``.
    """
    scores = {
        method: score_matrix({seed: [test_values(r)["mean_reach_reward"]] for seed, r in runs.items()})
        for method, runs in by_method.items()
    }
    return scores, "seed"


def episode_spread(by_method: RecordsByMethod) -> dict[str, float]:
    """
    Per run key the spread of the score from episode to episode within a seed: the root mean over seeds of
    the per-seed variance over test episodes (a description of the episodes, not an interval about the
    method); absent for a run key whose records hold no episodes.

    :param by_method: run key -> seed -> record.
    """
    spread: dict[str, float] = {}
    for method, runs in by_method.items():
        rows = [r.get("episodes") for r in runs.values()]
        if rows and all(len(e or ()) >= 2 for e in rows):
            variances = [np.var([row["reach_reward"] for row in e or ()], ddof=1) for e in rows]
            spread[method] = float(np.sqrt(np.mean(variances)))
    return spread


def aggregates(by_method: RecordsByMethod, pairs: list[tuple[str, str]]) -> Aggregates | None:
    """
    rliable's aggregates of the score (:mod:`~.aggregates`) over :func:`score_matrices` (seeds as runs), and
    the episode-level spread beside them.

    :param by_method: run key -> seed -> record.
    :param pairs: the compared ``(A, B)`` run keys.
    """
    if not by_method:
        return None
    scores, unit = score_matrices(by_method)
    out: Aggregates = {
        "metric": "mean_reach_reward",
        "unit": unit,
        "tasks": int(next(iter(scores.values())).shape[1]),
        "intervals": aggregate_intervals(scores),
        "probability_of_improvement": improvement_probabilities(scores, pairs),
    }
    spread = episode_spread(by_method)
    if spread:
        out["episode_spread"] = spread
    return out


def records_by_method(records: Iterable[JsonObject]) -> RecordsByMethod:
    """Finished method records (not the workers') by run key, then seed."""
    grouped: RecordsByMethod = {}
    for record in records:
        if record["method"] != WORKERS:
            grouped.setdefault(record["method"], {})[record["seed"]] = record
    return grouped


def curve_bands(records: Iterable[JsonObject], x_key: str, confidence: float = 0.95) -> dict[str, CurveBand]:
    """
    Per method, the mean learning curve over seeds with a bootstrap CI band, at the evaluation points at
    least half of the seeds share, within the steps every seed covers. A seed not evaluated at such a point
    (a run resumed between evaluations before their grid was kept across resumes) is interpolated linearly
    between its neighbouring evaluations.

    :param records: finished method records.
    :param x_key: ``timesteps`` (own steps) or ``total_timesteps`` (including worker pre-training).
    :return: method -> ``{"x", "mean", "low", "high"}``.
    """
    curves: dict[str, list[dict[float, float]]] = {}
    for record in records:
        if record["method"] == WORKERS:
            continue
        curves.setdefault(record["method"], []).append(
            {float(p[x_key]): float(p["mean_reach_reward"]) for p in record["history"]}
        )
    bands: dict[str, CurveBand] = {}
    for method, per_seed in curves.items():
        counts = Counter(x for curve in per_seed for x in curve)
        start, end = max(min(c) for c in per_seed), min(max(c) for c in per_seed)
        xs = sorted(x for x, n in counts.items() if 2 * n >= len(per_seed) and start <= x <= end)
        values = [np.interp(xs, sorted(c), [c[x] for x in sorted(c)]) for c in per_seed]
        band: CurveBand = {"x": xs, "mean": [], "low": [], "high": []}
        for i in range(len(xs)):
            mean, low, high = bootstrap_ci([v[i] for v in values], confidence=confidence, n_resamples=2000)
            band["mean"].append(mean)
            band["low"].append(low)
            band["high"].append(high)
        bands[method] = band
    return bands

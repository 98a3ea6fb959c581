"""
rliable's aggregates of a benchmark's test scores: IQM and mean with stratified bootstrap intervals, the
probability of improvement with intervals, and performance profiles (Agarwal et al., NeurIPS 2021).

A method's scores are a matrix of runs (training seeds) by tasks, a task being an environment (or a
preference): the benchmark's matrices (:func:`~.statistics.score_matrices`) hold one column, each seed's mean
over its test episodes. The episodes of one seed are not tasks: they share its trained model, and a matrix
with them as tasks resamples seeds per episode and gives intervals several times too narrow.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from hddpg_zoo.records.results_leaves import Interval

#: Bootstrap replications of every interval here (rliable's default is 50000, which takes minutes for a
#: benchmark of ten methods on two shared cores; at 2000 the bounds move by well under the table's precision).
BOOTSTRAP_REPS = 2_000
#: The seed of the bootstrap: the same records give the same intervals (the docs regenerate exactly).
BOOTSTRAP_SEED = 0


def score_matrix(per_seed: Mapping[int, Sequence[float]]) -> np.ndarray:
    """
    Runs by tasks: one row per seed (in seed order), its scores by episode (or one per-seed score).

    :raises ValueError: seeds with different numbers of scores (their episodes are not the same tasks).
    """
    lengths = {len(scores) for scores in per_seed.values()}
    if len(lengths) != 1:
        raise ValueError(f"Expected as many scores for every seed, actually: {sorted(lengths)}")
    return np.array([list(per_seed[seed]) for seed in sorted(per_seed)], dtype=np.float64)


def iqm_and_mean(scores: np.ndarray) -> np.ndarray:
    """
    rliable's ``aggregate_iqm`` and ``aggregate_mean`` of a runs-by-tasks matrix in one sort: the IQM is
    ``scipy.stats.trim_mean(scores, 0.25, axis=None)`` (a quarter of the scores cut at each end), computed
    here with numpy because scipy's per-call overhead, once per bootstrap replication, dominated the report.
    """
    flat = np.sort(scores, axis=None)
    cut = int(0.25 * flat.size)
    return np.array([flat[cut : flat.size - cut].mean(), flat.mean()])


def probability_of_improvement(x: np.ndarray, y: np.ndarray) -> float:
    """
    rliable's ``probability_of_improvement`` of runs-by-tasks matrices ``x`` and ``y``: per task the
    probability that a run of ``x`` scores above a run of ``y`` (ties half), averaged over tasks. The same
    definition by broadcasting: rliable calls scipy's Mann-Whitney U per task and replication, minutes here.
    """
    wins = (x[:, None, :] > y[None, :, :]) + 0.5 * (x[:, None, :] == y[None, :, :])
    return float(wins.mean(axis=(0, 1)).mean())


def _rng() -> np.random.RandomState:
    # arch's bootstrap (under rliable) takes a legacy RandomState.
    return np.random.RandomState(BOOTSTRAP_SEED)


def _interval_estimates(*args: Any, **kwargs: Any) -> Any:
    """``rliable.library.get_interval_estimates``, without arch's warning that rliable's ``random_state`` is old."""
    from rliable import library as rly  # rliable imports arch, pandas and seaborn: only the report needs it

    # rliable's stratified bootstrap draws its indices from numpy's global generator, whatever random_state
    # says: seed it for the call and give the caller's state back.
    state = np.random.get_state()
    np.random.seed(BOOTSTRAP_SEED)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", "random_state is deprecated", FutureWarning)
            return rly.get_interval_estimates(*args, **kwargs)
    finally:
        np.random.set_state(state)


def aggregate_intervals(
    scores: Mapping[str, np.ndarray], confidence: float = 0.95
) -> dict[str, dict[str, Interval]]:
    """
    Per method the IQM and the mean over every (run, task) score with stratified bootstrap intervals.

    :param scores: method -> runs-by-tasks matrix (:func:`score_matrix`).
    :param confidence: interval coverage.
    :return: method -> ``{"iqm": {"value", "ci_low", "ci_high"}, "mean": {...}}``.
    """
    points, intervals = _interval_estimates(
        dict(scores),
        iqm_and_mean,
        reps=BOOTSTRAP_REPS,
        confidence_interval_size=confidence,
        random_state=_rng(),
    )
    return {
        method: {
            name: {
                "value": float(points[method][i]),
                "ci_low": float(intervals[method][0][i]),
                "ci_high": float(intervals[method][1][i]),
            }
            for i, name in enumerate(("iqm", "mean"))
        }
        for method in scores
    }


def improvement_probabilities(
    scores: Mapping[str, np.ndarray], pairs: Sequence[tuple[str, str]], confidence: float = 0.95
) -> dict[str, Interval]:
    """
    rliable's probability of improvement ``P(A > B)`` for each pair, averaged over tasks, with a stratified
    bootstrap interval (runs of A and of B resampled independently).

    :param scores: method -> runs-by-tasks matrix.
    :param pairs: ``(A, B)`` method pairs, both in ``scores``.
    :return: ``"A vs B"`` -> ``{"value", "ci_low", "ci_high"}``.
    """
    pair_scores = {f"{a} vs {b}": (scores[a], scores[b]) for a, b in pairs}
    points, intervals = _interval_estimates(
        pair_scores,
        probability_of_improvement,
        reps=BOOTSTRAP_REPS,
        confidence_interval_size=confidence,
        random_state=_rng(),
    )
    return {
        key: {
            "value": float(points[key]),
            "ci_low": float(np.ravel(intervals[key][0])[0]),
            "ci_high": float(np.ravel(intervals[key][1])[0]),
        }
        for key in pair_scores
    }


def performance_profiles(
    scores: Mapping[str, np.ndarray], taus: np.ndarray
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """
    rliable's performance profiles: per method the fraction of (run, task) scores above each ``tau``, with
    stratified bootstrap bands (for the figure only: rliable does not seed this bootstrap).

    :param scores: method -> runs-by-tasks matrix.
    :param taus: the thresholds.
    :return: ``(profiles, bands)`` as rliable gives them (bands: 2 x len(taus)).
    """
    from rliable import library as rly

    return rly.create_performance_profile(dict(scores), taus, reps=BOOTSTRAP_REPS // 5)

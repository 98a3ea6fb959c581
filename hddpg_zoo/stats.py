"""Statistics for comparing RL methods over seeds, on scipy.

Per-seed results are small samples (typically 5-20 seeds). Summaries carry a percentile bootstrap interval
(``scipy.stats.bootstrap``) and the interquartile mean of rliable (Agarwal et al., NeurIPS 2021,
``scipy.stats.trim_mean``); paired differences carry a Student t interval (``scipy.stats.ttest_rel``), which
holds at 10 seeds where a percentile bootstrap of the mean under-covers. A table's comparisons follow one
decision rule (:func:`holm_family`): Holm's step-down test on the paired t p-values, each interval at the
Holm-consistent level of its comparison (so an interval excludes 0 exactly where Holm rejects), and words
generated from that (:func:`verdict_word`): ahead, behind, level (only where the adjusted interval lies within a
stated equivalence margin: a TOST at the same level), else not distinguishable. :func:`trend_slope` is the
"reward trend slope" of Figure 9 of the paper.
The aggregates over runs and episodes (stratified bootstrap, probability of improvement with intervals,
performance profiles) are rliable's own: :mod:`hddpg_zoo.benchmark.aggregates`.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from types import ModuleType

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hddpg_zoo.records.results_leaves import Summary


def _scipy_stats() -> ModuleType:
    """``scipy.stats``, imported on first use: it takes about a second, which every command would pay at start."""
    from scipy import stats

    return stats


#: A statistic maps a 1-D sample to a number. If it accepts an ``axis`` keyword (as ``np.mean``,
#: ``np.median`` and :func:`iqm` do) the bootstrap evaluates it on many resamples at once.
Statistic = Callable[..., float | np.floating | NDArray[np.float64]]


def _as_sample(values: ArrayLike, name: str = "values") -> np.ndarray:
    """
    Convert ``values`` to a flat float array and validate it.

    :param values: Array-like of numbers (any shape; it is flattened).
    :param name: Name of the argument, used in error messages.
    :return: 1-D float64 array.
    :raises ValueError: If the input is empty, not numeric, or contains NaN or infinite values.
    """
    try:
        array = np.asarray(values, dtype=np.float64).ravel()
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be numeric: {error}") from error
    if array.size == 0:
        raise ValueError(f"{name} is empty: at least one value is needed")
    if np.isnan(array).any():
        raise ValueError(f"{name} contains NaN ({int(np.isnan(array).sum())} of {array.size} values)")
    if np.isinf(array).any():
        raise ValueError(f"{name} contains infinite values ({int(np.isinf(array).sum())} of {array.size})")
    return array


def _check_confidence(confidence: float) -> None:
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must lie strictly between 0 and 1, got {confidence}")


def iqm(values: ArrayLike, axis: int | None = None) -> float | NDArray[np.float64]:
    """
    Interquartile mean: the mean of the middle 50 % of the values, as in rliable.

    Uses the semantics of ``scipy.stats.trim_mean(values, 0.25)`` (which rliable calls): after sorting,
    ``k = floor(0.25 * n)`` values are removed from each end and the rest are averaged with equal
    weights. This is *not* the fractional-weight definition (which would give the boundary values a
    partial weight when ``n`` is not a multiple of 4); the two agree when ``n`` is divisible by 4. For
    ``n < 4`` nothing is trimmed and the IQM equals the mean.

    :param values: Array-like of numbers.
    :param axis: Axis along which to compute; ``None`` flattens the input first (and validates it).
    :return: The IQM (a float when ``axis`` is ``None``, else an array).
    """
    if axis is None:
        array = _as_sample(values)
        axis = 0
    else:
        array = np.asarray(values, dtype=np.float64)
    if array.shape[axis] == 0:
        raise ValueError("values is empty: at least one value is needed")
    result = _scipy_stats().trim_mean(array, 0.25, axis=axis)
    return float(result) if np.ndim(result) == 0 else result


def bootstrap_ci(
    values: ArrayLike,
    statistic: Statistic = np.mean,
    confidence: float = 0.95,
    n_resamples: int = 10_000,
    seed: int | np.random.Generator | None = 0,
) -> tuple[float, float, float]:
    """
    Percentile bootstrap confidence interval of a statistic.

    The sample is resampled with replacement ``n_resamples`` times, the statistic is computed on each
    resample and the interval is given by the ``(1 - confidence) / 2`` and ``(1 + confidence) / 2``
    quantiles of those values. With a single value the interval collapses to the point estimate.

    :param values: Array-like of numbers, e.g. one final score per seed (flattened if not 1-D).
    :param statistic: Function of a 1-D sample returning a number; if it accepts ``axis`` it is
        evaluated in batches (``np.mean``, ``np.median`` and :func:`iqm` do).
    :param confidence: Confidence level, strictly between 0 and 1.
    :param n_resamples: Number of bootstrap resamples (at least 1).
    :param seed: Seed or generator for the resampling, so results are reproducible.
    :return: ``(point, low, high)``: the statistic on the data and the interval bounds.
    :raises ValueError: On empty input, NaN or infinite values, or invalid parameters.
    """
    sample = _as_sample(values)
    _check_confidence(confidence)
    if n_resamples < 1:
        raise ValueError(f"n_resamples must be at least 1, got {n_resamples}")
    point = float(statistic(sample))
    if sample.size == 1 or np.ptp(sample) == 0:
        return point, point, point
    with warnings.catch_warnings():
        # A statistic that is constant on most resamples makes scipy warn of a degenerate distribution.
        warnings.simplefilter("ignore", _scipy_stats().DegenerateDataWarning)
        result = _scipy_stats().bootstrap(
            (sample,),
            statistic,
            confidence_level=confidence,
            n_resamples=n_resamples,
            method="percentile",
            rng=np.random.default_rng(seed),
        )
    low, high = result.confidence_interval
    # Guard against floating-point noise making the interval not contain the point.
    return point, float(min(low, point)), float(max(high, point))


def paired_difference_ci(
    a: ArrayLike,
    b: ArrayLike,
    statistic: Statistic = np.mean,
    confidence: float = 0.95,
    n_resamples: int = 10_000,
    seed: int | np.random.Generator | None = 0,
) -> tuple[float, float, float]:
    """
    Bootstrap confidence interval of the mean difference ``a - b`` of paired results.

    Use it when ``a[i]`` and ``b[i]`` share something (the same seed, the same evaluation episodes):
    the per-pair differences are resampled, which removes the shared variation.

    :param a: Results of method A, one per seed.
    :param b: Results of method B, paired with ``a`` element by element.
    :param statistic: Statistic of the differences (default: the mean).
    :param confidence: Confidence level, strictly between 0 and 1.
    :param n_resamples: Number of bootstrap resamples.
    :param seed: Seed or generator for the resampling.
    :return: ``(point, low, high)`` of the statistic of ``a - b``; an interval excluding 0 indicates
        a difference at that confidence level.
    :raises ValueError: If the samples differ in length, are empty or contain NaN.
    """
    first = _as_sample(a, "a")
    second = _as_sample(b, "b")
    if first.shape != second.shape:
        raise ValueError(f"paired samples must have the same length, got {first.size} and {second.size}")
    return bootstrap_ci(first - second, statistic, confidence, n_resamples, seed)


def probability_of_improvement(a: ArrayLike, b: ArrayLike) -> float:
    """
    Probability that a random result of A beats a random result of B, ``P(X > Y)``, ties counting half.

    This is rliable's "probability of improvement" for one task: the Mann-Whitney U statistic
    divided by ``len(a) * len(b)``. The samples need not be paired nor of equal length.

    :param a: Results of method A.
    :param b: Results of method B.
    :return: A number in ``[0, 1]``; 0.5 means no tendency either way.
    :raises ValueError: If a sample is empty or contains NaN.
    """
    first = _as_sample(a, "a")
    second = _as_sample(b, "b")
    # Mann-Whitney's U of the first sample counts the pairs it wins, ties as half.
    u = _scipy_stats().mannwhitneyu(first, second, alternative="two-sided", method="asymptotic").statistic
    return float(u / (first.size * second.size))


def trend_slope(x: ArrayLike, y: ArrayLike) -> float:
    """
    Least-squares slope of ``y`` against ``x`` (the "reward trend slope" of Figure 9 of the paper).

    :param x: Abscissae, e.g. training steps or episode indices.
    :param y: Ordinates of the same length, e.g. episode rewards.
    :return: The slope of the ordinary least-squares line ``y = slope * x + intercept``.
    :raises ValueError: If fewer than two points are given, the lengths differ, the input contains NaN,
        or all ``x`` are equal (the slope is then undefined).
    """
    xs = _as_sample(x, "x")
    ys = _as_sample(y, "y")
    if xs.size != ys.size:
        raise ValueError(f"x and y must have the same length, got {xs.size} and {ys.size}")
    if xs.size < 2:
        raise ValueError("at least two points are needed for a slope")
    if np.ptp(xs) == 0.0:
        raise ValueError("all x values are equal: the slope is undefined")
    return float(_scipy_stats().linregress(xs, ys).slope)


def paired_t_interval(a: ArrayLike, b: ArrayLike, confidence: float = 0.95) -> dict[str, float]:
    """
    Student t interval of the mean paired difference ``a - b`` (``scipy.stats.ttest_rel``), with its p-value.

    :param a: Results of method A, one per seed.
    :param b: Results of method B, paired with ``a`` element by element.
    :param confidence: Confidence level of the interval (lower it to adjust for several comparisons).
    :return: ``{"difference", "ci_low", "ci_high", "p_value", "n", "standard_error"}``; with identical
        differences the interval is the point (p 0 if it is not 0, else 1); with one pair it is unbounded.
    :raises ValueError: If the samples differ in length, are empty or contain NaN.
    """
    first, second = _as_sample(a, "a"), _as_sample(b, "b")
    if first.shape != second.shape:
        raise ValueError(f"paired samples must have the same length, got {first.size} and {second.size}")
    _check_confidence(confidence)
    diff = first - second
    point = float(diff.mean())
    n = int(diff.size)
    if n < 2:
        return {
            "difference": point,
            "ci_low": -np.inf,
            "ci_high": np.inf,
            "p_value": 1.0,
            "n": n,
            "standard_error": np.inf,
        }
    standard_error = float(diff.std(ddof=1) / np.sqrt(n))
    # Identical differences: certain unless they are all 0 (the t statistic is undefined there).
    p_value = (
        float(point == 0) if standard_error == 0 else float(_scipy_stats().ttest_rel(first, second).pvalue)
    )
    low, high = t_interval(point, standard_error, n, confidence)
    return {
        "difference": point,
        "ci_low": low,
        "ci_high": high,
        "p_value": p_value,
        "n": n,
        "standard_error": standard_error,
    }


def t_interval(mean: float, standard_error: float, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """
    The Student t interval ``mean +- t(n - 1) * standard_error`` at ``confidence`` (e.g. a paired difference's
    interval again at a Bonferroni-adjusted level).
    """
    _check_confidence(confidence)
    if n < 2 or not np.isfinite(standard_error):
        return -np.inf, np.inf
    half = float(_scipy_stats().t.ppf(0.5 + confidence / 2, n - 1)) * standard_error
    return mean - half, mean + half


def bonferroni_confidence(confidence: float, comparisons: int) -> float:
    """
    The confidence of each of ``comparisons`` intervals so that all of them hold together with
    ``confidence`` (Bonferroni: each at ``1 - (1 - confidence) / comparisons``).
    """
    _check_confidence(confidence)
    if comparisons < 1:
        raise ValueError(f"comparisons must be at least 1, got {comparisons}")
    return 1.0 - (1.0 - confidence) / comparisons


def holm_adjust(p_values: Sequence[float]) -> list[float]:
    """
    Holm's step-down adjustment of p-values for the family they form (``scipy.stats`` has no Holm):
    the ``k``-th smallest is multiplied by ``m - k``, made monotone, capped at 1.

    :param p_values: One p-value per comparison of a table.
    :return: The adjusted p-values, in the given order.
    """
    m = len(p_values)
    order = np.argsort(p_values)
    adjusted = np.empty(m)
    running = 0.0
    for rank, index in enumerate(order):
        running = max(running, min(1.0, (m - rank) * float(p_values[index])))
        adjusted[index] = running
    return adjusted.tolist()


#: The equivalence margin of "level": a share of the baseline's mean. Two methods are called level only where
#: the comparison's adjusted interval lies within +- this share of the baseline's mean (:func:`verdict_word`).
EQUIVALENCE_MARGIN = 0.01

#: The family-wise error rate of a table's comparisons: every decision of :func:`holm_family` holds together
#: with probability ``1 - FAMILY_ALPHA``.
FAMILY_ALPHA = 0.05


def holm_confidences(p_values: Sequence[float], alpha: float = FAMILY_ALPHA) -> list[float]:
    """
    The confidence level of each comparison's interval that matches Holm's step-down decisions: the ``k``-th
    smallest p-value (``k`` from 0) is tested at ``alpha / (m - k)`` while every smaller one was rejected; from
    the first that is not, every later comparison keeps that first one's level. An interval at ``1 - level``
    then excludes 0 exactly where Holm rejects (a t interval excludes 0 iff its two-sided p < its level, and a
    later p-value is at least the first retained one, which is at or above that level).

    :param p_values: one two-sided p-value per comparison of the family.
    :param alpha: the family-wise error rate.
    :return: per comparison, in the given order, its interval's confidence level.
    """
    _check_confidence(1.0 - alpha)
    m = len(p_values)
    levels = np.empty(m)
    retained_level: float | None = None
    for rank, index in enumerate(np.argsort(p_values, kind="stable")):
        level = alpha / (m - rank)
        if retained_level is None and not float(p_values[index]) < level:
            retained_level = level
        levels[index] = retained_level if retained_level is not None else level
    return (1.0 - levels).tolist()


def holm_family(differences: Sequence[ArrayLike], alpha: float = FAMILY_ALPHA) -> list[dict[str, float]]:
    """
    One table's paired comparisons under one decision rule: per comparison the paired Student t test over
    seeds, Holm's adjusted p-value over the family, and the t interval at the Holm-consistent level
    (:func:`holm_confidences`), so that ``p_holm < alpha`` and "the interval excludes 0" never disagree.

    :param differences: per comparison, the per-seed differences ``a - b``.
    :param alpha: the family-wise error rate.
    :return: per comparison ``{"difference", "standard_error", "n", "p_value", "p_holm", "confidence",
        "ci_low", "ci_high", "higher"}`` (``higher``: the seeds where ``a > b``).
    """
    tests = [paired_t_interval(np.asarray(d, dtype=np.float64), np.zeros(np.size(d))) for d in differences]
    p_values = [t["p_value"] for t in tests]
    adjusted = holm_adjust(p_values)
    confidences = holm_confidences(p_values, alpha)
    out = []
    for diff, test, p_holm, confidence in zip(differences, tests, adjusted, confidences, strict=True):
        low, high = t_interval(test["difference"], test["standard_error"], int(test["n"]), confidence)
        out.append(
            {
                "difference": test["difference"],
                "standard_error": test["standard_error"],
                "n": test["n"],
                "p_value": test["p_value"],
                "p_holm": p_holm,
                "confidence": confidence,
                "ci_low": low,
                "ci_high": high,
                "higher": float(np.sum(np.asarray(diff, dtype=np.float64) > 0)),
            }
        )
    return out


def verdict_word(
    difference: float,
    ci_low: float,
    ci_high: float,
    p_holm: float,
    n: int,
    higher: int,
    margin: float | None = None,
    alpha: float = FAMILY_ALPHA,
) -> str:
    """
    The words a comparison's test allows, for A against B: ``ahead`` or ``behind`` where Holm rejects (its
    interval then excludes 0 on that side); ``level`` only where the Holm-consistent interval lies within
    ``[-margin, margin]`` (an equivalence test, TOST, at that interval's level); else ``not distinguishable
    (n seeds; higher in k of n)``.

    :param difference: the mean paired difference A - B.
    :param ci_low: the comparison's adjusted interval (:func:`holm_family`).
    :param ci_high: its upper bound.
    :param p_holm: the Holm-adjusted p-value.
    :param n: the seeds.
    :param higher: the seeds where A scored above B.
    :param margin: the equivalence margin (``None``: no equivalence is claimed).
    :param alpha: the family-wise error rate.
    """
    if p_holm < alpha:
        return "ahead" if difference > 0 else "behind"
    if margin is not None and -margin <= ci_low and ci_high <= margin:
        return "level"
    return f"not distinguishable ({n} seeds; higher in {higher} of {n})"


def summarise(
    values: ArrayLike,
    confidence: float = 0.95,
    n_resamples: int = 10_000,
    seed: int | np.random.Generator | None = 0,
) -> Summary:
    """
    Summary of per-seed results: mean, spread, bootstrap CI of the mean and IQM.

    :param values: Array-like of numbers, e.g. one final score per seed.
    :param confidence: Confidence level of the interval.
    :param n_resamples: Number of bootstrap resamples.
    :param seed: Seed or generator for the resampling.
    :return: ``{"mean", "std", "n", "ci_low", "ci_high", "iqm"}``; ``std`` is the sample standard
        deviation (``ddof=1``), 0.0 for a single value; the interval is that of the mean.
    :raises ValueError: On empty input or NaN values.
    """
    sample = _as_sample(values)
    mean, low, high = bootstrap_ci(sample, np.mean, confidence, n_resamples, seed)
    return {
        "mean": mean,
        "std": float(sample.std(ddof=1)) if sample.size > 1 else 0.0,
        "n": int(sample.size),
        "ci_low": low,
        "ci_high": high,
        "iqm": float(iqm(sample)),
    }


__all__ = [
    "EQUIVALENCE_MARGIN",
    "FAMILY_ALPHA",
    "bonferroni_confidence",
    "bootstrap_ci",
    "holm_adjust",
    "holm_confidences",
    "holm_family",
    "iqm",
    "paired_difference_ci",
    "paired_t_interval",
    "probability_of_improvement",
    "summarise",
    "t_interval",
    "trend_slope",
    "verdict_word",
]

"""Statistics for comparing RL methods over seeds (numpy only).

Per-seed results are small samples (typically 3-20 seeds), so every summary comes with a percentile
bootstrap confidence interval, and the robust aggregate of rliable (Agarwal et al., NeurIPS 2021), the
interquartile mean, is offered next to the mean. :func:`trend_slope` is the "reward trend slope" of
Figure 9 of the paper (least-squares slope of reward over training).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

#: A statistic maps a 1-D sample to a number. If it accepts an ``axis`` keyword (as ``np.mean``,
#: ``np.median`` and :func:`iqm` do) the bootstrap evaluates it on many resamples at once.
Statistic = Callable[..., Any]

#: Upper bound on the number of resampled values held in memory at once by :func:`bootstrap_ci`.
_MAX_BATCH_ELEMENTS = 2_000_000


def _as_sample(values: Any, name: str = "values") -> np.ndarray:
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


def _apply_to_rows(statistic: Statistic, resamples: np.ndarray) -> np.ndarray:
    """Evaluate ``statistic`` on each row, vectorised via ``axis=1`` when the statistic supports it."""
    try:
        result = np.asarray(statistic(resamples, axis=1), dtype=np.float64)
        if result.shape == (resamples.shape[0],):
            return result
    except TypeError:
        pass
    return np.array([float(statistic(row)) for row in resamples], dtype=np.float64)


def iqm(values: Any, axis: int | None = None) -> Any:
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
    n = array.shape[axis]
    if n == 0:
        raise ValueError("values is empty: at least one value is needed")
    cut = int(0.25 * n)
    ordered = np.sort(array, axis=axis)
    middle = np.take(ordered, np.arange(cut, n - cut), axis=axis)
    result = middle.mean(axis=axis)
    return float(result) if np.ndim(result) == 0 else result


def bootstrap_ci(
    values: Any,
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
    n = sample.size
    if n == 1:
        return point, point, point
    rng = np.random.default_rng(seed)
    batch = max(1, min(n_resamples, _MAX_BATCH_ELEMENTS // n))
    estimates = np.empty(n_resamples, dtype=np.float64)
    for start in range(0, n_resamples, batch):
        stop = min(start + batch, n_resamples)
        indices = rng.integers(0, n, size=(stop - start, n))
        estimates[start:stop] = _apply_to_rows(statistic, sample[indices])
    alpha = 1.0 - confidence
    low, high = np.quantile(estimates, [alpha / 2.0, 1.0 - alpha / 2.0])
    # Guard against floating-point noise making a constant sample's interval not contain the point.
    return point, float(min(low, point)), float(max(high, point))


def paired_difference_ci(
    a: Any,
    b: Any,
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


def probability_of_improvement(a: Any, b: Any) -> float:
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
    second = np.sort(_as_sample(b, "b"))
    below = np.searchsorted(second, first, side="left")  # values of b strictly below each a_i
    below_or_equal = np.searchsorted(second, first, side="right")
    wins = below.sum() + 0.5 * (below_or_equal - below).sum()
    return float(wins / (first.size * second.size))


def trend_slope(x: Any, y: Any) -> float:
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
    dx = xs - xs.mean()
    denominator = float(np.dot(dx, dx))
    if denominator == 0.0:
        raise ValueError("all x values are equal: the slope is undefined")
    return float(np.dot(dx, ys - ys.mean()) / denominator)


def summarise(
    values: Any,
    confidence: float = 0.95,
    n_resamples: int = 10_000,
    seed: int | np.random.Generator | None = 0,
) -> dict[str, float | int]:
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
        "iqm": iqm(sample),
    }


__all__ = [
    "bootstrap_ci",
    "iqm",
    "paired_difference_ci",
    "probability_of_improvement",
    "summarise",
    "trend_slope",
]

"""Statistics over seeds: known answers for the bootstrap, IQM, slopes and probability of improvement."""

import math

import numpy as np
import pytest

from hddpg_zoo.stats import (
    bootstrap_ci,
    iqm,
    paired_difference_ci,
    probability_of_improvement,
    summarise,
    trend_slope,
)


def test_constant_data_gives_zero_width_ci():
    point, low, high = bootstrap_ci([2.5] * 7)
    assert point == low == high == 2.5


def test_single_value_collapses_interval():
    assert bootstrap_ci([4.0]) == (4.0, 4.0, 4.0)
    assert bootstrap_ci(np.array([[-1.5]]), statistic=np.median) == (-1.5, -1.5, -1.5)


def test_ci_of_large_normal_sample_covers_mean_with_expected_width():
    rng = np.random.default_rng(123)
    true_mean, sigma, n = 5.0, 2.0, 2_000
    sample = rng.normal(true_mean, sigma, size=n)
    point, low, high = bootstrap_ci(sample, n_resamples=4_000, seed=1)
    assert low < true_mean < high
    assert low < point < high
    expected_width = 2 * 1.959964 * sigma / math.sqrt(n)
    assert (high - low) == pytest.approx(expected_width, rel=0.1)


def test_ci_narrows_with_lower_confidence_and_is_reproducible():
    sample = np.arange(20.0)
    wide = bootstrap_ci(sample, confidence=0.99, seed=3)
    narrow = bootstrap_ci(sample, confidence=0.5, seed=3)
    assert wide[1] < narrow[1] < narrow[2] < wide[2]
    assert bootstrap_ci(sample, seed=3) == bootstrap_ci(sample, seed=3)


def test_ci_with_statistic_without_axis_matches_vectorised_path():
    sample = np.random.default_rng(0).exponential(size=15)
    vectorised = bootstrap_ci(sample, statistic=np.median, n_resamples=500, seed=7)
    looped = bootstrap_ci(sample, statistic=lambda v: np.median(v), n_resamples=500, seed=7)
    assert vectorised == pytest.approx(looped)
    point, low, high = bootstrap_ci(sample, statistic=iqm, n_resamples=500)
    assert point == iqm(sample)
    assert low <= point <= high


def test_iqm_known_values():
    assert iqm(np.arange(1, 9)) == pytest.approx(4.5)  # mean of 3, 4, 5, 6
    assert iqm([1, 2, 3, 4, 100, -100, 5, 6]) == pytest.approx(3.5)  # outliers trimmed
    # trim_mean(0.25) semantics: n = 5 trims floor(1.25) = 1 value at each end.
    assert iqm([10, 1, 2, 3, -10]) == pytest.approx(2.0)
    # fewer than 4 values: nothing trimmed.
    assert iqm([1, 2, 9]) == pytest.approx(4.0)
    rows = np.array([np.arange(1, 9), np.arange(1, 9) * 2.0])
    np.testing.assert_allclose(iqm(rows, axis=1), [4.5, 9.0])


def test_trend_slope():
    x = np.arange(10)
    assert trend_slope(x, 3 * x + 1) == pytest.approx(3.0)
    assert trend_slope([0, 1, 2], [5, 5, 5]) == pytest.approx(0.0)
    rng = np.random.default_rng(0)
    xs = np.linspace(0, 100, 500)
    noisy = -0.2 * xs + rng.normal(0, 1, xs.size)
    assert trend_slope(xs, noisy) == pytest.approx(-0.2, abs=0.01)


def test_paired_difference_ci():
    a = np.array([10.0, 12.0, 9.0, 15.0, 11.0])
    point, low, high = paired_difference_ci(a + 2.0, a)
    assert point == low == high == pytest.approx(2.0)
    rng = np.random.default_rng(5)
    base = rng.normal(0, 10, size=30)  # large shared seed effect, small consistent improvement
    better = base + 1.0 + rng.normal(0, 0.1, size=30)
    point, low, high = paired_difference_ci(better, base)
    assert 0.0 < low < point < high
    assert point == pytest.approx(1.0, abs=0.1)


def test_probability_of_improvement():
    assert probability_of_improvement([5, 6, 7], [1, 2, 3]) == 1.0
    assert probability_of_improvement([1, 2, 3], [5, 6, 7, 8]) == 0.0
    assert probability_of_improvement([1, 1], [1, 1, 1]) == 0.5
    # 2 beats 1 and ties 2; 1 ties 1 and loses to 2: (1 + 0.5 + 0.5 + 0) / 4.
    assert probability_of_improvement([1, 2], [1, 2]) == pytest.approx(0.5)
    assert probability_of_improvement([3], [1, 3, 5, 2]) == pytest.approx((2 + 0.5) / 4)
    rng = np.random.default_rng(1)
    x, y = rng.normal(size=40), rng.normal(size=25)
    brute = np.mean((x[:, None] > y[None, :]) + 0.5 * (x[:, None] == y[None, :]))
    assert probability_of_improvement(x, y) == pytest.approx(brute)
    assert probability_of_improvement(x, y) + probability_of_improvement(y, x) == pytest.approx(1.0)


def test_summarise():
    values = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0]
    summary = summarise(values)
    assert set(summary) == {"mean", "std", "n", "ci_low", "ci_high", "iqm"}
    assert summary["mean"] == pytest.approx(4.5)
    assert summary["std"] == pytest.approx(np.std(values, ddof=1))
    assert summary["n"] == 8
    assert summary["iqm"] == pytest.approx(4.5)
    assert summary["ci_low"] < 4.5 < summary["ci_high"]
    single = summarise([3.0])
    assert single["std"] == 0.0
    assert single["ci_low"] == single["ci_high"] == 3.0


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: bootstrap_ci([]), "empty"),
        (lambda: bootstrap_ci([1.0, float("nan")]), "NaN"),
        (lambda: bootstrap_ci([1.0, float("inf")]), "infinite"),
        (lambda: bootstrap_ci(["a", "b"]), "numeric"),
        (lambda: bootstrap_ci([1.0, 2.0], confidence=1.0), "confidence"),
        (lambda: bootstrap_ci([1.0, 2.0], n_resamples=0), "n_resamples"),
        (lambda: iqm([]), "empty"),
        (lambda: iqm([np.nan]), "NaN"),
        (lambda: trend_slope([1], [2]), "two points"),
        (lambda: trend_slope([1, 2], [1, 2, 3]), "same length"),
        (lambda: trend_slope([1, 1, 1], [1, 2, 3]), "equal"),
        (lambda: trend_slope([1, 2], [1, np.nan]), "NaN"),
        (lambda: paired_difference_ci([1, 2], [1, 2, 3]), "same length"),
        (lambda: paired_difference_ci([1, 2], [1, np.nan]), "NaN"),
        (lambda: probability_of_improvement([], [1]), "empty"),
        (lambda: summarise([]), "empty"),
    ],
)
def test_bad_input_raises(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_paired_t_interval_is_scipys_and_wider_than_the_bootstrap_at_five_seeds():
    from scipy import stats as scipy_stats

    from hddpg_zoo.stats import paired_t_interval

    # The case: HDDPG's and HAM's collisions on five seeds; the percentile bootstrap gave
    # [-8.16, -0.54], the t interval includes 0.
    hddpg = [4.40, 5.95, 15.05, 5.30, 11.15]
    ham = [14.85, 11.65, 13.95, 12.40, 10.75]
    interval = paired_t_interval(hddpg, ham)
    expected = scipy_stats.ttest_rel(hddpg, ham).confidence_interval(0.95)
    assert (interval["ci_low"], interval["ci_high"]) == pytest.approx((expected.low, expected.high))
    assert interval["ci_low"] == pytest.approx(-10.52, abs=0.01) and interval["ci_high"] == pytest.approx(
        1.82, abs=0.01
    )
    assert interval["p_value"] == pytest.approx(scipy_stats.ttest_rel(hddpg, ham).pvalue)
    # Identical differences: the interval is the point; one pair: unbounded.
    same = paired_t_interval([3.0, 4.0], [1.0, 2.0])
    assert same["ci_low"] == same["ci_high"] == 2.0 and same["p_value"] == 0.0
    assert paired_t_interval([1.0], [0.0])["ci_high"] == math.inf


def test_holm_and_bonferroni():
    from hddpg_zoo.stats import bonferroni_confidence, holm_adjust

    assert holm_adjust([0.01, 0.04, 0.03]) == pytest.approx([0.03, 0.06, 0.06])
    assert holm_adjust([0.5, 0.9]) == pytest.approx([1.0, 1.0])
    assert bonferroni_confidence(0.95, 5) == pytest.approx(0.99)
    with pytest.raises(ValueError, match="comparisons"):
        bonferroni_confidence(0.95, 0)


def test_aggregates_are_rliables():
    from rliable import metrics

    from hddpg_zoo.benchmark.aggregates import (
        aggregate_intervals,
        improvement_probabilities,
        iqm_and_mean,
        probability_of_improvement,
        score_matrix,
    )

    rng = np.random.default_rng(0)
    x, y = np.round(rng.normal(size=(6, 4)), 1), np.round(rng.normal(size=(5, 4)), 1)
    assert iqm_and_mean(x) == pytest.approx([metrics.aggregate_iqm(x), metrics.aggregate_mean(x)])
    assert probability_of_improvement(x, y) == pytest.approx(metrics.probability_of_improvement(x, y))
    scores = {"a": x + 1.0, "b": y}
    first = aggregate_intervals(scores)
    assert first == aggregate_intervals(scores)  # seeded: the docs regenerate exactly
    assert first["a"]["iqm"]["ci_low"] <= first["a"]["iqm"]["value"] <= first["a"]["iqm"]["ci_high"]
    poi = improvement_probabilities(scores, [("a", "b")])["a vs b"]
    assert poi["ci_low"] <= poi["value"] <= poi["ci_high"] and poi["value"] > 0.5
    with pytest.raises(ValueError, match="as many scores"):
        score_matrix({0: [1.0, 2.0], 1: [1.0]})

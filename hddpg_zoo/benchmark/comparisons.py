"""
The one decision rule of the benchmark's comparisons: a paired comparison of two methods over their common
seeds (:func:`compare`), Holm's adjustment over each challenger's table (:func:`adjust_for_comparisons`),
and the words a comparison's test allows (:func:`verdict`).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from hddpg_zoo.records.results import Comparison
from hddpg_zoo.records.results_leaves import ComparisonFamily, PairedDifference
from hddpg_zoo.stats import (
    EQUIVALENCE_MARGIN,
    FAMILY_ALPHA,
    holm_adjust,
    holm_confidences,
    paired_t_interval,
    probability_of_improvement,
    t_interval,
    verdict_word,
)

#: The metrics every paired comparison reports.
COMPARED_METRICS = ("mean_reach_reward", "curve_mean", "slope", "success_rate", "collisions_per_episode")


def compare(a: Mapping[int, Mapping[str, float]], b: Mapping[int, Mapping[str, float]]) -> Comparison:
    """
    Paired comparison of two methods over their common seeds (same seed: same workers, same test episodes).

    :param a: seed -> metrics of the challenger.
    :param b: seed -> metrics of the baseline.
    :return: per metric the paired mean difference with its 95 % Student t interval and p-value (adjusted
        for the table by :func:`adjust_for_comparisons`), the relative gain of the means, and the
        probability of improvement of the per-seed values; plus the ratio of mean slopes (the paper's
        "improvement rate").
    """
    seeds = sorted(set(a) & set(b))
    metrics: dict[str, PairedDifference] = {}
    for key in COMPARED_METRICS:
        if not all(key in a[s] and key in b[s] for s in seeds):
            continue  # a metric the env does not report (the snake's success and collisions)
        xa = np.array([a[s][key] for s in seeds])
        xb = np.array([b[s][key] for s in seeds])
        interval = paired_t_interval(xa, xb)
        metrics[key] = {
            "difference": interval["difference"],
            "ci_low": interval["ci_low"],
            "ci_high": interval["ci_high"],
            "p_value": interval["p_value"],
            "standard_error": interval["standard_error"],
            "relative_gain": float(xa.mean() / xb.mean() - 1.0) if xb.mean() != 0 else None,
            "probability_of_improvement": probability_of_improvement(xa, xb),
            "seeds_higher": int(np.sum(xa > xb)),
            "equivalence_margin": float(EQUIVALENCE_MARGIN * abs(xb.mean())),
        }
    mean_b_slope = float(np.mean([b[s]["slope"] for s in seeds]))
    ratio = float(np.mean([a[s]["slope"] for s in seeds]) / mean_b_slope) if mean_b_slope != 0 else None
    return Comparison(tuple(seeds), metrics, ratio)


def adjust_for_comparisons(comparisons: Mapping[str, Comparison]) -> dict[str, ComparisonFamily]:
    """
    Apply the one decision rule to each table's comparisons, in place: a table is one challenger against every
    method it is compared with, per metric. Each comparison gains its Holm-adjusted p-value (``p_holm``) and
    the t interval at its Holm-consistent level (``ci_low_adjusted``, ``ci_high_adjusted``,
    ``confidence_adjusted``: :func:`~hddpg_zoo.stats.holm_confidences`), which excludes 0 exactly
    where ``p_holm < FAMILY_ALPHA``; :func:`~hddpg_zoo.stats.verdict_word` makes the words.

    :param comparisons: ``"A vs B"`` -> :func:`compare`'s result.
    :return: challenger -> ``{"comparisons": per metric the number m, "adjustment"}``.
    """
    families: dict[str, ComparisonFamily] = {}
    by_challenger: dict[str, list[str]] = {}
    for pair in comparisons:
        by_challenger.setdefault(pair.split(" vs ")[0], []).append(pair)
    for challenger, pair_keys in by_challenger.items():
        counts: dict[str, int] = {}
        for metric in COMPARED_METRICS:
            members = [k for k in pair_keys if metric in comparisons[k].metrics]
            if not members:
                continue
            counts[metric] = len(members)
            p_values = [comparisons[k].metrics[metric]["p_value"] for k in members]
            adjusted_p = holm_adjust(p_values)
            confidences = holm_confidences(p_values, FAMILY_ALPHA)
            for key, p_holm, confidence in zip(members, adjusted_p, confidences, strict=True):
                entry = comparisons[key].metrics[metric]
                low, high = t_interval(
                    entry["difference"], entry["standard_error"], len(comparisons[key].seeds), confidence
                )
                entry["p_holm"] = p_holm
                entry["ci_low_adjusted"], entry["ci_high_adjusted"] = low, high
                entry["confidence_adjusted"] = confidence
        families[challenger] = {
            "comparisons": counts,
            "adjustment": (
                f"paired Student t tests over seeds, Holm's step-down over the table's comparisons per metric "
                f"(family-wise error {FAMILY_ALPHA:.2f}); each interval at its Holm-consistent level, so it "
                f"excludes 0 exactly where the Holm-adjusted p-value is below {FAMILY_ALPHA:.2f}; level: the "
                f"interval within +-{EQUIVALENCE_MARGIN:.0%} of the baseline's mean (TOST at the same level)"
            ),
        }
    return families


def verdict(entry: PairedDifference, seeds: int) -> str:
    """The words a comparison's test allows (:func:`~hddpg_zoo.stats.verdict_word`)."""
    return verdict_word(
        entry["difference"],
        entry["ci_low_adjusted"],
        entry["ci_high_adjusted"],
        entry["p_holm"],
        seeds,
        int(entry["seeds_higher"]),
        entry.get("equivalence_margin"),
    )

"""
The blocks a results page holds, generated from a benchmark's results: its tables by name (:data:`TABLES`,
and ``comparisons-METHOD``: one challenger's comparisons) and the README's one results sentence
(:func:`results_sentence`). :mod:`~.pages` writes them into the pages.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np

from hddpg_zoo.benchmark.comparisons import verdict
from hddpg_zoo.benchmark.front_pages import (
    decides_matrix,
    decides_table,
    front_table,
)
from hddpg_zoo.benchmark.report import (
    env_terms,
    score_name,
    ttc_dependence_table,
)
from hddpg_zoo.benchmark.statistics import TRANSFER_FRACTION
from hddpg_zoo.records.results import BenchmarkResults
from hddpg_zoo.records.results_leaves import Aggregates, Interval, PairedDifference, Summary
from hddpg_zoo.stats import EQUIVALENCE_MARGIN, FAMILY_ALPHA, bootstrap_ci
from sb3_hddpg.artifacts.records import JsonObject


def _interval(point: float, entry: Summary | Interval | Mapping[str, float], fmt: str) -> str:
    low, high = entry["ci_low"], entry["ci_high"]
    return f"{point:{fmt}} [{low:{fmt}}, {high:{fmt}}]"


def _aggregates(results: BenchmarkResults) -> Aggregates:
    if results.aggregates is None:
        raise ValueError("no finished method run in this benchmark: no table to write")
    return results.aggregates


def _episodes(results: BenchmarkResults) -> JsonObject:
    return dict(results.test_episode_set or {})


def _unit_text(results: BenchmarkResults) -> str:
    aggregate = _aggregates(results)
    episodes = _episodes(results)
    where = f"{episodes['episodes']} {episodes['name']} episodes (seeds {results.test_seeds[0]}-{results.test_seeds[1]})"
    name = score_name(results)
    spread = (
        " Episode sd: how much one seed's score varies from episode to episode (the root mean of the per-seed "
        "variances), a description of the episodes, not an interval about the method."
        if "episode_spread" in aggregate
        else ""
    )
    return (
        f"Test on {where} per trained model. The unit of every interval is the seed (the independent training "
        f"run): the {name} is each seed's mean over its episodes, with rliable's mean and IQM over the seeds and "
        "stratified bootstrap 95 % intervals; the other columns: mean over seeds with a percentile bootstrap "
        f"95 % interval.{spread}"
    )


def methods_table(results: BenchmarkResults) -> str:
    """
    Per method: the score's mean and IQM with rliable's intervals over seeds and its episode-level spread; on
    the snake arm touch, contacts and success, on another env each term's return (and the crash rate where the
    env has a collision term); the worker choices.
    """
    aggregate = _aggregates(results)
    intervals = aggregate["intervals"]
    spread = aggregate.get("episode_spread")
    terms = env_terms(results)
    # (summary key, format, shown as a percentage, column header)
    columns = (
        [(f"{term}_reach_reward", ".1f", False, f"{term} (normalised sum)") for term in terms]
        if terms
        else [
            ("goal_touch_rate", ".1f", True, "goal touch (% of steps)"),
            ("collisions_per_episode", ".2f", False, "collisions / episode"),
            ("success_rate", ".0f", True, "success (% of episodes)"),
        ]
    )
    if any("crash_rate" in entry.stats for entry in results.methods.values()):
        columns.append(("crash_rate", ".0f", True, "crashes (% of episodes)"))
    headers = [column[3] for column in columns]
    spread_header = "episode sd | " if spread else ""
    lines = [
        _unit_text(results),
        "",
        f"| method | seeds | {score_name(results)}: mean [95 % CI] | IQM [95 % CI] | {spread_header}"
        f"{' | '.join(headers)} | worker choices (test) |",
        "|---|---|---|---|" + ("---|" if spread else "") + "---|" * len(headers) + "---|",
    ]
    for method, entry in results.methods.items():
        s = entry.stats
        cells = [
            _interval(_percent(s[key])["mean"], _percent(s[key]), fmt)
            if percent and key in s
            else _interval(s[key]["mean"], s[key], fmt)
            if key in s
            else "-"
            for key, fmt, percent, _ in columns
        ]
        choices = ", ".join(f"{k} {v:.0%}" for k, v in (entry.selection_rate or {}).items()) or "-"
        mean, iqm = intervals[method]["mean"], intervals[method]["iqm"]
        spread_cell = (f"{spread[method]:.1f} | " if method in spread else "- | ") if spread else ""
        lines.append(
            f"| `{method}` | {len(entry.seeds)} | {_interval(mean['value'], mean, '.1f')} "
            f"| {_interval(iqm['value'], iqm, '.1f')} | {spread_cell}{' | '.join(cells)} | {choices} |"
        )
    conflicts = side_by_side_conflicts(results)
    if conflicts:
        lines += [
            "",
            "Each interval above is one method's alone; the comparison is the paired test over seeds. Where "
            "two intervals read side by side would say more than that test:",
            "",
        ]
        lines += [f"- {note}" for note in conflicts]
    return "\n".join(lines)


def side_by_side_conflicts(results: BenchmarkResults) -> list[str]:
    """
    The methods table's pairs whose printed intervals a reader would take for a difference that the paired test
    over seeds does not show: for every compared pair (A, B) and every column with a paired test (the score's
    mean and IQM, tested on the mean; the collisions), the intervals as printed do not overlap, yet the test's
    word is not "ahead" or "behind" on that side. Each becomes one note under the table.

    :return: one sentence per such pair and column.
    """
    intervals = _aggregates(results)["intervals"]
    notes = []
    for pair, comparison in results.comparisons.items():
        a, b = pair.split(" vs ")
        seeds = len(comparison.seeds)
        columns: list[tuple[str, str, tuple[float, float], tuple[float, float], str]] = [
            (
                f"{score_name(results)} ({name})",
                "mean_reach_reward",
                (intervals[a][name]["ci_low"], intervals[a][name]["ci_high"]),
                (intervals[b][name]["ci_low"], intervals[b][name]["ci_high"]),
                ".1f",
            )
            for name in ("mean", "iqm")
        ]
        if "collisions_per_episode" in comparison.metrics and not env_terms(results):
            sa, sb = (results.methods[m].stats["collisions_per_episode"] for m in (a, b))
            columns.append(
                (
                    "collisions / episode",
                    "collisions_per_episode",
                    (sa["ci_low"], sa["ci_high"]),
                    (sb["ci_low"], sb["ci_high"]),
                    ".2f",
                )
            )
        apart_columns: dict[str, list[str]] = {}
        for label, metric, (a_low, a_high), (b_low, b_high), fmt in columns:
            entry = comparison.metrics.get(metric)
            if entry is None:
                continue
            shown = [float(f"{x:{fmt}}") for x in (a_low, a_high, b_low, b_high)]
            apart = "above" if shown[0] > shown[3] else "below" if shown[1] < shown[2] else None
            if apart is not None and verdict(entry, seeds) != {"above": "ahead", "below": "behind"}[apart]:
                apart_columns.setdefault(metric, []).append(label)
        for metric, labels in apart_columns.items():
            entry = comparison.metrics[metric]
            notes.append(
                f"`{a}` vs `{b}`, {' and '.join(labels)}: the intervals are apart, but the paired test says "
                f"{verdict(entry, seeds)}: difference {_difference_text(entry)}, Holm p {entry['p_holm']:.3f}."
            )
    return notes


def _percent(stats: Summary) -> dict[str, float]:
    return {"mean": 100 * stats["mean"], "ci_low": 100 * stats["ci_low"], "ci_high": 100 * stats["ci_high"]}


def _signed(entry: PairedDifference) -> str:
    """A paired difference with its adjusted interval, bold where the test rejects (the interval excludes 0)."""
    text = _difference_text(entry)
    return f"**{text}**" if entry["p_holm"] < FAMILY_ALPHA else text


def _difference_text(entry: PairedDifference, fmt: str = ".2f") -> str:
    point, low, high = (entry[k] for k in ("difference", "ci_low_adjusted", "ci_high_adjusted"))
    return f"{point:+{fmt}} [{low:+{fmt}}, {high:+{fmt}}]"


def rule_text(seeds: int, m: int) -> str:
    """How a comparison table decides, in one paragraph."""
    return (
        f"{m} comparisons per metric in this table, each paired by seed over the {seeds} seeds (same seed: same "
        "workers, same test episodes). One decision rule: a paired Student t test per comparison, Holm's "
        f"step-down over the table's {m} (family-wise error 5 %); each interval is at its comparison's "
        "Holm-consistent level, so it excludes 0 (bold) exactly where the test says ahead or behind. Level: "
        f"the interval lies within +-{EQUIVALENCE_MARGIN:.0%} of B's mean (an equivalence test at the same "
        "level); otherwise not distinguishable, with the seeds where A scored higher."
    )


def comparisons_table(results: BenchmarkResults, challenger: str) -> str:
    """One challenger against every method it is compared with: the rule's words, adjusted differences, P(A > B)."""
    pairs = {k: v for k, v in results.comparisons.items() if k.split(" vs ")[0] == challenger}
    if not pairs:
        return f"(no comparison of `{challenger}` in this run)"
    family = (results.comparison_families or {})[challenger]
    m = family["comparisons"]["mean_reach_reward"]
    seeds = len(next(iter(pairs.values())).seeds)
    poi = _aggregates(results)["probability_of_improvement"]
    snake = not env_terms(results)
    lines = [
        rule_text(seeds, m) + " P(A > B): rliable's probability of improvement over seeds, a description, "
        "not a test (its bootstrap interval, unadjusted, is in results.json).",
        "",
        f"| {challenger} vs | {score_name(results)}: {challenger} is | difference [adjusted CI] | Holm p "
        f"| P({challenger} > B) "
        + ("| collisions / episode: difference [adjusted CI] | goal touch (points of %) |" if snake else "|"),
        "|---|---|---|---|---|" + ("---|---|" if snake else ""),
    ]
    for pair, comparison in pairs.items():
        baseline = pair.split(" vs ")[1]
        p = poi[pair]
        metrics = comparison.metrics
        reach = metrics["mean_reach_reward"]
        collisions = (
            _signed(metrics["collisions_per_episode"]) if "collisions_per_episode" in metrics else "-"
        )
        touch = results.methods[challenger].stats.get("goal_touch_rate")
        other = results.methods[baseline].stats.get("goal_touch_rate")
        touch_text = f"{100 * (touch['mean'] - other['mean']):+.1f}" if touch and other else "-"
        snake_cells = f" {collisions} | {touch_text} |" if snake else ""
        lines.append(
            f"| `{baseline}` | {verdict(reach, len(comparison.seeds))} | {_signed(reach)} | {reach['p_holm']:.3f} "
            f"| {p['value']:.2f} |{snake_cells}"
        )
    return "\n".join(lines)


def per_seed_table(
    results: BenchmarkResults, key: str = "mean_reach_reward", fmt: str = ".1f", scale: float = 1.0
) -> str:
    """One metric (times ``scale``) per method and seed."""
    seeds = sorted({int(s) for entry in results.methods.values() for s in entry.per_seed})
    lines = [
        "| method | " + " | ".join(f"seed {s}" for s in seeds) + " |",
        "|---|" + "---|" * len(seeds),
    ]
    for method, entry in results.methods.items():
        found = [entry.per_seed.get(str(s), {}).get(key) for s in seeds]
        values = [scale * v if v is not None else None for v in found]
        lines.append(
            f"| `{method}` | " + " | ".join(f"{v:{fmt}}" if v is not None else "-" for v in values) + " |"
        )
    return "\n".join(lines)


def transfer_table(results: BenchmarkResults) -> str:
    """
    The transfer ratios per preference and manager, to one target for both runs (90 % of the way to the better
    final score, a miss censored at the run's last evaluation): where each run got there, in how many seeds the
    manager is sooner, and the geometric mean and median of the ratios with bootstrap intervals over seeds.
    """
    transfer = results.transfer
    if not transfer:
        return "(not a transfer run)"
    first, last = results.curve_seeds
    lines = [
        f"Measured on the learning curves: every evaluation on the {last - first + 1} curve episodes (seeds "
        f"{first}-{last}), every {transfer['eval_freq']} own env steps; not on the test episodes. Target: "
        f"{TRANSFER_FRACTION:.0%} of the way from a random policy's score to the better of the two runs' final "
        "scores (scored with the preference's factors), the same for both, so a run that ends lower cannot win "
        "by reaching its own. Ratio = flat steps / manager steps to the target. A run that never reaches it is "
        "censored at its last evaluation: `>x`, the flat agent missed (the ratio is at least x); `<x`, the "
        "manager missed (at most x). Sooner: the seeds where the ratio is above 1 for certain, and those where "
        "it is at or below 1 for certain. Geometric mean and median over seeds with 95 % percentile bootstrap "
        "intervals (the geometric mean's on the log ratios), censored ratios at their bounds.",
        "",
        "| preference | manager vs flat | seeds reaching: manager / flat | manager sooner / not | geometric mean "
        "[95 % CI] | median [95 % CI] | per seed |",
        "|---|---|---|---|---|---|---|",
    ]
    for preference, entry in transfer["preferences"].items():
        for comparison in entry.values():
            seeds = comparison["per_seed"].values()
            if not all("censored" in v for v in seeds):
                continue  # results written before the common target
            ratios = [
                (v["ratio_to_target"], v["censored"]) for v in seeds if v["ratio_to_target"] is not None
            ]
            if not ratios:
                continue
            values = [r for r, _ in ratios]
            sooner = sum(1 for r, c in ratios if r > 1 and c in ("none", "flat"))
            not_sooner = sum(1 for r, c in ratios if r <= 1 and c in ("none", "manager"))
            manager_reached = sum(v["censored"] in ("none", "flat") for v in seeds)
            flat_reached = sum(v["censored"] in ("none", "manager") for v in seeds)
            logs = bootstrap_ci(np.log(values))
            shown = ", ".join(
                f"{'>' if c == 'flat' else '<' if c == 'manager' else ''}{r:.1f}" for r, c in ratios
            )
            lines.append(
                f"| `{preference}` | `{comparison['manager']}` vs `{comparison['flat']}` "
                f"| {manager_reached} / {flat_reached} of {len(seeds)} | {sooner} / {not_sooner} "
                f"| {_triple(tuple(float(np.exp(x)) for x in logs))} | {_triple(bootstrap_ci(values, np.median))} "
                f"| {shown} |"
            )
    return "\n".join(lines)


def curve_to_test_table(results: BenchmarkResults) -> str:
    """
    Per method and seed: the test's score (the normalised return, or the snake's reach reward) at the learning
    curve's best evaluation on the curve episodes, the test episodes' score, and the drop between them.
    """
    first, last = results.curve_seeds
    name = score_name(results)
    lines = [
        f"The {name} on the curve episodes (seeds {first}-{last}) at each run's best curve evaluation, against "
        f"the {name} on the test episodes, per seed: best curve / test (drop).",
        "",
    ]
    seeds = sorted({int(s) for entry in results.methods.values() for s in entry.per_seed})
    lines += [
        "| method | " + " | ".join(f"seed {s}" for s in seeds) + " | mean drop |",
        "|---|" + "---|" * (len(seeds) + 1),
    ]
    for method, entry in results.methods.items():
        cells, drops = [], []
        for seed in seeds:
            values = entry.per_seed.get(str(seed), {})
            if "best_curve_reward" not in values:
                cells.append("-")
                continue
            best, test = values["best_curve_reward"], values["mean_reach_reward"]
            drops.append(best - test)
            cells.append(f"{best:.1f} / {test:.1f} ({best - test:.1f})")
        mean = f"{np.mean(drops):.1f}" if drops else "-"
        lines.append(f"| `{method}` | " + " | ".join(cells) + f" | {mean} |")
    return "\n".join(lines)


def _triple(values: tuple[float, ...]) -> str:
    point, low, high = values
    return f"{point:.1f} [{low:.1f}, {high:.1f}]"


#: Every table a page can hold, by name: ``results -> Markdown``.
TABLES: dict[str, Callable[[BenchmarkResults], str]] = {
    "methods": methods_table,
    "per-seed-reach": per_seed_table,
    "per-seed-touch": lambda r: per_seed_table(r, "goal_touch_rate", ".1f", 100.0),
    "per-seed-collisions": lambda r: per_seed_table(r, "collisions_per_episode", ".2f"),
    # A policy's outputs pinned at +-1: an actor's joint commands, a hierarchy's manager output.
    "per-seed-saturation": lambda r: per_seed_table(r, "action_saturation", ".1f", 100.0),
    "transfer": transfer_table,
    "curve-to-test": curve_to_test_table,
    "front": lambda r: "\n".join(front_table(r.front)) if r.front is not None else "(not a front run)",
    "front-decides": lambda r: (
        "\n".join(decides_table(r.front)) if r.front is not None else "(not a front run)"
    ),
    "front-decides-ratios": lambda r: (
        "\n".join(decides_matrix(r.front)) or "(no decisions by state)"
        if r.front is not None
        else "(not a front run)"
    ),
    "decides-ttc": lambda r: "\n".join(ttc_dependence_table(r)[0]) or "(no decisions by time to collision)",
}
#: The tables a page can hold besides :data:`TABLES`: one challenger's comparisons, for each method of the run.
COMPARISONS = "comparisons-"


def results_sentence(results: BenchmarkResults, run_name: str) -> str:
    """
    The README's results sentence: each challenger's mean score (``hddpg``, ``hddpg-front``, ...: every method
    the run compares with the others), and for every method it is compared with the word the comparison's
    test allows (:func:`verdict`): ahead of, level with, behind, or not distinguishable from (with the seeds
    where the challenger scored higher), each beside the paired difference and its adjusted interval it
    follows from. No interval of one method is printed beside another's point or interval: read side by side,
    two such intervals can say what the paired test does not.

    :raises ValueError: the run compares no challenger with another method.
    """
    intervals = _aggregates(results)["intervals"]
    verdicts: dict[str, dict[str, list[str]]] = {}
    for pair, comparison in results.comparisons.items():
        challenger, baseline = pair.split(" vs ")
        groups = verdicts.setdefault(
            challenger, {"ahead of": [], "level with": [], "behind": [], "not distinguishable from": []}
        )
        entry = comparison.metrics["mean_reach_reward"]
        word = verdict(entry, len(comparison.seeds))
        mean = results.methods[baseline].stats["mean_reach_reward"]["mean"]
        shown = f"{mean:.1f}; {_difference_text(entry, '.1f')}"
        if word in ("ahead", "behind"):
            groups["ahead of" if word == "ahead" else "behind"].append(f"`{baseline}` ({shown})")
        elif word == "level":
            groups["level with"].append(f"`{baseline}` ({shown})")
        else:
            groups["not distinguishable from"].append(
                f"`{baseline}` ({shown}, higher in {int(entry['seeds_higher'])} of {len(comparison.seeds)})"
            )
    if not verdicts:
        raise ValueError("no method of this benchmark is compared with another: no results sentence to write")
    clauses = []
    for challenger, groups in verdicts.items():
        score = intervals[challenger]["mean"]
        verdict_text = "; ".join(f"{word} {', '.join(names)}" for word, names in groups.items() if names)
        clauses.append(f"`{challenger}` scores {score['value']:.1f}: {verdict_text}.")
    episodes = _episodes(results)
    seeds = max(len(results.methods[challenger].seeds) for challenger in verdicts)
    return (
        f"On the {seeds}-seed benchmark `{run_name}` ({episodes['episodes']} {episodes['name']} episodes per model; "
        f"{score_name(results)}; in brackets the paired difference over seeds with its Holm-adjusted interval, "
        f"from which each word follows; level only within +-{EQUIVALENCE_MARGIN:.0%}, docs/RESULTS.md): "
        + " ".join(clauses)
    )

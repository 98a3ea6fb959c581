"""
The benchmark's results as console tables: title, columns and text cells from a ``results.json`` dict, for
any front end to render (``hddpg-cli benchmark`` draws them with rich). ``results.md`` (:mod:`.report`) and
the docs' pages (:mod:`.pages`) are the Markdown views of the same results.
"""

from __future__ import annotations

from dataclasses import dataclass

from hddpg_zoo.benchmark.comparisons import verdict
from hddpg_zoo.benchmark.report import ci_text, final_scores_text, flat_reaches_text
from hddpg_zoo.records.results import BenchmarkResults
from hddpg_zoo.records.results_leaves import TransferResults
from sb3_hddpg.evaluation import dependence_ratio_text
from sb3_hddpg.metric_labels import metric_label


@dataclass(frozen=True)
class TextTable:
    """
    A table of text cells.

    :param title: the table's title.
    :param columns: the column headers.
    :param rows: the rows, one text per column.
    :param left: the columns aligned left (the others are numbers, aligned right).
    :param fold: fold a cell narrower than a word onto several lines rather than cut it.
    """

    title: str
    columns: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    left: tuple[str, ...]
    fold: bool = False


def wall_time_text(results: BenchmarkResults) -> str:
    """The wall time of this invocation, and over every invocation of a resumed benchmark."""
    run = results.run
    if run is None:
        return "not recorded"
    text = f"{run.wall_time_s_this_invocation / 60:.1f} min"
    count = run.invocations or 1
    if count > 1 and run.wall_time_s_all_invocations is not None:
        text += f" ({run.wall_time_s_all_invocations / 60:.1f} min over its {count} invocations)"
    return text


def results_table(results: BenchmarkResults) -> TextTable:
    """The per-method table: final test metrics and learning-curve statistics, mean [95 % CI] over seeds."""
    episode_set = (results.test_episode_set or {}).get("name", "the")
    title = (
        f"Benchmark: mean [95 % bootstrap CI] over seeds; {episode_set} test episodes "
        f"from seed {results.test_seeds[0]}; "
        f"curve window {results.curve_window} own steps"
    )
    # The snake's own metrics only where some method's env reports them (the snake arm).
    snake = [
        (key, header, fmt)
        for key, header, fmt in (
            ("goal_touch_rate", "goal touch", ".1%"),
            ("collisions_per_episode", "contact steps /ep", ".2f"),
            ("success_rate", "success", ".0%"),
        )
        if any(key in entry.stats for entry in results.methods.values())
    ]
    columns = (
        "method",
        "seeds",
        f"{metric_label('mean_reach_reward').short} (test)",
        "IQM",
        *(header for _, header, _ in snake),
        "curve mean",
        f"slope /{results.slope_unit_steps} steps",
    )
    rows = []
    for method, entry in results.methods.items():
        s = entry.stats
        rows.append(
            (
                method,
                str(len(entry.seeds)),
                ci_text(s["mean_reach_reward"], ".1f"),
                f"{s['mean_reach_reward']['iqm']:.1f}",
                *(ci_text(s[key], fmt) if key in s else "-" for key, _, fmt in snake),
                ci_text(s["curve_mean"], ".1f"),
                ci_text(s["slope"], ".2f"),
            )
        )
    # Folded, not cut, where a column is narrower than a word in an 80-column terminal.
    return TextTable(title, columns, tuple(rows), left=("method",), fold=True)


def comparisons_table(results: BenchmarkResults) -> TextTable:
    """The paired comparisons: difference [adjusted t CI], relative gain, probability of improvement."""
    title = (
        "Paired comparisons over common seeds (A - B): Student t tests, Holm-adjusted over each challenger's "
        "comparisons, each interval at its Holm-consistent level (results.json: comparison_families)"
    )
    columns = ("A vs B", "metric", "A is", "difference [adjusted CI]", "relative", "P(A > B)")
    rows = []
    for pair, comparison in results.comparisons.items():
        for metric in ("mean_reach_reward", "curve_mean", "slope"):
            c = comparison.metrics[metric]
            relative = f"{c['relative_gain']:+.1%}" if c["relative_gain"] is not None else "-"
            rows.append(
                (
                    pair,
                    metric,
                    verdict(c, len(comparison.seeds)),
                    f"{c['difference']:+.2f} [{c['ci_low_adjusted']:+.2f}, {c['ci_high_adjusted']:+.2f}]",
                    relative,
                    f"{c['probability_of_improvement']:.2f}",
                )
            )
    return TextTable(title, columns, tuple(rows), left=("A vs B", "metric"))


def _steps(steps: int | None) -> str:
    return str(steps) if steps is not None else "no gain"  # the curve ended at or below the random score


def transfer_table(transfer: TransferResults) -> TextTable:
    """
    The transfer figure: per preference, manager and flat method, steps to the final score's fraction and
    their ratio.
    """
    columns = (
        "preference",
        "manager",
        "flat",
        "seeds",
        "ratio flat / manager [95 % CI]",
        "final score manager / flat",
        "flat reaches the manager's final",
        "per seed (flat / manager steps)",
    )
    rows = []
    for preference, entry in transfer["preferences"].items():
        for comparison in entry.values():
            ratio = comparison["ratio"]
            per_seed = ", ".join(
                f"{_steps(v['flat_steps'])} / {_steps(v['manager_steps'])}"
                for v in comparison["per_seed"].values()
            )
            rows.append(
                (
                    preference,
                    comparison["manager"],
                    comparison["flat"],
                    f"{comparison['seeds_with_ratio']}/{len(comparison['per_seed'])}",
                    ci_text(ratio, ".2f") if ratio else "undefined",
                    final_scores_text(comparison),
                    flat_reaches_text(comparison),
                    per_seed,
                )
            )
    title = f"Transfer: {transfer['definition']}"
    return TextTable(title, columns, tuple(rows), left=("preference", "manager", "flat"))


def dependence_table(results: BenchmarkResults) -> TextTable | None:
    """
    Per method and seed: the avoid worker's share near obstacles vs with none in range, and the ratio
    (``None`` where no run reports it).
    """
    figures = [
        (method, seed, figure)
        for method, entry in results.methods.items()
        for seed, figure in (entry.state_dependence or {}).items()
        if figure is not None
    ]
    if not figures:
        return None
    worker = figures[0][2]["worker"]
    title = f"State dependence (test): the {worker} worker's share of choices by nearest-obstacle clearance"
    columns = ("method", "seed", "near (<= half sensor range)", "none in range", "ratio")
    rows = tuple(
        (
            method,
            str(seed),
            f"{figure['near_share']:.1%}" if figure["near_share"] is not None else "-",
            f"{figure['clear_share']:.1%}" if figure["clear_share"] is not None else "-",
            dependence_ratio_text(dict(figure)),
        )
        for method, seed, figure in figures
    )
    return TextTable(title, columns, rows, left=("method",))


def console_tables(results: BenchmarkResults) -> list[TextTable]:
    """
    Every table of a benchmark's results, in the order ``hddpg-cli benchmark`` prints them: the methods,
    the paired comparisons (if any), the state dependence (where reported) and the transfer (its scenario).
    """
    tables = [results_table(results)]
    if results.comparisons:
        tables.append(comparisons_table(results))
    dependence = dependence_table(results)
    if dependence is not None:
        tables.append(dependence)
    if results.transfer is not None:
        tables.append(transfer_table(results.transfer))
    return tables

"""The benchmark's report: ``results.json``, ``results.md``, ``evaluations.csv`` and the figures."""

from __future__ import annotations

import csv
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np

from hddpg_zoo.benchmark.aggregates import performance_profiles
from hddpg_zoo.benchmark.comparisons import verdict
from hddpg_zoo.benchmark.episodes import records_episode_rows, write_episodes_csv
from hddpg_zoo.benchmark.front_pages import decides_table, front_figure, front_table
from hddpg_zoo.benchmark.methods import WORKERS
from hddpg_zoo.benchmark.statistics import (
    curve_bands,
    records_by_method,
    score_matrices,
    with_term_sums,
)
from hddpg_zoo.media import figures
from hddpg_zoo.media.aggregate_plots import aggregate_figure
from hddpg_zoo.records.results import BenchmarkResults
from hddpg_zoo.records.results_leaves import Summary, TransferComparison
from sb3_hddpg.artifacts.io import atomic_write, atomic_write_json
from sb3_hddpg.artifacts.records import JsonObject
from sb3_hddpg.evaluation import dependence_ratio_text

# ---------------------------------------------------------------------------------------------- outputs
#: Columns of ``evaluations.csv`` before the metrics.
CSV_KEYS = ("method", "seed", "kind", "timesteps", "total_timesteps")


#: A row of a CSV file: column -> value.
CsvRow = dict[str, object]


def evaluation_rows(records: Iterable[JsonObject]) -> list[CsvRow]:
    """Every evaluation of every run as flat rows (``kind``: ``curve``, ``test`` or ``worker-<name>``)."""
    rows: list[CsvRow] = []
    for record in records:
        base: CsvRow = {"method": record["method"], "seed": record["seed"]}
        if record["method"] == WORKERS:
            for name, history in record["history"].items():
                rows.extend({**base, "kind": f"worker-{name}", **_flat(p)} for p in history)
            continue
        rows.extend({**base, "kind": "curve", **_flat(p)} for p in record["history"])
        last = record["history"][-1]
        rows.append(
            {
                **base,
                "kind": "test",
                "timesteps": last["timesteps"],
                "total_timesteps": last["total_timesteps"],
                **_flat(with_term_sums(record["test"])),
            }
        )
    return rows


def _flat(point: Mapping[str, object]) -> CsvRow:
    row: CsvRow = {}
    for key, value in point.items():
        if isinstance(value, dict):
            row.update({f"{key}.{name}": v for name, v in value.items()})
        else:
            row[key] = value
    return row


def write_csv(path: Path, rows: list[CsvRow]) -> Path:
    """Write rows as CSV atomically, with the union of their keys as columns."""
    metric_keys = sorted({k for row in rows for k in row} - set(CSV_KEYS))

    def write(tmp: Path) -> None:
        with open(tmp, "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=[*CSV_KEYS, *metric_keys], restval="")
            writer.writeheader()
            writer.writerows(rows)

    return atomic_write(path, write)


#: The files :func:`write_outputs` produces in the benchmark folder: every one on the snake arm's standard
#: run, some only where the run has what they show (Figure 10 the snake's managers, ``fronts.png`` a front).
OUTPUT_FILES = (
    "results.json",
    "results.md",
    "evaluations.csv",
    "episodes.csv",
    "learning_curves.png",
    "figure9.png",
    "figure10.png",
    "aggregates.png",
    "performance_profile.png",
    "fronts.png",
)


def output_files_in(out: Path) -> list[str]:
    """The files of :data:`OUTPUT_FILES` in the benchmark folder ``out``, in that order."""
    return [name for name in OUTPUT_FILES if (out / name).is_file()]


def ci_text(stats: Summary, fmt: str) -> str:
    """``mean [ci_low, ci_high]`` of a statistic, each in ``fmt``."""
    return f"{stats['mean']:{fmt}} [{stats['ci_low']:{fmt}}, {stats['ci_high']:{fmt}}]"


def markdown_report(results: BenchmarkResults) -> str:
    """
    The results as Markdown tables (for docs): per method the test metrics and curve statistics as
    mean [95 % bootstrap CI] over seeds, then the paired comparisons.

    :param results: the results.
    """
    lines = _methods_lines(results)
    if results.comparisons:
        lines += [
            "",
            "Comparisons: paired Student t tests over seeds, Holm-adjusted over each challenger's comparisons per "
            "metric (their number: results.json, comparison_families); each interval at its Holm-consistent "
            "level, so it excludes 0 exactly where A is ahead or behind; level only within +-1 % of B's mean.",
            "",
            "| A vs B | metric | A is | A - B [adjusted CI], paired by seed | relative | P(A > B) |",
            "|---|---|---|---|---|---|",
        ]
        for pair, comparison in results.comparisons.items():
            for metric in (
                "mean_reach_reward",
                "curve_mean",
                "slope",
                "success_rate",
                "collisions_per_episode",
            ):
                if metric not in comparison.metrics:
                    continue
                c = comparison.metrics[metric]
                relative = f"{c['relative_gain']:+.1%}" if c["relative_gain"] is not None else "-"
                word = verdict(c, len(comparison.seeds)) if "p_holm" in c else "-"
                lines.append(
                    f"| {pair} | {metric} | {word} | {c['difference']:+.2f} "
                    f"[{c['ci_low_adjusted']:+.2f}, {c['ci_high_adjusted']:+.2f}] "
                    f"| {relative} | {c['probability_of_improvement']:.2f} |"
                )
            ratio = comparison.slope_ratio
            lines.append(
                f"| {pair} | slope ratio A / B | | {ratio:.2f} | | |"
                if ratio is not None
                else f"| {pair} | slope ratio A / B | | undefined (B's slope is 0) | | |"
            )
    lines += _dependence_lines(results)
    lines += _ttc_dependence_lines(results)
    lines += _transfer_lines(results)
    lines += _front_lines(results)
    return "\n".join(lines) + "\n"


def _methods_lines(results: BenchmarkResults) -> list[str]:
    """
    Per method its test score and IQM, the score's parts (the snake's goal and avoid parts with touch, contacts
    and success; on another env each term's normalised sum), saturation, the curve's statistics and choices.
    """
    unit = results.slope_unit_steps
    terms = env_terms(results)
    # (summary key, format, column header)
    parts = (
        [(f"{term}_reach_reward", ".1f", f"{term} part") for term in terms]
        if terms
        else [
            ("goal_reach_reward", ".1f", "goal part"),
            ("avoid_reach_reward", ".1f", "avoid part"),
            ("goal_touch_rate", ".3f", "goal-touch rate"),
            ("collisions_per_episode", ".2f", "collisions / episode"),
            ("success_rate", ".2f", "success"),
        ]
    )
    # Clearance needs an env that declares obstacles (the snake arm, or a user's env with `proximity`).
    clearance = not terms or any("min_clearance" in entry.stats for entry in results.methods.values())
    headers = [header for _, _, header in parts] + (["min clearance"] if clearance else [])
    lines = [
        f"| method | seeds | {score_name(results)} (test) | IQM | {' | '.join(headers)} | saturated actions "
        f"| curve mean | slope / {unit} steps | worker choices (test) |",
        "|---|---|---|---|" + "---|" * len(headers) + "---|---|---|---|",
    ]
    for method, entry in results.methods.items():
        s = entry.stats
        choices = ", ".join(f"{k} {v:.0%}" for k, v in (entry.selection_rate or {}).items()) or "-"
        # The deciding network's saturation (the manager's for hierarchies); absent in older results.
        saturation = f"{s['action_saturation']['mean']:.0%}" if "action_saturation" in s else "-"
        cells = [ci_text(s[key], fmt) if key in s else "-" for key, fmt, _ in parts]
        if clearance:
            cells.append(f"{s['min_clearance']['mean']:.3f}" if "min_clearance" in s else "-")
        lines.append(
            f"| {method} | {len(entry.seeds)} | {ci_text(s['mean_reach_reward'], '.1f')} "
            f"| {s['mean_reach_reward']['iqm']:.1f} | {' | '.join(cells)} | {saturation} "
            f"| {ci_text(s['curve_mean'], '.1f')} | {ci_text(s['slope'], '.2f')} | {choices} |"
        )
    return lines


def _front_lines(results: BenchmarkResults) -> list[str]:
    """The front's table and, where it counted them, the conditioned manager's decisions by state."""
    if results.front is None:
        return []
    lines = ["", "**The front** (hypervolume per member over seeds; `benchmark --scenario front`):", ""]
    lines += front_table(results.front)
    decides = decides_table(results.front)
    if len(decides) > 2:  # more than its heading
        lines += ["", "**The conditioned manager's decisions by state**, per seed and preference:", ""]
        lines += decides
    return lines


def _share_text(value: float | None) -> str:
    return f"{value:.1%}" if value is not None else "-"


def ttc_dependence_table(results: BenchmarkResults) -> tuple[list[str], float | None]:
    """
    On highway-env, per method, seed and worker: its share of the decisions made with a car close ahead and
    with the road clear (the test episodes' ``decisions_by_ttc``), and their ratio, as a Markdown table (no
    lines: no method reports them); and the time to collision, in seconds, under which a car is close.
    """
    rows: list[str] = []
    close = None
    for method, entry in results.methods.items():
        for seed, workers in (entry.decisions_by_ttc or {}).items():
            for worker, figure in workers.items():
                close = figure["close_seconds"]
                ratio = figure["ratio"]
                rows.append(
                    f"| {method} | {seed} | {worker} | {_share_text(figure['close_share'])} "
                    f"({figure['close_decisions']}) | {_share_text(figure['clear_share'])} "
                    f"({figure['clear_decisions']}) | {f'{ratio:.2f}' if ratio is not None else '-'} |"
                )
    if not rows:
        return [], None
    header = [
        "| method | seed | worker | share close ahead | share road clear | ratio |",
        "|---|---|---|---|---|---|",
    ]
    return header + rows, close


def _ttc_dependence_lines(results: BenchmarkResults) -> list[str]:
    """:func:`ttc_dependence_table` with the text that says how to read it (none where it is empty)."""
    table, close = ttc_dependence_table(results)
    if not table:
        return []
    return [
        "",
        f"Decisions by time to collision (test episodes): each worker's share of the decisions made with a car "
        f"close ahead (time to collision under {close:g} s) and with the road clear (no car ahead in the lane "
        "closing in); decisions counted in brackets. A manager that decides by state gives the safe worker a "
        "ratio well above 1.",
        "",
        *table,
    ]


def _dependence_lines(results: BenchmarkResults) -> list[str]:
    """The per-seed state-dependence table (does a hierarchy choose by state?), for the methods that report choices."""
    rows = []
    for method, entry in results.methods.items():
        for seed, figure in (entry.state_dependence or {}).items():
            if figure is None:
                continue
            ratio = dependence_ratio_text(dict(figure))
            rows.append(
                f"| {method} | {seed} | {_share_text(figure['near_share'])} ({figure['near_choices']}) "
                f"| {_share_text(figure['clear_share'])} ({figure['clear_choices']}) | {ratio} |"
            )
    if not rows:
        return []
    figure = next(f for e in results.methods.values() for f in (e.state_dependence or {}).values() if f)
    return [
        "",
        f"State dependence (test episodes): the {figure['worker']} worker's share of the choices made with the "
        f"nearest obstacle within {figure['near_clearance']:.3g} (half the sensor range) and with none within "
        f"{figure['clear_clearance']:.3g} (the sensor range); choices counted in brackets. A manager that "
        "decides by state has a ratio well above 1; a fixed mix, about 1.",
        "",
        f"| method | seed | {figure['worker']} share near | {figure['worker']} share none in range | ratio |",
        "|---|---|---|---|---|",
        *rows,
    ]


def final_scores_text(comparison: TransferComparison) -> str:
    """A transfer comparison's mean final scores over its seeds, ``manager / flat`` (the preference's score)."""
    seeds = comparison["per_seed"].values()
    manager = np.mean([v["manager_final_score"] for v in seeds])
    agent = np.mean([v["flat_final_score"] for v in seeds])
    return f"{manager:.1f} / {agent:.1f}"


def flat_reaches_text(comparison: TransferComparison) -> str:
    """In how many seeds the flat agent gets 90 % of the way to the manager's final score, and at which steps."""
    per_seed = comparison["per_seed"].values()
    reached = [
        v["flat_steps_to_manager_final"] for v in per_seed if v["flat_steps_to_manager_final"] is not None
    ]
    text = f"{comparison['seeds_flat_reaches_manager']}/{len(per_seed)}"
    return f"{text} (at {', '.join(str(s) for s in reached)})" if reached else text


def _transfer_lines(results: BenchmarkResults) -> list[str]:
    """The transfer figure: steps to reach the final score's fraction, and their ratio."""
    transfer = results.transfer
    if not transfer:
        return []
    lines = [
        "",
        f"Transfer: {transfer['definition']}. Curves are evaluated every {transfer['eval_freq']} own steps, "
        "so a run that is there at its first evaluation counts that many; 'no gain': the curve ended at or below the random score.",
        "",
        "| preference | manager | flat | seeds | manager steps (mean) | flat steps (mean) "
        "| ratio flat / manager [95 % CI] | final score manager / flat (mean) "
        "| flat gets 90 % of the way to the manager's final | per seed (flat / manager) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for preference, entry in transfer["preferences"].items():
        for comparison in entry.values():
            hierarchy, flat = comparison["manager"], comparison["flat"]
            seeds = comparison["per_seed"]
            manager = [v["manager_steps"] for v in seeds.values() if v["manager_steps"] is not None]
            agent = [v["flat_steps"] for v in seeds.values() if v["flat_steps"] is not None]
            ratio = comparison["ratio"]
            per_seed = ", ".join(
                f"{seed}: {v['flat_steps'] if v['flat_steps'] is not None else 'no gain'} / "
                f"{v['manager_steps'] if v['manager_steps'] is not None else 'no gain'}"
                for seed, v in seeds.items()
            )
            lines.append(
                f"| {preference} | {hierarchy} | {flat} | {comparison['seeds_with_ratio']}/{len(seeds)} "
                f"| {np.mean(manager) if manager else float('nan'):.0f} | {np.mean(agent) if agent else float('nan'):.0f} "
                f"| {ci_text(ratio, '.2f') if ratio else 'undefined'} | {final_scores_text(comparison)} "
                f"| {flat_reaches_text(comparison)} | {per_seed} |"
            )
    return lines


def write_outputs(out: Path, results: BenchmarkResults, records: list[JsonObject]) -> BenchmarkResults:
    """
    Write ``results.json``, ``results.md``, ``evaluations.csv``, ``episodes.csv`` (every test episode of the
    records that hold them) and the plots into ``out``.

    :return: the results as written, with the learning curves' bands.
    """

    method_records = [r for r in records if r["method"] != WORKERS]
    results = results.with_curves(
        {
            "own_steps": curve_bands(method_records, "timesteps"),
            "total_steps": curve_bands(method_records, "total_timesteps"),
        }
    )
    atomic_write_json(out / "results.json", results.to_json())
    atomic_write(out / "results.md", lambda tmp: tmp.write_text(markdown_report(results)))
    write_csv(out / "evaluations.csv", evaluation_rows(records))
    write_episodes_csv(out / "episodes.csv", records_episode_rows(records))
    figures.benchmark_learning_curves(results, out / "learning_curves.png")
    figures.figure9(results, out / "figure9.png")
    figures.figure10(results, out / "figure10.png")
    headline_figures(out, results, records)
    if results.front is not None:
        front_figure(results.front, out / "fronts.png")
    return results


def env_terms(results: BenchmarkResults) -> list[str]:
    """Another env's reward terms, in order (none on the snake arm)."""
    env = results.settings.get("env")
    terms = env.get("terms") if isinstance(env, dict) else None
    return [str(term) for term in terms] if isinstance(terms, list) else []


def score_name(results: BenchmarkResults) -> str:
    """What the score is called: the snake arm's reach reward, another env's normalised return."""
    return "norm. return" if env_terms(results) else "reach reward"


#: Thresholds of the performance profile, in reach reward (0..2 per step, 200 steps).
PROFILE_STEP = 2.0


def headline_figures(out: Path, results: BenchmarkResults, records: list[JsonObject]) -> list[Path]:
    """
    The rliable-style figures of a run: the aggregates' intervals (from ``results``) and the performance
    profile of the reach reward over the score matrices of the records.
    """
    # Only the run's own methods: a front's flat runs copied from its workers' benchmark stand beside its point.
    by_method = {m: runs for m, runs in records_by_method(records).items() if m in results.methods}
    if not by_method or not results.aggregates:
        return []
    scores, unit = score_matrices(by_method)
    low = min(float(m.min()) for m in scores.values())
    high = max(float(m.max()) for m in scores.values())
    taus = np.arange(np.floor(low / PROFILE_STEP) * PROFILE_STEP, high + PROFILE_STEP, PROFILE_STEP)
    profiles, bands = performance_profiles(scores, taus)
    return aggregate_figure(
        results.aggregates["intervals"],
        profiles,
        bands,
        taus,
        results.colours or {},
        unit,
        score_name(results),
        out,
    )

"""
The docs' result tables, generated from a benchmark folder's records: ``hddpg-cli report RUN_DIR``.

A page holds each generated table between ``<!-- generated:RUN/NAME -->`` and ``<!-- /generated:RUN/NAME -->``
(``RUN``: the folder's name, ``NAME``: one of :data:`TABLES`, or ``comparisons-METHOD`` for a method of the
run), and the README its one results sentence between ``<!-- results:start -->`` and ``<!-- results:end -->``;
the prose around them only interprets. The results come from the records by
:func:`~.statistics.compute_results` (with ``episodes.csv``'s rows where the folder ships it), so a re-run
updates every table, and a test checks that the shipped tables regenerate exactly.
"""

from __future__ import annotations

import contextlib
import functools
import re
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path

import numpy as np

from sb3_hddpg.artifacts.io import atomic_write
from sb3_hddpg.artifacts.limits import MAX_SHOWN
from sb3_hddpg.artifacts.records import JsonObject, read_benchmark_record
from sb3_hddpg.artifacts.records.results import BenchmarkResults
from sb3_hddpg.artifacts.records.results_leaves import Aggregates, Interval, PairedDifference, Summary
from sb3_hddpg.artifacts.run_folder import check_output_file
from sb3_hddpg.experiments.benchmark.benchmark_file import read_benchmark_settings
from sb3_hddpg.experiments.benchmark.episodes import group_rows, read_episodes_csv
from sb3_hddpg.experiments.benchmark.front_pages import decides_matrix, decides_table, front_table
from sb3_hddpg.experiments.benchmark.report import (
    env_terms,
    headline_figures,
    score_name,
    ttc_dependence_table,
)
from sb3_hddpg.experiments.benchmark.settings import BenchmarkSettings
from sb3_hddpg.experiments.benchmark.statistics import compute_results
from sb3_hddpg.experiments.stats import bootstrap_ci
from sb3_hddpg.experiments.study_export import read_exports, studies_table

#: The README's results sentence markers.
README_START, README_END = "<!-- results:start -->", "<!-- results:end -->"
#: A generated block: ``<!-- generated:RUN/NAME -->`` ... ``<!-- /generated:RUN/NAME -->``. Its body never
#: holds another opening marker: a search from each opening marker stops at the next one, so a page of many
#: unclosed markers costs time linear in its length (searched to the page's end, it was quadratic).
BLOCK = re.compile(
    r"(<!-- generated:(?P<key>[\w.-]+/[\w-]+) -->\n)(?P<body>(?:(?!<!-- generated:).)*?)"
    r"(<!-- /generated:(?P=key) -->)",
    re.S,
)


def load_run(run: Path) -> tuple[BenchmarkSettings, list[JsonObject]]:
    """
    A benchmark folder's settings and finished records; a record's test episodes are ``episodes.csv``'s rows
    where the folder ships that file (the shipped per-episode data is the source of the per-seed figures).

    :raises FileNotFoundError: not a benchmark folder.
    """
    if not (run / "benchmark.json").is_file() or not (run / "records").is_dir():
        raise FileNotFoundError(f"not a benchmark folder (no benchmark.json and records/): {str(run)!r}")
    settings = read_benchmark_settings(run / "benchmark.json")
    # Through the one reader of a record (its size, depth, status, method, seed and version checked).
    read = [read_benchmark_record(path).to_json() for path in sorted((run / "records").glob("*/seed-*.json"))]
    records: list[JsonObject] = [r for r in read if r.get("status") == "done"]
    csv_path = run / "episodes.csv"
    if csv_path.is_file():
        rows = group_rows(read_episodes_csv(csv_path))
        for record in records:
            shipped = rows.get(record["method"], {}).get(record["seed"])
            if shipped:
                record["episodes"] = [
                    {k: v for k, v in row.items() if k not in ("method", "seed", "episode_set")}
                    for row in shipped
                ]
    return settings, records


def run_results(run: Path) -> BenchmarkResults:
    """The results of a benchmark folder, computed from its records (not read from its results.json)."""
    settings, records = load_run(run)
    with made_from(run):
        return compute_results(settings, records)


def draw_headline_figures(run: Path) -> list[Path]:
    """Draw a benchmark folder's rliable-style figures into it from its records."""
    settings, records = load_run(run)
    with made_from(run):
        return headline_figures(run, compute_results(settings, records), records)


@contextlib.contextmanager
def made_from(run: Path) -> Iterator[None]:
    """
    Results, tables and figures made from a benchmark folder's files, which may come from someone else: each
    file passed its reader (size, depth, a record's run fields, ``episodes.csv``'s cells), but a record or a
    row may still lack a field the tables read, or hold it in another shape. That is the folder's fault, not
    this library's: one ``ValueError`` naming the folder (exit 2 at the CLI), not an internal ``KeyError``.
    """
    try:
        yield
    except (KeyError, TypeError, IndexError, AttributeError) as error:
        shown = repr(error.args[0]) if isinstance(error, KeyError) and error.args else str(error)
        raise ValueError(
            f"{run}: its records do not hold what the results are made of ({type(error).__name__}: "
            f"{shown[:MAX_SHOWN]})"
        ) from error


# ------------------------------------------------------------------------------------------------ tables
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
    if aggregate["unit"] == "episode":
        return (
            f"Test on {where} per trained model. {name.capitalize()}: rliable's mean and IQM over every (seed, episode) "
            "score with stratified bootstrap 95 % intervals (seeds resampled within each episode); the other "
            "columns: mean over seeds with a percentile bootstrap 95 % interval."
        )
    return (
        f"Test on {where} per trained model. This run ships per-seed records only (no per-episode data): every "
        f"interval resamples the per-seed means (rliable's stratified bootstrap for the {name}'s mean and "
        "IQM, a percentile bootstrap for the others), and no episode-level interval or performance profile can "
        "be computed from it."
    )


def methods_table(results: BenchmarkResults) -> str:
    """
    Per method: the score's mean and IQM with rliable's intervals; on the snake arm touch, contacts and success,
    on another env each term's return; the worker choices.
    """
    intervals = _aggregates(results)["intervals"]
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
    headers = [column[3] for column in columns]
    lines = [
        _unit_text(results),
        "",
        f"| method | seeds | {score_name(results)}: mean [95 % CI] | IQM [95 % CI] | {' | '.join(headers)} "
        "| worker choices (test) |",
        "|---|---|---|---|" + "---|" * len(headers) + "---|",
    ]
    for method, entry in results.methods.items():
        s = entry.stats
        aggregate = intervals[method]
        cells = [
            _interval(_percent(s[key])["mean"], _percent(s[key]), fmt)
            if percent
            else _interval(s[key]["mean"], s[key], fmt)
            if key in s
            else "-"
            for key, fmt, percent, _ in columns
        ]
        choices = ", ".join(f"{k} {v:.0%}" for k, v in (entry.selection_rate or {}).items()) or "-"
        mean, iqm = aggregate["mean"], aggregate["iqm"]
        lines.append(
            f"| `{method}` | {len(entry.seeds)} | {_interval(mean['value'], mean, '.1f')} "
            f"| {_interval(iqm['value'], iqm, '.1f')} | {' | '.join(cells)} | {choices} |"
        )
    return "\n".join(lines)


def _percent(stats: Summary) -> dict[str, float]:
    return {"mean": 100 * stats["mean"], "ci_low": 100 * stats["ci_low"], "ci_high": 100 * stats["ci_high"]}


def _signed(entry: PairedDifference, scale: float = 1.0) -> str:
    """A paired difference with its adjusted interval, bold when that excludes 0."""
    point, low, high = (scale * entry[k] for k in ("difference", "ci_low_adjusted", "ci_high_adjusted"))
    text = f"{point:+.2f} [{low:+.2f}, {high:+.2f}]"
    return f"**{text}**" if low > 0 or high < 0 else text


def comparisons_table(results: BenchmarkResults, challenger: str) -> str:
    """One challenger against every method it is compared with: paired differences, adjusted, and P(A > B)."""
    pairs = {k: v for k, v in results.comparisons.items() if k.split(" vs ")[0] == challenger}
    if not pairs:
        return f"(no comparison of `{challenger}` in this run)"
    family = (results.comparison_families or {})[challenger]
    m = family["comparisons"]["mean_reach_reward"]
    first = next(iter(pairs.values()))
    seeds = len(first.seeds)
    confidence = first.metrics["mean_reach_reward"]["confidence_adjusted"]
    aggregates = _aggregates(results)
    poi = aggregates["probability_of_improvement"]
    unit = "episodes and seeds" if aggregates["unit"] == "episode" else "seeds"
    snake = not env_terms(results)
    lines = [
        f"{m} comparisons per metric in this table. Differences: paired by seed, mean over the {seeds} seeds with "
        f"a Student t interval Bonferroni-adjusted for the {m} comparisons (each at {confidence:.2%}, all {m} "
        f"together at 95 %); bold where it excludes 0. P(A > B): rliable's probability of improvement over "
        f"{unit}, stratified bootstrap 95 % interval (not adjusted).",
        "",
        f"| {challenger} vs | {score_name(results)}: difference [CI] | P({challenger} > B) [95 % CI] "
        + ("| collisions / episode: difference [CI] | goal touch (points of %) |" if snake else "|"),
        "|---|---|---|" + ("---|---|" if snake else ""),
    ]
    for pair, comparison in pairs.items():
        baseline = pair.split(" vs ")[1]
        p = poi[pair]
        metrics = comparison.metrics
        collisions = (
            _signed(metrics["collisions_per_episode"]) if "collisions_per_episode" in metrics else "-"
        )
        touch = results.methods[challenger].stats.get("goal_touch_rate")
        other = results.methods[baseline].stats.get("goal_touch_rate")
        touch_text = f"{100 * (touch['mean'] - other['mean']):+.1f}" if touch and other else "-"
        snake_cells = f" {collisions} | {touch_text} |" if snake else ""
        lines.append(
            f"| `{baseline}` | {_signed(metrics['mean_reach_reward'])} "
            f"| {p['value']:.2f} [{p['ci_low']:.2f}, {p['ci_high']:.2f}] |{snake_cells}"
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
    """The transfer ratios per preference and manager: arithmetic mean, geometric mean and median, with CIs."""
    transfer = results.transfer
    if not transfer:
        return "(not a transfer run)"
    lines = [
        "Ratio = flat steps / manager steps to 90 % of the way from random to the final score, per seed; 95 % "
        "percentile bootstrap intervals over the seeds (the geometric mean's on the log ratios). The per-seed "
        "ratios spread over two orders of magnitude, so the geometric mean and the median are the headline, "
        "the arithmetic mean is shown for comparison with earlier text.",
        "",
        "| preference | manager vs flat | seeds with a ratio | arithmetic mean [95 % CI] | geometric mean "
        "[95 % CI] | median [95 % CI] | per seed |",
        "|---|---|---|---|---|---|---|",
    ]
    for preference, entry in transfer["preferences"].items():
        for comparison in entry.values():
            ratios = [v["ratio"] for v in comparison["per_seed"].values() if v["ratio"] is not None]
            if not ratios:
                continue
            arithmetic = bootstrap_ci(ratios)
            logs = bootstrap_ci(np.log(ratios))
            median = bootstrap_ci(ratios, np.median)
            lines.append(
                f"| `{preference}` | `{comparison['manager']}` vs `{comparison['flat']}` "
                f"| {len(ratios)}/{len(comparison['per_seed'])} | {_triple(arithmetic)} "
                f"| {_triple(tuple(float(np.exp(x)) for x in logs))} | {_triple(median)} "
                f"| {', '.join(f'{r:.1f}' for r in ratios)} |"
            )
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
    The README's results sentence: each challenger's score with its interval (``hddpg``, ``hddpg-front``, ...:
    every method the run compares with the others), and for every method it is compared with whether it is
    ahead, level or behind by the table's adjusted interval.

    :raises ValueError: the run compares no challenger with another method.
    """
    intervals = _aggregates(results)["intervals"]
    verdicts: dict[str, dict[str, list[str]]] = {}
    for pair, comparison in results.comparisons.items():
        challenger, baseline = pair.split(" vs ")
        groups = verdicts.setdefault(challenger, {"ahead of": [], "level with": [], "behind": []})
        entry = comparison.metrics["mean_reach_reward"]
        word = (
            "ahead of"
            if entry["ci_low_adjusted"] > 0
            else "behind"
            if entry["ci_high_adjusted"] < 0
            else "level with"
        )
        mean = results.methods[baseline].stats["mean_reach_reward"]["mean"]
        groups[word].append(f"`{baseline}` ({mean:.1f})")
    if not verdicts:
        raise ValueError("no method of this benchmark is compared with another: no results sentence to write")
    clauses = []
    for challenger, groups in verdicts.items():
        score = intervals[challenger]["mean"]
        verdict = "; ".join(f"{word} {', '.join(names)}" for word, names in groups.items() if names)
        clauses.append(
            f"`{challenger}` scores {score['value']:.1f} [{score['ci_low']:.1f}, {score['ci_high']:.1f}]: {verdict}."
        )
    episodes = _episodes(results)
    seeds = max(len(results.methods[challenger].seeds) for challenger in verdicts)
    return (
        f"On the {seeds}-seed benchmark `{run_name}` ({episodes['episodes']} {episodes['name']} episodes per model; "
        f"{score_name(results)}, paired t intervals over seeds adjusted for the comparisons, docs/RESULTS.md): "
        + " ".join(clauses)
    )


# ------------------------------------------------------------------------------------------------- pages
def _write_text(path: Path, text: str) -> None:
    def write(tmp: Path) -> None:
        tmp.write_text(text)

    atomic_write(path, write)


def render_page(
    text: str,
    run_name: str,
    results: BenchmarkResults | None,
    extra: Mapping[str, Callable[[], str]] | None = None,
) -> tuple[str, list[str]]:
    """
    ``text`` with every generated block of ``run_name`` rewritten from ``results`` (a block named in ``extra``
    from its own function, e.g. ``studies``; ``results`` ``None``: only those, for a folder of study exports).

    :return: the new text and the names of the blocks written.
    :raises ValueError: a block of ``run_name`` that names no known table.
    """
    written: list[str] = []
    makers: dict[str, Callable[[], str]] = (
        {name: functools.partial(table, results) for name, table in TABLES.items()}
        if results is not None
        else {}
    )
    makers.update(extra or {})

    def replace(match: re.Match[str]) -> str:
        run, _, name = match.group("key").partition("/")
        if run != run_name:
            return match.group(0)
        if results is not None and name.startswith(COMPARISONS) and name not in makers:
            makers[name] = functools.partial(comparisons_table, results, name[len(COMPARISONS) :])
        if name not in makers:
            choices = [*makers, f"{COMPARISONS}METHOD"]
            raise ValueError(f"Unknown generated table {name!r} in a page; choose from {choices}")
        written.append(name)
        return f"{match.group(1)}{makers[name]()}\n{match.group(4)}"

    return BLOCK.sub(replace, text), written


def render_readme(text: str, sentence: str) -> str:
    """``text`` with the results sentence between the README's markers replaced (unchanged without them)."""
    start, end = text.find(README_START), text.find(README_END)
    if start < 0 or end < start:
        return text
    return f"{text[: start + len(README_START)]}\n{sentence}\n{text[end:]}"


def update_tuning_page(run: Path, tuning_page: Path, check: bool = False) -> dict[str, list[str]]:
    """
    Regenerate ``tuning_page``'s ``RUN/studies`` block from the study exports of ``run/studies/`` alone: the
    equal-effort table before the benchmark that the studies serve has run (its folder holds only
    ``studies/``). Returns as :func:`update_pages` does.

    :raises FileNotFoundError: ``run`` has no ``studies/`` folder.
    """
    if not (run / "studies").is_dir():
        raise FileNotFoundError(f"neither a benchmark folder nor a folder of study exports: {str(run)!r}")
    studies = {"studies": functools.partial(studies_table, read_exports(run / "studies"))}
    new, written = render_page(tuning_page.read_text(), run.name, None, studies)
    return {"written": written, "changed": _write_changed({tuning_page: new}, check)}


def _write_changed(outputs: Mapping[Path, str], check: bool) -> list[str]:
    """The files whose new text differs from what they hold, written unless ``check``."""
    changed = {path: new for path, new in outputs.items() if new != path.read_text()}
    if not check:
        for path in changed:  # each before any is written
            # Rewritten in place, a link would become a file, and the page it names stay as it was.
            check_output_file(path, force=True)
        for path, new in changed.items():
            _write_text(path, new)
    return [str(path) for path in changed]


def update_pages(
    run: Path, page: Path, readme: Path | None = None, check: bool = False, tuning_page: Path | None = None
) -> dict[str, list[str]]:
    """
    Regenerate ``page``'s blocks of the benchmark folder ``run`` (and ``readme``'s sentence) from its records.

    :param run: a benchmark folder; its name is the ``RUN`` of the blocks.
    :param page: a Markdown page with generated blocks (e.g. ``docs/RESULTS.md``).
    :param readme: a README with the results markers (the sentence is a standard run's).
    :param check: write nothing; report the files that would change.
    :param tuning_page: a page whose ``RUN/studies`` block gets the equal-effort table of ``run/studies/``
        (the study exports, :mod:`sb3_hddpg.experiments.study_export`).
    :return: ``{"written": block names, "changed": files that differ from their regenerated text}``.
    """
    settings, records = load_run(run)
    outputs: dict[Path, str] = {}
    studies = (
        {"studies": functools.partial(studies_table, read_exports(run / "studies"))}
        if (run / "studies").is_dir()
        else {}
    )
    with made_from(run):
        results = compute_results(settings, records)
        outputs[page], written = render_page(page.read_text(), run.name, results, studies)
        if tuning_page is not None and studies:
            outputs[tuning_page], more = render_page(tuning_page.read_text(), run.name, results, studies)
            written += more
        if readme is not None and "hddpg" in results.methods and results.scenario == "standard":
            outputs[readme] = render_readme(readme.read_text(), results_sentence(results, run.name))
    return {"written": written, "changed": _write_changed(outputs, check)}

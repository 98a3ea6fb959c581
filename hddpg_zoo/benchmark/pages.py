"""
The docs' result tables, generated from a benchmark folder's records: ``hddpg-cli report RUN_DIR``.

A page holds each generated table between ``<!-- generated:RUN/NAME -->`` and ``<!-- /generated:RUN/NAME -->``
(``RUN``: the folder's name, ``NAME``: one of :data:`~.page_blocks.TABLES`, or ``comparisons-METHOD`` for a
method of the run), and the README its one results sentence between ``<!-- results:start -->`` and
``<!-- results:end -->``;
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

from hddpg_zoo.benchmark.benchmark_file import (
    invocation_codes,
    read_benchmark_file,
    read_benchmark_settings,
)
from hddpg_zoo.benchmark.episodes import SEED_METRIC_OF, group_rows, read_episodes_csv
from hddpg_zoo.benchmark.front_pages import (
    front_figure,
)
from hddpg_zoo.benchmark.page_blocks import (
    COMPARISONS,
    TABLES,
    comparisons_table,
    results_sentence,
)
from hddpg_zoo.benchmark.report import (
    headline_figures,
    markdown_report,
)
from hddpg_zoo.benchmark.settings import BenchmarkSettings
from hddpg_zoo.benchmark.statistics import compute_results
from hddpg_zoo.records import read_benchmark_record
from hddpg_zoo.records.results import BenchmarkResults
from hddpg_zoo.study_export import read_exports, studies_table
from sb3_hddpg.artifacts.io import atomic_write, atomic_write_json
from sb3_hddpg.artifacts.limits import MAX_SHOWN
from sb3_hddpg.artifacts.records import JsonObject
from sb3_hddpg.artifacts.run_folder import check_output_file

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
                # The shipped rows stand for the record's test episodes: they must make every per-seed
                # metric its summary holds, or the pages would mix the two sources.
                summary = record.get("test") or {}
                missing = sorted(m for m, seed_metric in SEED_METRIC_OF.items() if seed_metric in summary)
                missing = [m for m in missing if m not in shipped[0]]
                if missing:
                    raise ValueError(
                        f"{str(csv_path)!r}: {record['method']} seed {record['seed']} lacks {missing[:3]}, "
                        "which its record's test summary holds"
                    )
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
    """Draw a benchmark folder's rliable-style figures into it from its records, and its fronts if it has one."""
    settings, records = load_run(run)
    with made_from(run):
        results = compute_results(settings, records)
        drawn = headline_figures(run, results, records)
        if results.front is not None:
            drawn.append(front_figure(results.front, run / "fronts.png"))
        return drawn


def rewrite_results(run: Path) -> list[Path]:
    """
    Rewrite a benchmark folder's own ``results.json`` and ``results.md`` from its records, with today's
    statistics (a folder shipped by an older version keeps its records and its per-episode files untouched).

    :return: the files written.
    """
    results = run_results(run)
    return [
        atomic_write_json(run / "results.json", results.to_json()),
        atomic_write(run / "results.md", lambda tmp: tmp.write_text(markdown_report(results))),
    ]


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


def code_text(run: Path) -> str:
    """
    The code that ran a benchmark folder, from its invocations' records (``benchmark.json``): each distinct
    version and commit with its number of invocations, or "not recorded" for invocations from before the
    field; never a commit that no record holds.
    """
    header = run / "benchmark.json"
    codes = invocation_codes(read_benchmark_file(header), str(header))
    if not codes:
        return "Code: no invocation recorded."
    counts: dict[str, int] = {}
    for code in codes:
        key = "not recorded" if code is None else code.describe()
        counts[key] = counts.get(key, 0) + 1
    parts = [f"{key} ({n} of {len(codes)} invocations)" for key, n in counts.items()]
    text = f"Code (`benchmark.json`'s `invocations[].code`): {'; '.join(parts)}."
    if "not recorded" in counts:
        text += (
            " An invocation without the field ran before benchmarks recorded their code: the commit behind its"
            " records cannot be proven."
        )
    return text


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
        (the study exports, :mod:`hddpg_zoo.study_export`).
    :return: ``{"written": block names, "changed": files that differ from their regenerated text}``.
    """
    settings, records = load_run(run)
    outputs: dict[Path, str] = {}
    studies: dict[str, Callable[[], str]] = (
        {"studies": functools.partial(studies_table, read_exports(run / "studies"))}
        if (run / "studies").is_dir()
        else {}
    )
    studies["code"] = functools.partial(code_text, run)
    with made_from(run):
        results = compute_results(settings, records)
        outputs[page], written = render_page(page.read_text(), run.name, results, studies)
        if tuning_page is not None and (run / "studies").is_dir():
            outputs[tuning_page], more = render_page(tuning_page.read_text(), run.name, results, studies)
            written += more
        if readme is not None and "hddpg" in results.methods and results.scenario == "standard":
            outputs[readme] = render_readme(readme.read_text(), results_sentence(results, run.name))
    return {"written": written, "changed": _write_changed(outputs, check)}

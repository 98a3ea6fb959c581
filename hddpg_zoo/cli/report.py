"""``hddpg-cli report RUN_DIR``: the docs' result tables and the README's results sentence, from the records."""

from __future__ import annotations

from pathlib import Path

import typer

from hddpg_zoo.benchmark.page_blocks import COMPARISONS, TABLES
from hddpg_zoo.benchmark.pages import (
    draw_headline_figures,
    load_run,
    rewrite_results,
    update_pages,
    update_tuning_page,
)
from hddpg_zoo.study_export import export_study, write_export
from hddpg_zoo.study_storage import check_storage_url
from sb3_hddpg.cli.app import app, console
from sb3_hddpg.cli.options import usage_errors
from sb3_hddpg.names import check_plain_name


@app.command("export-study")
def export_study_command(
    storage: str = typer.Option(
        ..., "--storage", help="The study's Optuna storage URL (sqlite:///... or another)."
    ),
    study_name: str = typer.Option(..., "--study-name", help="The study's name in the storage."),
    out: Path = typer.Option(
        ..., "--out", help="The folder of the export, e.g. docs/results/RUN/studies (STUDY_NAME.json)."
    ),
) -> None:
    """Export a tuning study's trials to JSON, for a benchmark's shipped studies and docs/TUNING.md's table."""
    with usage_errors("'--study-name'"):
        check_plain_name(study_name, "--study-name")
    with usage_errors("'--storage' / '--study-name'"):
        check_storage_url(storage)
        try:
            export = export_study(storage, study_name)
        except KeyError as error:
            raise ValueError(f"no study {study_name!r} in that storage") from error
    with usage_errors("'--out'"):
        path = write_export(out, export)
    console.print(f"Exported {len(export['trials'])} trials of {study_name!r} to {path}")


@app.command("report")
def report_command(
    run: Path = typer.Argument(
        ...,
        help=(
            "A benchmark folder (its name is RUN in the page's generated blocks), or a folder of study exports "
            "alone (RUN/studies/: only the tuning page's table)."
        ),
    ),
    page: Path = typer.Option(
        Path("docs/RESULTS.md"),
        "--page",
        help=(
            "The page whose <!-- generated:RUN/NAME --> blocks are rewritten (NAME among "
            f"{', '.join(TABLES)}, or {COMPARISONS}METHOD for a method of the run)."
        ),
    ),
    readme: Path | None = typer.Option(
        None,
        "--readme",
        help="Also rewrite the sentence between <!-- results:start --> and <!-- results:end --> (a standard run).",
    ),
    tuning_page: Path = typer.Option(
        Path("docs/TUNING.md"),
        "--tuning-page",
        help="The page whose <!-- generated:RUN/studies --> block gets the table of RUN/studies/ (if that exists).",
    ),
    figures: bool = typer.Option(
        False,
        "--figures",
        help="Also draw RUN/aggregates.png and RUN/performance_profile.png (rliable's style).",
    ),
    results: bool = typer.Option(
        False,
        "--results",
        help="Also rewrite RUN/results.json and RUN/results.md from its records (its records stay as they are).",
    ),
    check: bool = typer.Option(
        False, "--check", help="Write nothing; exit 1 if a page differs from its regenerated text."
    ),
) -> None:
    """Regenerate the result tables of a page (and the README's sentence) from a benchmark folder's records."""
    # A folder of study exports alone (the benchmark they serve has not run): only the tuning page's table.
    studies_only = (run / "studies").is_dir() and not (run / "benchmark.json").exists()
    with usage_errors("'RUN'"):
        if not studies_only:
            load_run(run)
    with usage_errors("'--page' / '--readme'"):
        pages = (
            (tuning_page,)
            if studies_only
            else (page, readme, tuning_page if (run / "studies").is_dir() else None)
        )
        for path in pages:
            if path is not None and not path.is_file():
                raise FileNotFoundError(f"no such page: {str(path)!r}")
    if studies_only:
        outcome = update_tuning_page(run, tuning_page, check=check)
    else:
        outcome = update_pages(
            run, page, readme, check=check, tuning_page=tuning_page if (run / "studies").is_dir() else None
        )
    tables = ", ".join(outcome["written"]) or "none (no generated block of this run in the page)"
    console.print(f"Tables of {run.name}: {tables}")
    if check and outcome["changed"]:
        console.print(
            f"[red]Out of date[/]: {', '.join(outcome['changed'])} (run without --check to rewrite)"
        )
        raise typer.Exit(1)
    verb = "would change" if check else "rewritten"
    console.print(f"Files {verb}: {', '.join(outcome['changed']) or 'none'}")
    if results and not check and not studies_only:
        console.print(f"Results: {', '.join(str(p) for p in rewrite_results(run))}")
    if figures and not check and not studies_only:
        drawn = draw_headline_figures(run)
        console.print(f"Figures: {', '.join(str(p) for p in drawn) or 'none (no method runs)'}")

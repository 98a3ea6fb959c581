"""``hddpg-cli export-models``: a benchmark's final models copied into a folder, with their index."""

from __future__ import annotations

from pathlib import Path

import typer

from hddpg_zoo.model_export import export_models
from sb3_hddpg.cli.app import app, console
from sb3_hddpg.cli.options import usage_errors


def export_run(run: Path, dest: Path) -> None:
    """Copy a benchmark's final models into ``dest`` and say how many (``benchmark --export-models``)."""
    index = export_models(run, dest)
    console.print(f"Exported {len(index)} models to {dest} (index: {dest / 'index.json'})")


@app.command("export-models")
def export_models_command(
    run: Path = typer.Argument(..., help="A benchmark folder (the --out of hddpg-cli benchmark)."),
    dest: Path = typer.Argument(..., help="The folder to copy the final models into, with index.json."),
    method: list[str] = typer.Option(
        [],
        "--method",
        help="Only the models of this index.json method (e.g. hddpg-support-gpi); repeat for more (default: all).",
    ),
) -> None:
    """
    Copy a benchmark's final models (worker zips, hierarchy bundles, ham.json, flat zips) into DEST, in the
    benchmark's layout, with DEST/index.json: {"method", "seed", "path", "sha256"} per model.
    """
    with usage_errors("'RUN'"):
        if not (run / "records").is_dir():
            raise FileNotFoundError(f"not a benchmark folder (no records/): {str(run)!r}")

        index = export_models(run, dest, method or None)
    console.print(f"Exported {len(index)} models to {dest} (index: {dest / 'index.json'})")

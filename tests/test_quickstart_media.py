"""The README's GIF and the docs' selection figure are the current quickstart's: their record says so."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hddpg_zoo.quickstart_media import MEDIA, MEDIA_RECORD, publish_media, quickstart_settings
from sb3_hddpg.artifacts.provenance import sha256_file

DOCS = Path(__file__).resolve().parents[1] / "docs"


def test_the_docs_media_are_the_recorded_run_of_the_current_quickstart():
    record = json.loads((DOCS / MEDIA_RECORD).read_text())
    # Each file is the one the run wrote (a file replaced by hand, or a run never recorded, fails here).
    assert set(record["files"]) == set(MEDIA.values())
    for name, digest in record["files"].items():
        assert sha256_file(DOCS / name) == digest, f"docs/{name} is not the recorded quickstart's"
    # The run was the quickstart as it is now: a changed budget or main manager needs `make quickstart media`.
    assert {key: record[key] for key in ("budget", "main_manager")} == quickstart_settings("small"), (
        "the quickstart changed since docs/quickstart-*.{gif,png} were made: run `make quickstart media`"
    )


def _run_folder(path: Path, budget: str) -> Path:
    """A finished quickstart's folder as publish_media reads it: results, the workers' manifest and media."""
    path.mkdir()
    methods = {"hierarchy": {"shown_episode_seed": 9}}
    results = {"budget": {"name": budget}, "seed": 3, "eval_seeds": [7, 8, 9], "methods": methods}
    (path / "results.json").write_text(json.dumps(results))
    (path / "workers").mkdir()
    (path / "workers" / "manifest.json").write_text(json.dumps({"workers": {"goal": {"backend": "sbx"}}}))
    for source, name in MEDIA.items():
        (path / source).write_bytes((DOCS / name).read_bytes()[:100] + source.encode())
    return path


def test_publish_media_copies_the_runs_files_and_records_them(tmp_path):
    run = _run_folder(tmp_path / "run", "small")
    record = json.loads(publish_media(run, tmp_path / "docs").read_text())
    assert record["seed"] == 3 and record["backend"] == "sbx" and record["shown_episode_seed"] == 9
    for source, name in MEDIA.items():
        assert (tmp_path / "docs" / name).read_bytes() == (run / source).read_bytes()
        assert record["files"][name] == sha256_file(run / source)
    with pytest.raises(ValueError, match="small budget's run, this one is 'tiny'"):
        publish_media(_run_folder(tmp_path / "tiny", "tiny"), tmp_path / "other")
    assert not (tmp_path / "other").exists()  # nothing copied from a run the docs do not show

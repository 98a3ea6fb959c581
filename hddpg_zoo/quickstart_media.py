"""
The README's GIF and the docs' selection figure: a quickstart run's own ``hierarchy.gif`` and ``selection.png``,
copied into ``docs/`` with a record of the run that made them (:data:`MEDIA_RECORD`): its budget, seed,
backend and main manager, and each file's sha256. A test reads the record: a file that is not the recorded
one, or a quickstart whose settings have changed since, means the media are stale (``make media`` after
``make quickstart`` brings them up to date).
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Any

from hddpg_zoo.quickstart import BUDGETS, MAIN_HIERARCHY, flat_budget, main_manager_options
from sb3_hddpg.artifacts.io import atomic_write_bytes, atomic_write_json
from sb3_hddpg.artifacts.limits import read_json_record
from sb3_hddpg.artifacts.provenance import sha256_file

#: Run-folder file -> its name in the docs folder.
MEDIA = {"hierarchy.gif": "quickstart-hierarchy.gif", "selection.png": "quickstart-selection.png"}
#: The record of the run the docs' media come from, beside them.
MEDIA_RECORD = "quickstart-media.json"


def quickstart_settings(budget: str = "small") -> dict[str, Any]:
    """
    What a quickstart at ``budget`` trains, as its media record states it: the budget (as ``results.json``
    writes it) and the main manager's options (its algorithm, preferences and start from HAM).
    """
    chosen = BUDGETS[budget]
    manager = main_manager_options(chosen)
    return {
        "budget": {**vars(chosen), "flat_timesteps": flat_budget(chosen)},
        "main_manager": {**manager, "init_from_ham": asdict(manager["init_from_ham"])},
    }


def publish_media(run_dir: str | Path, docs_dir: str | Path) -> Path:
    """
    Copy a finished quickstart's GIF and selection figure into ``docs_dir`` and write their record.

    :param run_dir: the quickstart's run folder (its ``results.json`` says it finished).
    :param docs_dir: the docs folder.
    :return: the record's path.
    :raises ValueError: the run folder holds no finished quickstart, or one of another budget than ``small``.
    """
    run_dir, docs_dir = Path(run_dir), Path(docs_dir)
    results = read_json_record(run_dir / "results.json", f"{run_dir}: no finished quickstart (results.json)")
    budget = results.get("budget", {}).get("name") if isinstance(results, dict) else None
    if budget != "small":
        raise ValueError(f"{run_dir}: the docs show the small budget's run, this one is {budget!r}")
    workers = read_json_record(run_dir / "workers" / "manifest.json", f"{run_dir}: no workers manifest")
    backends = {entry.get("backend") for entry in workers.get("workers", {}).values()}
    files = {}
    for source, name in MEDIA.items():
        atomic_write_bytes(docs_dir / name, (run_dir / source).read_bytes())
        files[name] = sha256_file(docs_dir / name)
    record = {
        "made_by": "make quickstart; make media",
        **quickstart_settings(budget),
        "seed": results["seed"],
        "backend": backends.pop() if len(backends) == 1 else sorted(map(str, backends)),
        # The episode the media show (quickstart_figures.shown_episode), of the table's evaluation episodes.
        "shown_episode_seed": results["methods"][MAIN_HIERARCHY].get(
            "shown_episode_seed", results["eval_seeds"][0]
        ),
        "files": files,
    }
    return atomic_write_json(docs_dir / MEDIA_RECORD, record)


__all__ = ["MEDIA", "MEDIA_RECORD", "publish_media", "quickstart_settings"]

"""
A tuning study exported to JSON (every trial: state, value, parameters, peaks), and the equal-effort summary of a
folder of exports, so that a benchmark ships its studies (``docs/results/<run>/studies/``) and docs/TUNING.md's
table is generated from them.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import optuna

from hddpg_zoo.study_storage import make_storage
from sb3_hddpg.artifacts.io import atomic_write_json
from sb3_hddpg.artifacts.limits import read_json_file
from sb3_hddpg.artifacts.run_folder import RunFolderError, check_output_file
from sb3_hddpg.names import check_plain_name

#: Bumped when an export's meaning changes.
EXPORT_VERSION = 1
#: The trial attributes an export keeps (a trial's full learning curves stay in the study database).
KEPT_ATTRS = ("seed_peaks", "decisions", "diverged", "config_block")


def export_study(storage: str, study_name: str) -> dict[str, Any]:
    """
    A study as a JSON-ready record: what it tuned (its stored target: level, algorithm, env steps per trial,
    seeds per trial, the budget fraction where given) and every trial.

    :param storage: the study's Optuna storage URL.
    :param study_name: its name there.
    :raises KeyError: no such study in the storage (Optuna's message).
    """
    storage_ = make_storage(storage, heartbeat_interval=None, create=False)
    study = optuna.load_study(study_name=study_name, storage=storage_)
    trials = [
        {
            "number": trial.number,
            "state": trial.state.name,
            "value": trial.value,
            "params": trial.params,
            **{key: trial.user_attrs[key] for key in KEPT_ATTRS if key in trial.user_attrs},
        }
        for trial in study.get_trials(deepcopy=False)
    ]
    return {
        "export_version": EXPORT_VERSION,
        "study": study_name,
        "target": study.user_attrs.get("target", {}),
        "trials": trials,
    }


def write_export(out: str | Path, export: dict[str, Any]) -> Path:
    """
    Write a study's export as ``OUT/STUDY.json``: the study's name must be a plain name (it becomes the
    file's), ``OUT`` a folder that is not a symbolic link, and an existing ``STUDY.json`` an earlier export
    (a file of the user's of that name is never replaced).

    :param out: the folder of exports (created if missing).
    :param export: what :func:`export_study` returned.
    :return: the file written; raises ``ValueError`` (:class:`RunFolderError`) naming what is in the way.
    """
    out = Path(out)
    name = check_plain_name(export["study"], "--study-name")
    if out.is_symlink():
        raise RunFolderError(f"--out: {str(out)!r} is a symbolic link; name the folder itself")
    if out.exists() and not out.is_dir():
        raise RunFolderError(f"--out: {str(out)!r} exists and is a file; name a folder for the export")
    path = check_output_file(out / f"{name}.json", force=True)
    if path.exists():
        try:
            earlier = read_json_file(path)
        except (OSError, ValueError):
            earlier = None
        if not isinstance(earlier, dict) or "export_version" not in earlier:
            raise RunFolderError(
                f"--out: {str(path)!r} exists and is not a study export; move it away or choose another --out"
            )
    return atomic_write_json(path, export)


def study_effort(export: dict[str, Any]) -> dict[str, Any]:
    """
    A study's effort from its export: finished trials (complete and pruned), env steps per trial, seeds per
    trial, the budget fraction and final budget where the study was made with them, and the env steps the
    study was allowed (finished trials x seeds x steps; pruned trials stopped earlier, so it is an upper bound).
    """
    target = export.get("target", {})
    states = [t["state"] for t in export["trials"]]
    finished = sum(s in ("COMPLETE", "PRUNED") for s in states)
    steps = target.get("timesteps")
    seeds = int(target.get("n_seeds", 1))
    values = [t["value"] for t in export["trials"] if t["state"] == "COMPLETE" and t["value"] is not None]
    return {
        "study": export["study"],
        "level": target.get("level"),
        # HAM's switch trains nothing: it has no algorithm.
        "algo": "-" if target.get("level") == "ham" else target.get("algo", "ddpg"),
        "complete": states.count("COMPLETE"),
        "pruned": states.count("PRUNED"),
        "steps_per_trial": steps,
        "seeds_per_trial": seeds,
        "budget_fraction": target.get("budget_fraction"),
        "final_budget": target.get("final_budget"),
        "episode_set": target.get("episode_set", "curve"),
        "env_steps_at_most": finished * seeds * steps if steps else 0,
        "best_value": max(values) if values else None,
    }


def read_exports(folder: Path) -> list[dict[str, Any]]:
    """Every study export of a folder (``*.json``), by study name."""
    exports = [read_json_file(path) for path in sorted(folder.glob("*.json"))]
    for export in exports:
        if not isinstance(export, dict) or export.get("export_version") != EXPORT_VERSION:
            raise ValueError(f"Not a study export of version {EXPORT_VERSION} in {str(folder)!r}")
    return exports


def studies_table(exports: Sequence[dict[str, Any]]) -> str:
    """The equal-effort table: per study its trials, their budget and share of the final one, and its env steps."""
    lines = [
        "| study | level | algorithm | trials (complete + pruned) | env steps per trial x seeds | share of the "
        "final budget | env steps (at most) | evaluated on | best value |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for effort in map(study_effort, exports):
        fraction = (
            f"{effort['budget_fraction']:.0%} of {effort['final_budget']:,}"
            if effort["budget_fraction"]
            else "-"
        )
        best = f"{effort['best_value']:.1f}" if effort["best_value"] is not None else "-"
        steps = (
            f"{effort['steps_per_trial']:,} x {effort['seeds_per_trial']}"
            if effort["steps_per_trial"]
            else "-"
        )
        lines.append(
            f"| `{effort['study']}` | {effort['level']} | {effort['algo']} "
            f"| {effort['complete'] + effort['pruned']} ({effort['complete']} + {effort['pruned']}) | {steps} "
            f"| {fraction} | {effort['env_steps_at_most']:,} | {effort['episode_set']} episodes | {best} |"
        )
    return "\n".join(lines)

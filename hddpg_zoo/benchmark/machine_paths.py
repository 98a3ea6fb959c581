"""
A record states what ran, readable on any machine: the benchmark settings that say where something is on
this machine (:data:`MACHINE_PATHS`) are checked where the benchmark runs, and recorded without the machine's
paths (:func:`settings_record`): a folder relative to the benchmark's, MORL-baselines' python by its version.
"""

from __future__ import annotations

import os
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

from hddpg_zoo.benchmark.morl import check_morl_python, morl_python_version
from hddpg_zoo.benchmark.settings import BenchmarkSettings

#: Settings that say where something is on this machine: a folder copied to another machine resumes there
#: with its own paths (the reused workers are checked against their manifests whatever their path), but
#: one given or left out only on resume would mix two kinds of runs.
MACHINE_PATHS = ("workers_from", "morl_python")


def relative_to_run(path: str, run_dir: str | Path) -> str:
    """
    ``path`` as a record states it: relative to the run folder ``run_dir`` (a relative path is kept as given),
    so that no record holds an absolute path of the machine that wrote it.
    """
    if not os.path.isabs(path):
        return path
    return Path(os.path.relpath(path, Path(run_dir).absolute())).as_posix()


def check_machine_paths(settings: BenchmarkSettings) -> BenchmarkSettings:
    """
    The settings with their paths of this machine (:data:`MACHINE_PATHS`) checked and made absolute, before
    the benchmark runs: MORL-baselines' python must be an executable file here.

    :raises ValueError: naming the setting.
    """
    if settings.morl_python is None:
        return settings
    return replace(settings, morl_python=check_morl_python(settings.morl_python))


def settings_record(settings: BenchmarkSettings, run_dir: str | Path) -> dict[str, Any]:
    """
    The settings as ``benchmark.json`` and ``results.json`` record them: what ran, readable on any machine.
    ``workers_from`` is relative to the benchmark's folder ``run_dir``; MORL-baselines' python is its version
    (``python 3.11.7``), not its path.

    :param settings: settings whose machine paths are checked (:func:`check_machine_paths`).
    :param run_dir: the benchmark's folder.
    """
    record = asdict(settings)
    if settings.workers_from is not None:
        record["workers_from"] = relative_to_run(settings.workers_from, run_dir)
    if settings.morl_python is not None and os.path.isabs(settings.morl_python):
        record["morl_python"] = f"python {morl_python_version(settings.morl_python)}"
    return record


__all__ = ["MACHINE_PATHS", "check_machine_paths", "relative_to_run", "settings_record"]

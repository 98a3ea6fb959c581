"""A record states what ran: reading it never needs the machine that wrote it, and no shipped file holds its paths."""

from __future__ import annotations

import re
import sys
import zipfile
from pathlib import Path

import pytest

from hddpg_zoo.benchmark import BenchmarkSettings
from hddpg_zoo.benchmark.benchmark_file import read_benchmark_settings
from hddpg_zoo.benchmark.machine_paths import (
    check_machine_paths,
    relative_to_run,
    settings_record,
)
from sb3_hddpg.training.config import config_source, default_config

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
#: An absolute path of a machine: a home, a temporary or a work folder (after a quote, a space or a line
#: start, so that a URL's or a relative path's segments do not count).
MACHINE_PATH = re.compile(
    rb"""(?:^|[\s"'(=`])(?:/(?:root|home|tmp|work|Users|mnt|var/folders)/|[A-Z]:\\\\Users)"""
)
#: One env of the MO-Gymnasium adapter, as the shipped half-cheetah run's settings hold it.
CHEETAH = DOCS / "results" / "cheetah" / "benchmark.json"


def _shipped_files() -> list[Path]:
    return [p for p in DOCS.rglob("*") if p.is_file() and "_build" not in p.relative_to(DOCS).parts]


def test_no_shipped_file_under_docs_holds_a_path_of_a_machine():
    found = []
    for path in _shipped_files():
        if path.suffix == ".zip":
            with zipfile.ZipFile(path) as archive:
                found += [f"{path}:{n}" for n in archive.namelist() if MACHINE_PATH.search(archive.read(n))]
        elif path.suffix in {
            ".json",
            ".md",
            ".csv",
            ".txt",
            ".yml",
            ".yaml",
            ".rst",
            ".py",
            ".toml",
            ".html",
        }:
            found += [str(path)] if MACHINE_PATH.search(path.read_bytes()) else []
    assert not found, f"absolute paths of a machine in {found[:10]}"
    # The pattern finds what it must: the shipped records held exactly these before they were rewritten.
    assert MACHINE_PATH.search(b'"morl_python": "/root/morl-venv/bin/python"')
    assert MACHINE_PATH.search(b'"file": "/work/frozen/sb3_hddpg/zoo_configs/ddpg.yml"')
    assert not MACHINE_PATH.search(b'"file": "sb3_hddpg/zoo_configs/ddpg.yml", https://x.org/home/a')


def test_a_record_of_another_machines_settings_reads_here():
    # The half-cheetah run named MORL-baselines' python of its machine: its record states the version.
    settings = read_benchmark_settings(CHEETAH)
    assert settings.morl_python == "python 3.11.7"
    # Running with it is what needs the file, and then it is refused in one line naming the option.
    with pytest.raises(ValueError, match="--morl-python to be an executable python"):
        check_machine_paths(settings)


def test_settings_record_paths_relative_to_the_run_folder_and_the_python_by_version(tmp_path):
    cheetah = read_benchmark_settings(CHEETAH)
    settings = check_machine_paths(BenchmarkSettings(**{**vars(cheetah), "morl_python": sys.executable}))
    assert settings.morl_python == str(Path(sys.executable).absolute())
    record = settings_record(settings, tmp_path / "cheetah")
    version = ".".join(str(v) for v in sys.version_info[:3])
    assert record["morl_python"] == f"python {version}"
    source = BenchmarkSettings(methods=["goal-only"], workers_from=str(tmp_path / "record"))
    assert settings_record(source, tmp_path / "transfer")["workers_from"] == "../record"
    assert relative_to_run(str(tmp_path / "run" / "seed-0"), tmp_path / "run") == "seed-0"
    assert relative_to_run("runs/record", tmp_path) == "runs/record"  # relative: as given


def test_manifests_name_a_config_by_what_it_is_not_where_it_was(tmp_path):
    assert config_source(default_config("sac")) == "sb3_hddpg/zoo_configs/sac.yml"
    assert config_source("configs/mine.yml") == "configs/mine.yml"
    assert config_source(tmp_path / "mine.yml") == "mine.yml"
    assert config_source(tmp_path / "mine.yml", tmp_path / "run") == "../mine.yml"

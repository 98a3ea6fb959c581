"""``--resume`` on a protocol run's shipped records (protocol.json and records/ only): taken, or refused."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from hddpg_zoo.benchmark.morl_protocol import ProtocolSettings
from hddpg_zoo.benchmark.morl_protocol_run import read_protocol_run, shipped_run
from sb3_hddpg.artifacts.containment import RUN_MARKER

#: A shipped development run: three methods, five seeds, 50k env steps.
SHIPPED = Path(__file__).parents[1] / "docs" / "results" / "morl-dev" / "deep-sea-treasure-concave-v0"
MORL_PYTHON = os.environ.get("MORL_PYTHON")
COMMAND = [sys.executable, "-m", "sb3_hddpg", "benchmark", "--protocol", "morl-baselines"]


def _settings(**changed: object) -> ProtocolSettings:
    kept = json.loads((SHIPPED / "protocol.json").read_text())
    given = {
        "seeds": tuple(kept["seeds"]),
        "methods": tuple(kept["methods"]),
        "peers": (),
        "timesteps": kept["budget"],
        "eval_episodes": kept["eval_episodes"],
        **changed,
    }
    return ProtocolSettings(kept["env_id"], morl_python=sys.executable, **given)


@pytest.fixture
def shipped(tmp_path: Path) -> Path:
    copy = tmp_path / "shipped"
    shutil.copytree(SHIPPED, copy)
    return copy


def test_a_shipped_run_is_taken_by_settings_that_add_seeds_or_sides(shipped):
    assert shipped_run(shipped, _settings())
    assert shipped_run(shipped, _settings(seeds=tuple(range(10)), peers=("envelope",)))
    with pytest.raises(ValueError, match="may only add seeds and sides"):
        shipped_run(shipped, _settings(timesteps=10_000))


def test_a_folder_with_more_than_a_runs_records_is_not_a_shipped_run(shipped, tmp_path):
    for name in ("notes.txt", ".notes"):
        (shipped / name).write_text("mine")
        assert not shipped_run(shipped, _settings())
        (shipped / name).unlink()
    # A side's folder that is a link would take a new record's write out of the folder.
    side = shipped / "records" / "hddpg-gpi"
    shutil.move(side, tmp_path / "elsewhere")
    side.symlink_to(tmp_path / "elsewhere")
    assert not shipped_run(shipped, _settings())


def test_a_record_at_another_seeds_path_is_refused(shipped):
    records = shipped / "records" / "hddpg-gpi"
    (records / "seed-9.json").write_bytes((records / "seed-0.json").read_bytes())
    with pytest.raises(ValueError, match="not its path's"):
        shipped_run(shipped, _settings())
    (records / "seed-9.json").write_text("{")
    with pytest.raises(ValueError, match=r"seed-9\.json"):
        shipped_run(shipped, _settings())


def test_resume_of_other_settings_on_a_shipped_run_is_a_usage_error_that_writes_nothing(shipped):
    before = sorted(p.relative_to(shipped) for p in shipped.rglob("*"))
    done = subprocess.run(
        [*COMMAND, "--env", "deep-sea-treasure-concave-v0", "--seeds", "5", "--methods", "hddpg-gpi",
         "--timesteps", "400", "--morl-python", sys.executable, "--out", str(shipped), "--resume"],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert done.returncode == 2 and "may only add seeds and sides" in done.stderr
    assert "Traceback" not in done.stderr
    assert sorted(p.relative_to(shipped) for p in shipped.rglob("*")) == before


def test_without_resume_a_shipped_run_stays_the_users(shipped):
    done = subprocess.run(
        [*COMMAND, "--env", "deep-sea-treasure-concave-v0", "--seeds", "5",
         "--methods", "hddpg-gpi,hddpg-gpi-terms,hddpg-conditioned", "--timesteps", "50000",
         "--test-episodes", "5", "--morl-python", sys.executable, "--out", str(shipped)],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert done.returncode == 2 and "did not write" in done.stderr and not (shipped / RUN_MARKER).exists()


@pytest.mark.skipif(not MORL_PYTHON, reason="MORL_PYTHON (MORL-baselines' python) is not set")
def test_resume_adds_a_seed_to_a_shipped_run_and_keeps_its_records(tmp_path):
    arguments = [
        "--env",
        "deep-sea-treasure-concave-v0",
        "--methods",
        "hddpg-gpi-terms",
        "--timesteps",
        "400",
    ]
    arguments += ["--test-episodes", "1", "--morl-python", str(MORL_PYTHON)]
    run = tmp_path / "run"
    first = subprocess.run(
        [*COMMAND, *arguments, "--seeds", "1", "--out", str(run)], capture_output=True, check=False
    )
    assert first.returncode == 0
    shipped = tmp_path / "shipped"
    shipped.mkdir()
    for entry in ("protocol.json", "records"):  # what a repository ships of a run
        shutil.move(run / entry, shipped / entry)
    kept = shipped / "records" / "hddpg-gpi-terms" / "seed-0.json"
    before = (kept.read_bytes(), kept.stat().st_mtime_ns)
    done = subprocess.run(
        [*COMMAND, *arguments, "--seeds", "2", "--out", str(shipped), "--resume"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "shipped records" in done.stdout
    settings, records = read_protocol_run(shipped)
    assert settings["seeds"] == [0, 1] and sorted(records["hddpg-gpi-terms"]) == [0, 1]
    assert (kept.read_bytes(), kept.stat().st_mtime_ns) == before

"""
A benchmark folder someone else made, or edited: its ``benchmark.json``, records and ``episodes.csv`` are read
through one reader each, so a bad field is one line and exit 2, never a traceback, an import or a run that
trains for hours and then fails on what it read at the start.
"""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path
from typing import Any

import pytest

from sb3_hddpg.experiments.benchmark import BenchmarkSettings
from sb3_hddpg.experiments.benchmark.benchmark_file import read_benchmark_file, settings_from_json
from tests.cli_batch import run_batch

REPO = Path(__file__).resolve().parents[1]
SHIPPED = REPO / "docs" / "results" / "bench-e20"
#: A module a file could name as an env id's prefix (``gym.make("evilmod:Evil-v0")`` would import it).
EVIL_MODULE = "from pathlib import Path\nPath(__file__).with_name('IMPORTED').write_text('ran')\n"


def one_line_exit_2(done: Any) -> None:
    assert done.returncode == 2, done.stdout + done.stderr
    assert done.stderr.count("\n") == 1 and done.stderr.startswith("error:"), done.stderr
    assert "Traceback" not in done.stderr


def shipped_settings() -> dict[str, Any]:
    return json.loads((SHIPPED / "benchmark.json").read_text())["settings"]


@pytest.mark.parametrize(
    ("change", "named"),
    [
        ({"seeds": "abc"}, "seeds: expected a list of integers"),
        ({"timesteps": "10000"}, "timesteps: expected an integer"),
        ({"bias": float("nan")}, "bias: expected a finite number"),
        ({"final_test": 1}, "final_test: expected true or false"),
        ({"methods": [1]}, "methods: expected a list of strings"),
        ({"seeds": [-1]}, "seeds in [0"),
        ({"seeds": list(range(1001))}, "1 to 1000"),
        ({"zzz": 1}, "unknown settings ['zzz']"),
        ({"timesteps": 10**10}, "`timesteps` (env steps)"),
        ({"eval_episodes": 10**6}, "`eval_episodes`"),
        ({"env": {"env_id": "evilmod:Evil-v0", "env_kwargs": {}, "terms": ["a", "b"]}}, "module prefix"),
        (
            {
                "env": {
                    "env_id": "hddpg/SnakeReach-v0",
                    "env_kwargs": {"n_obstacles": 10**7},
                    "terms": ["a", "b"],
                }
            },
            "n_obstacles",
        ),
        (
            {"env": {"env_id": "hddpg/SnakeReach-v0", "env_kwargs": {}, "terms": ["../../x", "b"]}},
            "env.terms",
        ),
    ],
)
def test_settings_from_a_file_are_checked_field_by_field(change, named, tmp_path, monkeypatch):
    (tmp_path / "evilmod.py").write_text(EVIL_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    stored = {**shipped_settings(), **change}
    if "env" in change:
        stored["methods"] = ["hddpg"]
    with pytest.raises(ValueError, match=r"\AFILE: ") as error:
        settings_from_json(stored, "FILE")
    assert named in str(error.value)
    assert "evilmod" not in sys.modules and not (tmp_path / "IMPORTED").exists()


def test_the_shipped_settings_still_read_back():
    assert settings_from_json(shipped_settings(), "FILE") == BenchmarkSettings(**shipped_settings())


def test_every_budget_is_bounded_before_anything_trains():
    # A front manager's budget past the run options' bound used to pass here and fail its task after the
    # seed's workers had trained.
    with pytest.raises(ValueError, match=r"`front_timesteps` \(env steps\): expected an integer in"):
        BenchmarkSettings(methods=["hddpg-front"], scenario="front", timesteps=8, front_timesteps=10**11)
    # The manager's budget counts its decisions' env steps (option_steps each).
    with pytest.raises(ValueError, match=r"`timesteps` \(env steps\)"):
        BenchmarkSettings(methods=["hddpg"], timesteps=999_999_999)
    with pytest.raises(ValueError, match="`flat_timesteps`"):
        BenchmarkSettings(methods=["ddpg"], timesteps=8, flat_timesteps=10**10)


@pytest.mark.parametrize(
    "header",
    [
        [],
        {"settings": [1]},
        {"settings": {"methods": 5}},
        {"settings": {}, "budgets": [1]},
        {"settings": {}, "invocations": ["x"]},
        {"settings": {}, "invocations": [{"wall_time_s": "12"}]},
        {"settings": {}, "invocations": [{"wall_time_s": float("inf")}]},
    ],
)
def test_benchmark_json_has_one_reader_that_checks_its_shape(header, tmp_path):
    # A resumed benchmark read these fields at its end, after every run had trained: an AttributeError, exit 1.
    path = tmp_path / "benchmark.json"
    path.write_text(json.dumps(header))
    with pytest.raises(ValueError, match=r"benchmark\.json"):
        read_benchmark_file(path)


def edited_run(tmp_path: Path, name: str, settings: dict[str, Any] | None = None) -> Path:
    """A copy of the shipped benchmark folder with ``settings`` changed (its generated blocks are in page.md)."""
    run = tmp_path / name / "bench-e20"
    shutil.copytree(SHIPPED, run, ignore=shutil.ignore_patterns("*.png"))
    shutil.copy(REPO / "docs" / "RESULTS.md", tmp_path / name / "page.md")
    if settings is not None:
        stored = json.loads((run / "benchmark.json").read_text())
        stored["settings"].update(settings)
        (run / "benchmark.json").write_text(json.dumps(stored))
    return run


def test_report_over_an_edited_benchmark_json_is_one_line_and_imports_nothing(tmp_path):
    (tmp_path / "evilmod.py").write_text(EVIL_MODULE)
    evil = {"methods": ["hddpg"], "env": {"env_id": "evilmod:Evil-v0", "env_kwargs": {}, "terms": ["a", "b"]}}
    runs = [
        edited_run(tmp_path, "evil", evil),
        edited_run(tmp_path, "types", {"timesteps": "x", "methods": 5}),
        edited_run(tmp_path, "unknown", {"zzz": 1}),
    ]
    # From tmp_path: `python -m` puts the current folder first on the path, where evilmod.py lies.
    done = run_batch(
        [["report", str(run), "--page", str(run.parent / "page.md")] for run in runs], cwd=tmp_path
    )
    for result in done:
        one_line_exit_2(result)
    assert not (tmp_path / "IMPORTED").exists()
    assert (tmp_path / "evil" / "page.md").read_text() == (REPO / "docs" / "RESULTS.md").read_text()


def test_a_benchmark_of_too_many_seeds_is_refused_before_it_allocates_them(tmp_path):
    (done,) = run_batch([["benchmark", "--seeds", "300000000", "--out", str(tmp_path / "b")]])
    one_line_exit_2(done)
    assert "--seeds" in done.stderr and not (tmp_path / "b").exists()

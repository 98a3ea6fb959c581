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

from hddpg_zoo.benchmark import BenchmarkSettings
from hddpg_zoo.benchmark.benchmark_file import read_benchmark_file, settings_from_json
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


#: A page holding generated blocks of the shipped folder, the tables these tests regenerate.
SHIPPED_PAGE = "".join(
    f"<!-- generated:bench-e20/{name} -->\n<!-- /generated:bench-e20/{name} -->\n"
    for name in ("methods", "comparisons-hddpg", "per-seed-reach", "per-seed-touch", "per-seed-collisions")
)


def edited_run(tmp_path: Path, name: str, settings: dict[str, Any] | None = None) -> Path:
    """A copy of the shipped benchmark folder with ``settings`` changed (its generated blocks are in page.md)."""
    run = tmp_path / name / "bench-e20"
    shutil.copytree(SHIPPED, run, ignore=shutil.ignore_patterns("*.png"))
    (tmp_path / name / "page.md").write_text(SHIPPED_PAGE)
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
    assert (tmp_path / "evil" / "page.md").read_text() == SHIPPED_PAGE


def test_a_benchmark_of_too_many_seeds_is_refused_before_it_allocates_them(tmp_path):
    (done,) = run_batch([["benchmark", "--seeds", "300000000", "--out", str(tmp_path / "b")]])
    one_line_exit_2(done)
    assert "--seeds" in done.stderr and not (tmp_path / "b").exists()


# ------------------------------------------------------------------------------------ records and episodes.csv
HEADER = "method,seed,episode_set,episode_seed,reach_reward,reward,length\n"
ROW = "hddpg,0,development,15000,300.0,300.0,200\n"


@pytest.mark.parametrize(
    ("text", "named"),
    [
        (HEADER + ROW + "hddpg,0,development,15001,1,2,3,4,5\n", ":3: expected as many cells"),
        (HEADER + ROW + "hddpg,0\n", ":3: expected as many cells"),
        (HEADER + ROW + "hddpg,0,development,15001," + "1" * 200_000 + ",2,3\n", "not a CSV row"),
        (HEADER + ROW.replace(",0,", ",0.5,"), "whole number in column 'seed'"),
        (HEADER + ROW.replace("300.0,", "inf,", 1), "finite number"),
    ],
)
def test_episodes_csv_rows_that_are_not_ours_are_one_line(text, named, tmp_path):
    # Cells past the header's were a TypeError and a field over csv's size limit a csv.Error: exit 1.
    from hddpg_zoo.benchmark.episodes import read_episodes_csv

    path = tmp_path / "episodes.csv"
    path.write_text(text)
    with pytest.raises(ValueError, match=r"episodes\.csv") as error:
        read_episodes_csv(path)
    assert named in str(error.value)


def test_an_episodes_csv_is_read_within_a_budget_of_cells(tmp_path):
    # 64 MiB of one-digit cells passed the size limit and took 2 GB to read.
    from hddpg_zoo.benchmark.episodes import read_episodes_csv
    from sb3_hddpg.artifacts.limits import MAX_CSV_CELLS

    columns = 34
    path = tmp_path / "episodes.csv"
    header = "method,seed,episode_set,episode_seed," + ",".join(f"m{i}" for i in range(columns - 4))
    path.write_text(
        header + "\n" + ("h,0,d,1," + ",".join("0" * (columns - 4)) + "\n") * (MAX_CSV_CELLS // columns + 2)
    )
    with pytest.raises(ValueError, match=f"more than {MAX_CSV_CELLS} cells"):
        read_episodes_csv(path)


def test_report_over_records_that_lack_what_the_tables_read_is_one_line(tmp_path):
    def edit_record(run: Path, change: dict[str, Any]) -> Path:
        path = run / "records" / "hddpg" / "seed-0.json"
        path.write_text(json.dumps({**json.loads(path.read_text()), **change}))
        return run

    runs = [
        edit_record(edited_run(tmp_path, "test"), {"test": "x"}),
        edit_record(edited_run(tmp_path, "history"), {"history": []}),
        edit_record(edited_run(tmp_path, "seed"), {"seed": -1}),
        edit_record(edited_run(tmp_path, "version"), {"record_version": 99}),
    ]
    csv_run = edited_run(tmp_path, "csv")  # a snake run's episodes without the snake's metrics
    (csv_run / "episodes.csv").write_text(HEADER + ROW)
    (csv_run / "records" / "hddpg" / "seed-1.json").write_bytes(b"\xff\xfe")
    runs += [csv_run, edited_run(tmp_path, "csv-only")]
    (runs[-1] / "episodes.csv").write_text(HEADER + ROW)
    done = run_batch([["report", str(run), "--page", str(run.parent / "page.md")] for run in runs])
    for result in done:
        # numpy may warn first (the mean of an empty curve); the error is one line, the last.
        assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr
        assert result.stderr.splitlines()[-1].startswith("error:") and result.stderr.count("error:") == 1
    assert "goal_touch_rate" in done[-1].stderr


# ------------------------------------------------------------------------------------------------ pages
def test_a_page_of_unclosed_markers_is_searched_in_linear_time():
    import time

    from hddpg_zoo.benchmark.pages import BLOCK, render_page

    # Opening markers without their closing ones: each was searched to the page's end, quadratic in all.
    page = "<!-- generated:bench-e20/methods -->\n" * 30_000
    started = time.perf_counter()
    assert render_page(page, "bench-e20", None) == (page, [])
    assert time.perf_counter() - started < 5
    block = "<!-- generated:r/methods -->\nold\n<!-- /generated:r/methods -->"
    assert [m.group("body") for m in BLOCK.finditer(f"a\n{block}\nb\n{block}")] == ["old\n", "old\n"]


def test_report_refuses_to_replace_a_linked_page_by_a_file(tmp_path):
    run = edited_run(tmp_path, "linked")
    real = tmp_path / "linked" / "real.md"
    stale = (
        (tmp_path / "linked" / "page.md")
        .read_text()
        .replace("<!-- generated:bench-e20/methods -->\n", "<!-- generated:bench-e20/methods -->\nSTALE\n")
    )
    real.write_text(stale)
    link = tmp_path / "linked" / "link.md"
    link.symlink_to(real)
    (done,) = run_batch([["report", str(run), "--page", str(link)]])
    one_line_exit_2(done)
    # The link was replaced by a regular file holding the new tables, and the page it named kept STALE.
    assert "symbolic link" in done.stderr and link.is_symlink() and real.read_text() == stale

"""``hddpg-cli snapshot``: a benchmark's finished seeds copied into a folder that resumes and serves its workers."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from hddpg_zoo.model_export import read_index
from tests.cli_batch import run_batch
from tests.test_benchmark import cli
from tests.test_benchmark_methods import TINY

ARGS = ("benchmark", "--seeds", "2", "--methods", "goal-only,hddpg", *TINY)


def _files(folder: Path) -> dict[str, bytes]:
    return {
        p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


def test_a_snapshot_holds_whole_seeds_resumes_and_grows_without_replacing_a_run(tmp_path):
    bench, snap = tmp_path / "bench", tmp_path / "snap"
    done = cli(*ARGS, "--out", str(bench))
    assert done.returncode == 0, done.stdout + done.stderr
    # Seed 1 as if its manager were still training.
    unfinished = bench / "records" / "hddpg" / "seed-1.json"
    aside = tmp_path / "hddpg-seed-1.json"
    shutil.move(unfinished, aside)

    first = cli("snapshot", str(bench), str(snap))
    assert first.returncode == 0, first.stdout + first.stderr
    assert "3 runs copied" in first.stdout and "finished seeds: 0;" in first.stdout
    assert "not finished: 1" in first.stdout
    assert sorted(p.relative_to(snap).as_posix() for p in snap.glob("records/*/*.json")) == [
        "records/goal-only/seed-0.json",
        "records/hddpg/seed-0.json",
        "records/workers/seed-0.json",
    ]
    for name in ("goal", "avoid"):  # what --workers-from checks besides the zips
        assert (snap / "seed-0" / "evaluations" / f"{name}.json").read_bytes() == (
            bench / "seed-0" / "evaluations" / f"{name}.json"
        ).read_bytes()
    assert not list(snap.rglob("checkpoints")) and not list(snap.rglob("tensorboard"))
    assert not (snap / "seed-1").exists()
    index = read_index(snap)  # every file checked against its sha256
    assert [(e["method"], e["seed"]) for e in index] == [
        ("worker:goal", 0),
        ("worker:avoid", 0),
        ("hddpg", 0),
    ]
    assert json.loads((snap / "benchmark.json").read_text()) == json.loads(
        (bench / "benchmark.json").read_text()
    )

    # Taken again once seed 1 finished: only its runs are added, the others are left as they are.
    grown = tmp_path / "grown"
    shutil.copytree(snap, grown)
    shutil.move(aside, unfinished)
    before = _files(grown)

    # What would replace a run or anyone's files, or write outside DEST, is refused.
    other = tmp_path / "other"
    shutil.copytree(snap, other)
    record_file = other / "records" / "goal-only" / "seed-0.json"
    record = json.loads(record_file.read_text())
    record["test"]["mean_reach_reward"] += 1.0
    record_file.write_text(json.dumps(record))
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "notes.txt").write_text("mine")
    untouched = {folder: _files(folder) for folder in (other, theirs)}
    # A link planted in an earlier snapshot never sends a file elsewhere.
    linked, elsewhere = tmp_path / "linked", tmp_path / "elsewhere"
    shutil.copytree(snap, linked)
    shutil.move(linked / "records" / "hddpg", elsewhere)
    (linked / "records" / "hddpg").symlink_to(elsewhere)
    # A record moved to another run's place would copy that run's models under its name.
    moved = tmp_path / "moved"
    shutil.copytree(bench, moved, ignore=shutil.ignore_patterns("checkpoints", "tensorboard", "best"))
    shutil.copy(moved / "records" / "hddpg" / "seed-0.json", moved / "records" / "goal-only" / "seed-0.json")
    # None of these command lines changes what another reads: one interpreter runs them all
    # (tests/cli_batch.py), each with its own exit code and output.
    again, *refused = run_batch(
        [
            ["snapshot", str(bench), str(grown)],
            ["snapshot", str(moved), str(tmp_path / "new")],
            ["snapshot", str(bench), str(other)],
            ["snapshot", str(bench), str(theirs)],
            ["snapshot", str(bench), str(bench / "inside")],
            ["snapshot", str(theirs), str(tmp_path / "new")],
            ["snapshot", str(bench), str(linked)],
        ]
    )
    assert again.returncode == 0, again.stdout + again.stderr
    assert "3 runs copied" in again.stdout and "finished seeds: 0, 1;" in again.stdout
    after = _files(grown)
    assert {k: v for k, v in after.items() if k in before and k != "index.json"} == {
        k: v for k, v in before.items() if k != "index.json"
    }
    assert len(read_index(grown)) == 6

    expected_errors = (
        "expected the record of goal-only/seed-0",
        "holds another run of goal-only/seed-0",
        "holds other files",
        "apart from the benchmark",
        "no benchmark.json",
        "leads outside it",  # a record linked out of the run folder: refused by every read (containment)
    )
    for result, expected in zip(refused, expected_errors, strict=True):
        assert result.returncode == 2 and expected in result.stderr, result.stderr
        assert "Traceback" not in result.stderr
    assert {folder: _files(folder) for folder in (other, theirs)} == untouched
    assert not (bench / "inside").exists() and not (tmp_path / "new").exists()
    assert sorted(p.name for p in elsewhere.iterdir()) == ["seed-0.json"]

    # The snapshot resumes the benchmark (its runs kept, seed 1's run) and serves its workers; resumed on
    # its own, the snapshot is no longer one of the benchmark: never overwritten. The docs' tables come
    # from a snapshot's records as from the benchmark's own folder.
    page = tmp_path / "page.md"
    page.write_text("<!-- generated:grown/methods -->\n<!-- /generated:grown/methods -->\n")
    resumed, reused, overwrite, reported = run_batch(
        [
            [*ARGS, "--out", str(snap), "--resume"],
            [
                "benchmark",
                "--seeds",
                "2",
                "--methods",
                "goal-only",
                *TINY,
                "--workers-from",
                str(grown),
                "--out",
                str(tmp_path / "reused"),
            ],
            ["snapshot", str(bench), str(snap)],
            ["report", str(grown), "--page", str(page), "--tuning-page", str(page)],
        ]
    )
    assert resumed.returncode == 0, resumed.stdout + resumed.stderr
    assert resumed.stdout.count("kept") == 3 and resumed.stdout.count("started") == 3
    assert reused.returncode == 0, reused.stdout + reused.stderr
    assert overwrite.returncode == 2 and "run on its own" in overwrite.stderr
    assert reported.returncode == 0, reported.stdout + reported.stderr
    assert "goal-only" in page.read_text() and "hddpg" in page.read_text()


def test_a_benchmark_snapshots_each_seed_as_it_finishes(tmp_path):
    bench, snap, theirs = tmp_path / "bench", tmp_path / "snap", tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "notes.txt").write_text("mine")
    args = ["benchmark", "--seeds", "2", "--methods", "goal-only", *TINY]
    refused, done = run_batch(
        [
            [*args, "--out", str(tmp_path / "never"), "--snapshot", str(theirs)],
            [*args, "--out", str(bench), "--snapshot", str(snap)],
        ]
    )
    # A folder it may not fill is refused before anything runs.
    assert (
        refused.returncode == 2 and "'--snapshot'" in refused.stderr and "holds other files" in refused.stderr
    )
    assert not (tmp_path / "never").exists() and _files(theirs) == {"notes.txt": b"mine"}

    assert done.returncode == 0, done.stdout + done.stderr
    assert "left at this pace" in done.stdout and "4/4 runs done" in done.stdout  # the progress lines
    # One snapshot as each seed's last run finishes, one at the end (the invocation's wall time in it).
    assert done.stdout.count("snapshot: finished seeds 0 in") == 1
    assert done.stdout.count("snapshot: finished seeds 0, 1 in") == 2
    assert json.loads((snap / "benchmark.json").read_text()) == json.loads(
        (bench / "benchmark.json").read_text()
    )
    assert sorted(p.relative_to(snap).as_posix() for p in snap.glob("records/*/*.json")) == [
        f"records/{method}/seed-{seed}.json" for method in ("goal-only", "workers") for seed in (0, 1)
    ]
    assert [(e["method"], e["seed"]) for e in read_index(snap)] == [
        ("worker:goal", 0),
        ("worker:goal", 1),
        ("worker:avoid", 0),
        ("worker:avoid", 1),
    ]

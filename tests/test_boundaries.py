"""
The filesystem, process and exit-code boundaries: ``--force`` deletes only what the tool wrote, every name
that becomes a path is plain, writes stay inside their destination, and the CLI decides exit codes in one
place (2 for usage and input errors, 1 for internal ones, 130 for interrupts).

Each class is tried on more than the case that revealed it: the choke points are
``artifacts/run_folder.py::clear_run_folder``, ``names.py::check_plain_name``, the one writer of
``export_models`` and ``cli/errors.py::exit_code``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import pytest
import typer
from hypothesis import given, settings
from hypothesis import strategies as st

from hddpg_zoo.model_export import export_models
from hddpg_zoo.study_storage import StorageError, make_storage
from sb3_hddpg.artifacts.io import LOCK_FILE, FolderLockedError
from sb3_hddpg.artifacts.limits import LimitError
from sb3_hddpg.artifacts.run_folder import (
    RUN_MARKER,
    RunFolderError,
    check_clearable,
    clear_run_folder,
    mark_run_folder,
)
from sb3_hddpg.cli.errors import CommandStopped, error_line, exit_code
from sb3_hddpg.envs.terms_env import parse_terms
from sb3_hddpg.names import PlainNameError, check_plain_name
from tests.cli_batch import run_batch

REPO = Path(__file__).resolve().parents[1]
WORKER = REPO / "docs" / "results" / "models" / "seed-0" / "workers" / "goal.zip"


def one_line_exit_2(done: subprocess.CompletedProcess) -> None:
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and done.stderr.startswith("error:"), done.stderr
    assert "Traceback" not in done.stderr


def snapshot(folder: Path) -> dict[str, bytes | None]:
    """Every path below ``folder`` with its content (``None`` for folders)."""
    return {
        str(p.relative_to(folder)): (None if p.is_dir() else p.read_bytes())
        for p in sorted(folder.rglob("*"))
        if not p.is_symlink()
    }


# ------------------------------------------------------------------------------------ deletion (--force)
def user_folder(folder: Path) -> Path:
    """A folder a user made: notes, data, a sub-folder."""
    (folder / "data").mkdir(parents=True)
    (folder / "notes.txt").write_text("mine")
    (folder / "data" / "x.csv").write_text("1,2")
    return folder


def run_folder(folder: Path) -> Path:
    """A run folder the tool made, with a user's file dropped into it."""
    (folder / "workers").mkdir(parents=True)
    (folder / "workers" / "goal.zip").write_bytes(b"zip")
    (folder / "hierarchy.zip").write_bytes(b"zip")
    (folder / "tensorboard" / "goal").mkdir(parents=True)
    (folder / ".hierarchy.zip.abc.tmp").write_bytes(b"")
    (folder / "mine.txt").write_text("the user's")
    mark_run_folder(folder, "train-workers")
    return folder


def test_force_clears_only_the_tools_own_entries_and_keeps_foreign_ones(tmp_path):
    folder = run_folder(tmp_path / "run")
    outside = tmp_path / "elsewhere"
    user_folder(outside)
    (folder / "checkpoints").symlink_to(
        outside, target_is_directory=True
    )  # a link inside: removed, not followed
    kept = clear_run_folder(folder)
    assert kept == ["mine.txt"]
    assert sorted(p.name for p in folder.iterdir()) == [RUN_MARKER, "mine.txt"]
    assert snapshot(outside) == snapshot(user_folder(tmp_path / "same"))  # the link's target is untouched


@pytest.mark.parametrize(
    "where", ["cwd", "parent", "grandparent", "home", "root", "symlink", "foreign", "file"]
)
def test_force_refuses_folders_it_must_never_clear(tmp_path, monkeypatch, where):
    work = run_folder(tmp_path / "a" / "b" / "run")
    monkeypatch.chdir(work)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    user_folder(tmp_path / "home")
    mark_run_folder(tmp_path / "home", "train-workers")  # even a marked home folder is refused
    link = tmp_path / "link"
    link.symlink_to(user_folder(tmp_path / "users"), target_is_directory=True)
    (tmp_path / "f").write_text("x")
    target = {
        "cwd": Path("."),
        "parent": Path(".."),
        "grandparent": work.parent.parent,
        "home": tmp_path / "home",
        "root": Path("/"),
        "symlink": link,
        "foreign": tmp_path / "users",
        "file": tmp_path / "f",
    }[where]
    before = snapshot(tmp_path)
    with pytest.raises(RunFolderError) as refused:
        clear_run_folder(target)
    assert "\n" not in str(refused.value)
    assert snapshot(tmp_path) == before


HOLD = textwrap.dedent(
    """
    import sys, time
    from sb3_hddpg.artifacts.io import locked_folder
    with locked_folder(sys.argv[1]):
        print("held", flush=True)
        time.sleep(120)
    """
)


@pytest.fixture
def held_run(tmp_path):
    """A run folder whose lock another live process holds (as a running train-workers does)."""
    folder = run_folder(tmp_path / "cc")
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(folder)],
        env={**os.environ, "PYTHONPATH": str(REPO)},
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        yield folder, holder.pid
    finally:
        holder.kill()
        holder.wait()


def test_a_folder_a_live_run_holds_is_never_cleared(held_run, tmp_path):
    folder, pid = held_run
    before = snapshot(folder)
    with pytest.raises(RunFolderError, match=f"pid {pid}"):
        clear_run_folder(folder)
    assert snapshot(folder) == before and (folder / LOCK_FILE).exists()
    # Through the CLI: package and train-workers --force both refuse it, naming the holder.
    results = run_batch(
        [
            ["package", str(WORKER), "--out", str(folder), "--force"],
            ["train-workers", "--no-progress", "--timesteps", "10", "--out", str(folder), "--force"],
        ]
    )
    for done in results:
        assert done.returncode == 2 and f"pid {pid}" in done.stderr, done.stderr
        assert done.stderr.count("\n") == 1
    assert snapshot(folder) == before


def test_package_into_the_current_folder_deletes_nothing(tmp_path):
    home = user_folder(tmp_path / "project")
    before = snapshot(tmp_path)
    commands = [
        ["package", str(WORKER), "--out", out, "--force", "--episodes", "1"] for out in (".", "", "..")
    ]
    commands.append(["package", str(WORKER), "--out", str(home), "--force", "--episodes", "1"])
    for done in run_batch(commands, cwd=home):
        one_line_exit_2(done)
    assert snapshot(tmp_path) == before


@pytest.mark.slow  # two packages (evaluation and video each): about 40 s on a busy machine
def test_package_force_replaces_its_own_package_and_keeps_a_users_file(tmp_path):
    out = tmp_path / "pkg"
    package = ["package", str(WORKER), "--out", str(out), "--episodes", "1", "--video-steps", "3"]
    (first,) = run_batch([package])
    assert first.returncode == 0, first.stderr
    own = snapshot(out)
    (out / "mine.txt").write_text("keep me")
    refused, replaced = run_batch([package, [*package, "--force"]])
    one_line_exit_2(refused)  # not empty, no --force
    assert replaced.returncode == 0, replaced.stderr
    assert (out / "mine.txt").read_text() == "keep me"
    assert set(snapshot(out)) == set(own) | {"mine.txt"}


def test_a_run_folder_from_before_the_marker_is_recognised_by_its_lock_file(tmp_path):
    # Before the marker, a released lock left its file behind; that file is how such a folder is known.
    folder = tmp_path / "old"
    folder.mkdir()
    (folder / ".hddpg.lock").write_text("")
    (folder / "hierarchy.zip").write_bytes(b"zip")
    assert check_clearable(folder) == folder
    assert clear_run_folder(folder) == [] and not (folder / "hierarchy.zip").exists()


# ------------------------------------------------------------------------------------------ plain names
@pytest.mark.parametrize(
    "name",
    [
        "é",
        "a" * 65,
        "a" * 300,
        "..",
        ".",
        "../x",
        "a/b",
        "a\\b",
        "goal\n",
        "",
        " ",
        "-x",
        "_x",
        "x:y",
        "\u0663",
        "ｇｏａｌ",
        "a\x00",
    ],
)
def test_names_that_are_not_plain_are_refused_in_one_line(name):
    with pytest.raises(PlainNameError) as refused:
        check_plain_name(name, "term name")
    assert "\n" not in str(refused.value) and len(str(refused.value)) < 300
    if name == name.strip():  # --terms strips the spaces around each name
        with pytest.raises(ValueError):
            parse_terms(f"{name},fuel")


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=80))
def test_a_name_the_rule_accepts_stays_inside_its_folder(name):
    try:
        check_plain_name(name, "name")
    except PlainNameError:
        return
    folder = Path("/srv/run")
    assert name.isascii() and len(name) <= 64 and ".." not in name and not name.startswith(".")
    assert (folder / f"{name}.zip").resolve().parent == folder
    assert os.path.normpath(folder / name) == str(folder / name)


# ------------------------------------------------------------------------ writes outside the destination
def benchmark_with(tmp_path: Path, record: dict) -> Path:
    run = tmp_path / "bench"
    (run / "records" / "workers").mkdir(parents=True)
    (run / "records" / "workers" / "seed-0.json").write_text(json.dumps(record))
    return run


@pytest.mark.parametrize(
    "record",
    [
        {"status": "done", "method": "workers", "seed": 0, "workers": ["../../../evil/pwn"]},
        {"status": "done", "method": "workers", "seed": 0, "workers": {"../../evil": {}}},
        {"status": "done", "method": "workers", "seed": 0, "workers": ["/etc/passwd"]},
        {"status": "done", "method": "../../evil", "seed": 0},
        {"status": "done", "method": "hddpg@../../evil", "seed": 0},
        {"status": "done", "method": "workers", "seed": "0/../../..", "workers": ["goal"]},
        {"status": "done", "method": "workers", "seed": -1, "workers": ["goal"]},
        {"status": "done", "method": "workers", "seed": 10**30, "workers": ["goal"]},
        {"status": "done", "method": "workers", "seed": 0, "workers": ["goal"] * 1000},
    ],
)
def test_export_models_follows_no_name_out_of_its_destination(tmp_path, record):
    run = benchmark_with(tmp_path, record)
    before = snapshot(tmp_path)
    with pytest.raises(ValueError) as refused:
        export_models(run, tmp_path / "dest" / "a" / "b")
    assert "\n" not in str(refused.value)
    assert snapshot(tmp_path) == before


@pytest.mark.parametrize("dest", [".", "", "..", "/"])
def test_export_models_never_writes_into_the_current_a_parent_or_the_root_folder(tmp_path, monkeypatch, dest):
    run = benchmark_with(tmp_path, {"status": "done", "method": "workers", "seed": 0, "workers": ["goal"]})
    monkeypatch.chdir(run)
    before = snapshot(tmp_path)
    with pytest.raises(RunFolderError):
        export_models(run, dest)
    assert snapshot(tmp_path) == before


def test_export_models_refuses_a_destination_whose_links_lead_elsewhere(tmp_path):
    run = benchmark_with(tmp_path, {"status": "done", "method": "workers", "seed": 0, "workers": ["goal"]})
    (run / "seed-0" / "workers").mkdir(parents=True)
    (run / "seed-0" / "workers" / "manifest.json").write_text("{}")
    (run / "seed-0" / "workers" / "goal.zip").write_bytes(b"zip")
    dest, elsewhere = tmp_path / "dest", tmp_path / "elsewhere"
    dest.mkdir()
    elsewhere.mkdir()
    (dest / "seed-0").symlink_to(elsewhere, target_is_directory=True)
    with pytest.raises(RunFolderError, match="holds other files"):
        export_models(run, dest)
    (dest / "index.json").write_text("[]")  # an earlier export, with a link planted in it
    with pytest.raises(ValueError, match="resolves outside"):
        export_models(run, dest)
    assert list(elsewhere.iterdir()) == []


# ----------------------------------------------------------------------------- exit codes, in one place
@pytest.mark.parametrize(
    ("error", "code"),
    [
        (ValueError("bad"), 2),
        (LimitError("too big"), 2),
        (PlainNameError("é"), 2),
        (RunFolderError("refused"), 2),
        (StorageError("cannot open"), 2),
        (FileNotFoundError(2, "No such file", "x"), 2),
        (IsADirectoryError("a folder"), 2),
        (NotADirectoryError("a file"), 2),
        (FileExistsError("exists"), 2),
        (FolderLockedError("in use by pid 3"), 2),
        (gym.error.NameNotFound("Environment `x` doesn't exist."), 2),
        (gym.error.DependencyNotInstalled("highway-env"), 2),
        (typer.BadParameter("nope"), 2),
        (KeyError("x"), 1),
        (RuntimeError("crashed"), 1),
        (MemoryError(), 1),
        (OSError(28, "No space left on device"), 1),
        (ZeroDivisionError("division by zero"), 1),
        (KeyboardInterrupt(), 130),
        (typer.Abort(), 130),
        (CommandStopped("Stopped: the same command with --resume continues it."), 130),
        (typer.Exit(3), 3),
    ],
)
def test_the_exit_code_of_every_kind_of_ending_is_decided_in_one_place(error, code):
    assert exit_code(error) == code
    if not isinstance(error, typer.Exit):
        line = error_line(error)
        assert line and "\n" not in line
    if isinstance(error, KeyError):
        assert error_line(error) == "KeyError: 'x'"  # a bare key says nothing without its type


def test_an_interrupted_command_says_so_in_one_line_and_exits_130(monkeypatch, capsys, tmp_path):
    # typer turns the KeyboardInterrupt into an exit code before the CLI's own handler sees it.
    from hddpg_zoo.cli import snapshot
    from sb3_hddpg import cli

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "benchmark.json").write_text("{}")
    monkeypatch.setattr(snapshot, "snapshot_benchmark", interrupted)
    with pytest.raises(SystemExit) as ended:
        cli.main(["snapshot", str(tmp_path / "run"), str(tmp_path / "copy")])
    assert ended.value.code == 130
    assert capsys.readouterr().err.strip() == "error: interrupted"

    # A command that saved its work first says how to continue instead, on its output.
    def stopped(*args, **kwargs):
        raise CommandStopped("Stopped: run it again to continue.")

    monkeypatch.setattr(snapshot, "snapshot_benchmark", stopped)
    with pytest.raises(SystemExit) as ended:
        cli.main(["snapshot", str(tmp_path / "run"), str(tmp_path / "copy")])
    out, err = capsys.readouterr()
    assert ended.value.code == 130 and out.strip() == "Stopped: run it again to continue." and err == ""


@pytest.mark.parametrize(
    "url",
    [
        "sqlite:///file::memory:?uri=true",
        "sqlite:///file:x?mode=memory&uri=true",
        "sqlite:///{tmp}",
        "sqlite:///0/",  # a folder path: SQLite would write a file and its journals beside it
        "sqlite:///{tmp}/new/",
        "sqlite:////dev/null",
        "postgresql+psycopg://u:secret@127.0.0.1:{port}/db",
        "postgresql+psycopg://u:secret@127.0.0.1:{port}/db?sslmode=bogus",
    ],
)
def test_unusable_study_storages_are_input_errors_without_the_password(
    tmp_path, url, unused_port, monkeypatch
):
    monkeypatch.chdir(tmp_path)  # a relative path that slipped through would write here, not in the checkout
    url = url.format(tmp=tmp_path, port=unused_port)
    if "psycopg" in url:
        pytest.importorskip("psycopg")
    started = time.monotonic()
    with pytest.raises(ValueError) as refused:
        make_storage(url)
    assert exit_code(refused.value) == 2
    assert "secret" not in str(refused.value) and "\n" not in str(refused.value)
    assert time.monotonic() - started < 30
    assert not (tmp_path / "0").exists() and not (tmp_path / "0-shm").exists()


def test_a_file_a_command_writes_is_replaced_only_with_force(tmp_path):
    """record, plot-selection, evaluate --json and rollout --png never replace an existing file unasked."""
    from sb3_hddpg.artifacts.run_folder import check_output_file

    mine = tmp_path / "mine.gif"
    mine.write_bytes(b"my own video")
    (tmp_path / "folder.png").mkdir()
    (tmp_path / "link.json").symlink_to(tmp_path / "elsewhere.json")
    for path in (mine, tmp_path / "folder.png", tmp_path / "link.json"):
        with pytest.raises(RunFolderError):
            check_output_file(path, force=False)
    assert check_output_file(mine, force=True) == mine
    assert check_output_file(tmp_path / "new.gif", force=False) == tmp_path / "new.gif"
    (tmp_path / "mine.png").write_bytes(b"my own figure")
    (tmp_path / "mine.json").write_text("{}")
    commands = [
        ["record", str(WORKER), "--out", str(mine), "--max-steps", "2"],
        ["plot-selection", str(WORKER), "--out", str(tmp_path / "mine.png"), "--max-steps", "2"],
        ["evaluate", "random", "--episodes", "1", "--json", str(tmp_path / "mine.json")],
        ["rollout", "--episodes", "1", "--png", str(tmp_path / "mine.png")],
    ]
    for argv, done in zip(commands, run_batch(commands)):
        one_line_exit_2(done)
        assert "--force" in done.stderr, (argv, done.stderr)
    assert mine.read_bytes() == b"my own video"
    assert (tmp_path / "mine.png").read_bytes() == b"my own figure"
    assert (tmp_path / "mine.json").read_text() == "{}"
    (replaced,) = run_batch(
        [["evaluate", "random", "--episodes", "1", "--json", str(tmp_path / "mine.json"), "--force"]]
    )
    assert replaced.returncode == 0, replaced.stderr
    assert json.loads((tmp_path / "mine.json").read_text()) != {}


@pytest.fixture
def unused_port() -> int:
    import socket

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def test_the_listed_cli_cases_exit_2_with_one_line(tmp_path, unused_port):
    """The issue's cases of these classes, and variants, through the CLI (one interpreter for all)."""
    (tmp_path / "dir.gif").mkdir()
    tune = ("tune", "--level", "worker", "--worker", "goal", "--n-trials", "1", "--timesteps", "50")
    storages = [
        "sqlite:///file::memory:?uri=true",
        f"sqlite:///{tmp_path}",
        "sqlite:////dev/null",
        f"postgresql+psycopg://u:secret@127.0.0.1:{unused_port}/db?sslmode=bogus",
    ]
    commands = [[*tune, "--storage", url, "--out", str(tmp_path / f"t{i}")] for i, url in enumerate(storages)]
    commands.append(["record", str(WORKER), "--out", str(tmp_path / "dir.gif")])
    traversal = {"status": "done", "method": "workers", "seed": 0, "workers": ["../../../evil/pwn"]}
    commands.append(["export-models", str(benchmark_with(tmp_path, traversal)), str(tmp_path / "dest")])
    env = ("train-workers", "--env", "mo-mountaincarcontinuous-v0", "--out", str(tmp_path / "o"), "--terms")
    commands += [[*env, terms] for terms in ("é,fuel", "a" * 300 + ",fuel", "../x,fuel", "time,ti me")]
    for argv, done in zip(commands, run_batch(commands)):
        assert done.returncode == 2, (argv, done.stderr)
        assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr, done.stderr
        assert "secret" not in done.stderr
    assert not any((tmp_path / name).exists() for name in ("o", "dest", "evil"))


# ------------------------------------------------------------------------------- the current folder, MuJoCo
def test_mujoco_warnings_go_to_logging_not_to_a_file_in_the_current_folder(tmp_path, monkeypatch, caplog):
    """MuJoCo writes MUJOCO_LOG.TXT to the current folder unless a warning callback is set: one is."""
    import types

    from sb3_hddpg.envs.adapters import make_adapted

    installed: list[Any] = []
    fake = types.SimpleNamespace(
        get_mju_user_warning=lambda: installed[-1] if installed else None,
        set_mju_user_warning=installed.append,
    )
    monkeypatch.setitem(sys.modules, "mujoco", fake)
    monkeypatch.chdir(tmp_path)
    make_adapted("mo-mountaincarcontinuous-v0").close()
    make_adapted("mo-mountaincarcontinuous-v0").close()
    assert len(installed) == 1  # once per process; a user's own callback would stay
    with caplog.at_level("WARNING", logger="sb3_hddpg.mujoco"):
        installed[0]("Nan, Inf or huge value in QACC at DOF 0.\n")
    assert "MuJoCo: Nan, Inf or huge value in QACC" in caplog.text
    assert list(tmp_path.iterdir()) == []
    # A model's compile warning comes again with every env made: logged once per process, others still logged.
    caplog.clear()
    with caplog.at_level("WARNING", logger="sb3_hddpg.mujoco"):
        for _ in range(3):
            installed[0]("compiler attribute 'settotalmass' is deprecated\n")
        installed[0]("Nan, Inf or huge value in QACC at DOF 1.\n")
    assert caplog.text.count("settotalmass") == 1 and "DOF 1" in caplog.text

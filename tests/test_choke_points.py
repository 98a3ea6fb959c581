"""
The third pass of docs/ROBUSTNESS.md: each class of defect is held at its one choke point, and the tests
here call that place (and, for a sample of the issue's reproductions, the CLI in one batch interpreter).

1. folders the user owns: ``artifacts/run_folder.py::check_out_folder`` and the marker's inventory;
2. reads and writes outside the named folder: ``hddpg_zoo/model_export.py::file_inside``, plain names, storages
   that are only read;
3. files that are not what they seem: ``artifacts/limits.py::read_file_bytes`` and
   ``check_zip_directory``, ``artifacts/provenance.py::read_verified``;
4. counts: ``artifacts/limits.py::COUNTS`` / ``check_count``;
5. values: the manifest reader, the wrapper's probabilities, preferences, ``check_resumed_agent``;
6. messages: one line naming the option, file or field.
"""

from __future__ import annotations

import copy
import json
import os
import shutil
import time
import zipfile
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import sb3_hddpg  # noqa: F401  (registers the ids)
from hddpg_zoo.model_export import file_inside
from hddpg_zoo.study_storage import StorageError, make_storage
from hddpg_zoo.tuning.results import check_only_block_changed, replace_block
from sb3_hddpg.artifacts import limits
from sb3_hddpg.artifacts.io import LOCK_FILE
from sb3_hddpg.artifacts.limits import (
    COUNTS,
    LimitError,
    check_count,
    check_zip_directory,
    count_bounds,
    read_file_bytes,
)
from sb3_hddpg.artifacts.manifests import ResumeMismatch, check_resumed_agent, load_workers
from sb3_hddpg.artifacts.records import read_workers_manifest
from sb3_hddpg.artifacts.records.models import models_manifest_from_json
from sb3_hddpg.artifacts.run_folder import (
    RUN_MARKER,
    RunFolderError,
    check_out_folder,
    clear_run_folder,
    mark_run_folder,
    record_written,
)
from sb3_hddpg.hierarchy import WorkerSelectionWrapper
from sb3_hddpg.hierarchy.bundle import BundleError
from sb3_hddpg.hierarchy.conditioning import PreferenceSpace
from sb3_hddpg.hierarchy.hierarchy import Hierarchy
from sb3_hddpg.hierarchy.selection import check_preferences, preferences_from_bias
from tests.cli_batch import run_batch
from tests.helpers import ConstantWorker

REPO = Path(__file__).resolve().parents[1]
WORKERS = REPO / "docs" / "results" / "models" / "seed-0" / "workers"
HIERARCHY = REPO / "docs" / "results" / "models" / "seed-0" / "hddpg" / "hierarchy.zip"


def contents(folder: Path) -> dict[str, bytes | None]:
    """Every path below ``folder`` with its content (``None`` for folders), links not followed."""
    return {
        str(p.relative_to(folder)): (None if p.is_dir() and not p.is_symlink() else p.read_bytes())
        for p in sorted(folder.rglob("*"))
        if not p.is_symlink()
    }


def users_folder(folder: Path) -> Path:
    """The issue's folder of a user's: names the tool itself writes, and one it does not."""
    (folder / "evaluations").mkdir(parents=True)
    (folder / "evaluations" / "x.csv").write_text("1,2")
    for name in ("README.md", "a.png", "t.zip", "results.md", "figure9.png"):
        (folder / name).write_text(f"the user's {name}")
    return folder


# ------------------------------------------------------------------ 1. folders the user owns
def test_a_users_folder_a_link_and_a_protected_folder_are_never_written(tmp_path, monkeypatch):
    mine = users_folder(tmp_path / "mine")
    before = contents(mine)
    with pytest.raises(RunFolderError, match="this tool did not write"):
        check_out_folder(mine)
    link = tmp_path / "run"
    link.symlink_to(mine)
    with pytest.raises(RunFolderError, match="symbolic link"):
        check_out_folder(link)
    monkeypatch.chdir(mine)
    with pytest.raises(RunFolderError, match="the current folder"):
        check_out_folder(mine)
    assert contents(mine) == before
    # New and empty folders are fine.
    assert check_out_folder(tmp_path / "new") == tmp_path / "new"
    (tmp_path / "empty").mkdir()
    assert check_out_folder(tmp_path / "empty") == tmp_path / "empty"


def test_force_deletes_only_the_inventory_and_a_users_file_of_a_tool_name_stops_the_run(tmp_path):
    folder = tmp_path / "run"
    mark_run_folder(folder, "train-workers")
    (folder / "workers").mkdir()
    (folder / "workers" / "goal.zip").write_bytes(b"zip")
    (folder / "hierarchy.zip").write_bytes(b"zip")
    record_written(folder)
    # The user drops files into the finished run folder, one of a name the tool writes.
    (folder / "README.md").write_text("my notes")
    (folder / "notes.txt").write_text("mine")
    with pytest.raises(RunFolderError, match=r"'README\.md' there was not written by this tool"):
        check_out_folder(folder)
    kept = clear_run_folder(folder)
    assert sorted(kept) == ["README.md", "notes.txt"]
    assert (folder / "README.md").read_text() == "my notes" and not (folder / "workers").exists()


def test_a_run_killed_before_its_inventory_keeps_what_was_there_before(tmp_path):
    folder = tmp_path / "run"
    mark_run_folder(folder, "train-workers")
    (folder / "workers").mkdir()
    record_written(folder)
    (folder / "results.md").write_text("the user's")
    with pytest.raises(RunFolderError):
        check_out_folder(folder)
    (folder / "results.md").rename(tmp_path / "results.md")
    # A --force run takes the folder, writes, and is killed before recording its inventory.
    mark_run_folder(folder, "benchmark", reopen=True)
    (folder / "checkpoints").mkdir()
    (folder / "notes.txt").write_text("mine, still")
    assert json.loads((folder / RUN_MARKER).read_text())["open"] is True
    assert clear_run_folder(folder) == ["notes.txt"]
    assert not (folder / "checkpoints").exists() and not (folder / "workers").exists()


NAMES = st.sampled_from(
    ["workers", "hierarchy.zip", "README.md", "a.png", "t.zip", "evaluations", "notes.txt", "data", "x"]
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    before=st.sets(NAMES, max_size=4),
    written=st.sets(NAMES, max_size=4),
    after=st.sets(NAMES, max_size=4),
    as_dirs=st.sets(NAMES),
)
def test_folder_contents_property(tmp_path_factory, before, written, after, as_dirs):
    """
    Whatever a folder holds before the tool takes it, what the tool writes and what the user adds later:
    the tool takes only a new or empty folder, and ``--force`` deletes exactly what the tool wrote.
    """
    folder = tmp_path_factory.mktemp("folder")

    def put(names: set[str], tag: str) -> None:
        for name in names:
            if (folder / name).exists():
                continue
            if name in as_dirs:
                (folder / name).mkdir()
                (folder / name / "f").write_text(tag)
            else:
                (folder / name).write_text(tag)

    put(before, "user")
    try:
        check_out_folder(folder)
    except RunFolderError:
        assert before, "an empty folder was refused"
        return
    assert not before
    mark_run_folder(folder, "train-workers")
    put(written, "tool")
    record_written(folder)
    put(after - written, "user")
    users = {name for name in after - written}
    kept = clear_run_folder(folder)
    assert set(kept) == users
    for name in users:
        assert (folder / name).exists()
    for name in written:
        assert not (folder / name).exists()


def test_save_config_replaces_only_the_tuned_block_and_keeps_comments():
    text = (
        "# my notes on these blocks\n"
        "default: &tiny\n"
        "  gamma: 0.9  # why 0.9\n"
        "# goal: tuned below\n"
        "goal:\n"
        "  <<: *tiny\n"
        "  learning_rate: 0.001\n"
        "\n"
        "# avoid is hand-made\n"
        "avoid:\n"
        "  <<: *tiny\n"
    )
    tuned = "# hddpg-cli tune: block 'goal'\ngoal:\n  learning_rate: 0.0003\n"
    new = replace_block(text, "goal", tuned)
    assert new.count("\n") == text.count("\n")  # the block's three lines became the tuned three
    for line in ("# my notes on these blocks", "  gamma: 0.9  # why 0.9", "# avoid is hand-made"):
        assert line in new
    assert yaml.safe_load(new)["goal"] == {"learning_rate": 0.0003}
    # Tuning again replaces the note and the block, nothing else.
    again = replace_block(new, "goal", tuned.replace("0.0003", "0.0001"))
    assert again.count("hddpg-cli tune") == 1 and again.count("\n") == new.count("\n")
    # A block whose anchor another block uses cannot be replaced without changing that block.
    anchored = "goal: &g\n  gamma: 0.9\navoid:\n  <<: *g\n"
    with pytest.raises(ValueError, match="would break the file"):
        check_only_block_changed(
            yaml.safe_load(anchored),
            replace_block(anchored, "goal", "goal:\n  gamma: 0.5\n"),
            "goal",
            "c.yml",
        )
    # An anchor kept in the new block, but with other values, changes the block that uses it.
    with pytest.raises(ValueError, match="would change \\['avoid'\\]"):
        check_only_block_changed(
            yaml.safe_load(anchored),
            replace_block(anchored, "goal", "goal: &g\n  gamma: 0.5\n"),
            "goal",
            "c.yml",
        )


# ------------------------------------------------------------------ 2. outside the named folder
def test_a_link_inside_a_run_folder_is_never_followed(tmp_path):
    secret = tmp_path / "secret"
    secret.write_text("secret")
    run = tmp_path / "run"
    (run / "seed-0" / "workers").mkdir(parents=True)
    (run / "seed-0" / "workers" / "goal.zip").symlink_to(secret)
    (run / "seed-1").symlink_to(tmp_path)
    with pytest.raises(LimitError, match="symbolic link inside"):
        file_inside(run, "seed-0/workers/goal.zip")
    with pytest.raises(LimitError, match="symbolic link inside"):
        file_inside(run, "seed-1/secret")
    with pytest.raises(LimitError, match="outside"):
        file_inside(run, "../secret")
    (run / "seed-0" / "ok.json").write_text("{}")
    assert file_inside(run, "seed-0/ok.json") == run / "seed-0" / "ok.json"


def test_reading_a_study_leaves_no_new_database(tmp_path):
    path = tmp_path / "nosuch.db"
    with pytest.raises(StorageError, match="does not exist"):
        make_storage(f"sqlite:///{path}", heartbeat_interval=None, create=False)
    assert not path.exists() and list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------ 3. files that are not what they seem
def test_fifos_devices_and_sparse_giants_are_refused_before_reading(tmp_path):
    fifo = tmp_path / "manifest.json"
    os.mkfifo(fifo)
    start = time.monotonic()
    with pytest.raises(LimitError, match="FIFO"):
        read_file_bytes(fifo, 1 << 20)
    with pytest.raises(LimitError, match="FIFO"):
        read_workers_manifest(fifo)
    with pytest.raises(BundleError, match="FIFO, socket or device"):
        Hierarchy.load("/dev/zero")
    sparse = tmp_path / "goal.zip"
    with open(sparse, "wb") as handle:
        handle.truncate(16 << 30)
    with pytest.raises(LimitError, match=f"{16 << 30} bytes is over"):
        read_file_bytes(sparse, limits.MAX_MODEL_FILE_BYTES)
    assert time.monotonic() - start < 10


def test_a_sparse_worker_and_a_fifo_manifest_in_a_workers_folder(tmp_path):
    folder = tmp_path / "workers"
    shutil.copytree(WORKERS, folder)
    with open(folder / "avoid.zip", "r+b") as handle:
        handle.truncate(16 << 30)
    start = time.monotonic()
    with pytest.raises(LimitError, match="over the"):
        load_workers(folder)
    assert time.monotonic() - start < 20  # hashing 16 GiB took 49 s
    (folder / "manifest.json").unlink()
    os.mkfifo(folder / "manifest.json")
    with pytest.raises(LimitError, match="FIFO"):
        load_workers(folder)


def test_zips_with_two_members_of_one_name_are_refused(tmp_path):
    path = tmp_path / "twice.zip"
    with zipfile.ZipFile(path, "w") as archive, pytest.warns(UserWarning, match="Duplicate name"):
        archive.writestr("manifest.json", "{}")
        archive.writestr("manifest.json", '{"other": 1}')
    with zipfile.ZipFile(path) as archive, pytest.raises(LimitError, match="two members are named"):
        check_zip_directory(archive, str(path))
    with pytest.raises(BundleError, match=r"two members are named 'manifest\.json'"):
        Hierarchy.load(path)


def test_the_weights_loaded_are_the_bytes_hashed_even_if_the_file_is_swapped(tmp_path, monkeypatch):
    """The file is replaced right after it was read for hashing: the load must use what was hashed."""
    import sb3_hddpg.artifacts.provenance as provenance

    folder = tmp_path / "workers"
    shutil.copytree(WORKERS, folder)
    real_read = provenance.read_file_bytes
    swapped: list[str] = []

    def read_then_swap(path, *args, **kwargs):
        data = real_read(path, *args, **kwargs)
        if Path(path).name == "goal.zip":
            shutil.copy(folder / "avoid.zip", path)  # another valid model zip, unverified
            swapped.append(str(path))
        return data

    monkeypatch.setattr(provenance, "read_file_bytes", read_then_swap)
    workers = load_workers(folder)
    assert swapped
    monkeypatch.undo()
    reference = load_workers(WORKERS)
    for name in ("goal", "avoid"):
        for key, value in reference[name].policy.state_dict().items():
            assert np.array_equal(workers[name].policy.state_dict()[key].numpy(), value.numpy()), (name, key)


# ------------------------------------------------------------------ 4. counts
@settings(max_examples=200, deadline=None)
@given(
    name=st.sampled_from(sorted(COUNTS)),
    value=st.one_of(
        st.integers(min_value=-(2**70), max_value=2**70),
        st.integers(min_value=-3, max_value=40_000),
        st.floats(allow_nan=True),
        st.booleans(),
        st.text(max_size=5),
        st.none(),
    ),
)
def test_every_count_is_checked_against_the_one_table(name, value):
    low, high = count_bounds(name)
    try:
        checked = check_count(name, value, f"--{name}")
    except LimitError as error:
        text = str(error)
        assert text.startswith(f"--{name}: expected an integer in [{low}, {high}]") and "\n" not in text
        assert len(text) < 400
        return
    assert type(checked) is int and low <= checked <= high


@settings(max_examples=40, deadline=None)
@given(
    n=st.integers(min_value=0, max_value=400),
    bounds=st.lists(
        st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-5, 5), st.text(max_size=3)),
        min_size=0,
        max_size=3,
    ),
)
def test_manifest_values_property(n, bounds):
    """A workers manifest of any length and any reward bounds: refused in one line, or every value in range."""
    entry = {"file": "w.zip", "sha256": "0" * 64, "reward_term": "goal", "reward_bounds": bounds}
    value = {
        "schema_version": 1,
        "workers": {f"w{i}": {**entry, "file": f"w{i}.zip"} for i in range(n)},
    }
    try:
        manifest = models_manifest_from_json(value, "workers", "m.json")
    except ValueError as error:
        assert "\n" not in str(error) and str(error).startswith(("m.json", "Expected `m.json"))
        return
    assert len(manifest.entries) <= limits.MAX_MODELS
    for checked in manifest.entries.values():
        low, high = checked["reward_bounds"]
        assert np.isfinite(low) and np.isfinite(high) and low < high


# ------------------------------------------------------------------ 5. values
def make_wrapper(selection: str = "mix") -> WorkerSelectionWrapper:
    workers = {"goal": ConstantWorker(np.full(6, 0.5)), "avoid": ConstantWorker(np.full(6, -0.5))}
    return WorkerSelectionWrapper(gym.make("hddpg/SnakeReach-v0"), workers, selection=selection)


@pytest.mark.parametrize("shape", [(7,), (3,), (), (2, 2), (1, 2)])
def test_the_wrapper_takes_one_value_per_worker_and_nothing_else(shape):
    env = make_wrapper()
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(2,\)"):
        env.step(np.zeros(shape, dtype=np.float32))
    env.step(np.zeros(2, dtype=np.float32))


def test_a_selector_whose_probabilities_do_not_sum_to_one_is_stopped_before_a_worker_acts():
    env = make_wrapper()
    env.reset(seed=0)
    env.selector = copy.copy(env.selector)
    env.selector.probabilities = lambda simplex, action: [0.7, 0.7]  # type: ignore[method-assign]
    with pytest.raises(ValueError, match="summing to 1"):
        env.step(np.zeros(2, dtype=np.float32))
    discrete = make_wrapper("discrete")
    discrete.reset(seed=0)
    for bad in (np.array([0, 1]), np.array(0.5), np.array([[1]])):
        with pytest.raises(ValueError, match="one worker index"):
            discrete.step(bad)
    discrete.step(np.int64(1))


def test_preferences_weight_rewards_within_range_and_ratios_normalise_without_overflow():
    with pytest.raises(ValueError, match="at most 1e\\+06"):
        check_preferences({"goal": 1e308, "avoid": 1e308}, ["goal", "avoid"])
    with pytest.raises(ValueError, match="bias"):
        preferences_from_bias(["goal", "avoid"], "goal", 1e308)
    space = PreferenceSpace.parse("ratio-sweep", ["goal", "avoid"])
    assert space.check({"goal": 1e308, "avoid": 1e308}) == pytest.approx(space.check({"goal": 1, "avoid": 1}))
    assert np.all(np.isfinite(space.weights({"goal": 1e308, "avoid": 1e308})))


def test_a_resumed_agent_keeps_its_algorithm_seed_and_config():
    entry = {"algo": "ddpg", "seed": 0, "config": {"file": "c.yml", "block": {"learning_rate": 0.001}}}
    check_resumed_agent(entry, "goal", "ddpg", 0, {"learning_rate": 0.001})
    for asked, needle in (
        (("td3", 0, {"learning_rate": 0.001}), "--algo of 'goal' was 'ddpg' in the run, now 'td3'"),
        (("ddpg", 5, {"learning_rate": 0.001}), "--seed was 0 in the run"),
        (("ddpg", 0, {"learning_rate": 0.1}), "learning_rate was 0.001 in the run, now 0.1"),
    ):
        with pytest.raises(ResumeMismatch, match=needle):
            check_resumed_agent(entry, "goal", *asked)
    # Said on purpose, a difference is accepted (the manifest then records the new value).
    check_resumed_agent(entry, "goal", "td3", 5, {"learning_rate": 0.1}, accept=["algo", "seed", "config"])
    with pytest.raises(ResumeMismatch, match="--seed was 0"):
        check_resumed_agent(entry, "goal", "td3", 5, {"learning_rate": 0.001}, accept=["algo"])


# ------------------------------------------------------------------ the issue's reproductions, through the CLI
def test_the_issues_reproductions_end_in_one_line_naming_what_is_at_fault(tmp_path):
    mine = users_folder(tmp_path / "p")
    link = tmp_path / "link"
    link.symlink_to(mine)
    bundle = tmp_path / "b"
    before = contents(mine)
    fifo_dir = tmp_path / "fifo-workers"
    fifo_dir.mkdir()
    os.mkfifo(fifo_dir / "manifest.json")
    worker = str(WORKERS / "goal.zip")
    cases = [
        (["train-workers", "--timesteps", "10", "--out", str(mine)], "'--out'", "this tool did not write"),
        (["train-workers", "--timesteps", "10", "--out", str(link), "--force"], "'--out'", "symbolic link"),
        (["train-flat", "--timesteps", "10", "--out", str(mine), "--force"], "'--out'", "this tool did not"),
        (["benchmark", "--timesteps", "10", "--out", str(mine)], "'--out'", "this tool did not write"),
        (["quickstart", "--out", str(link), "--force"], "'--out'", "symbolic link"),
        (["train-manager", "--workers", str(fifo_dir), "--out", str(bundle)], "", "FIFO"),
        (["evaluate", worker, "--episodes", "1000000000"], "'--episodes'", "[1, 10000]"),
        (["rollout", "--episodes", "1000000000"], "'--episodes'", "[1, 10000]"),
        (["record", worker, "--out", str(tmp_path / "v.gif"), "--episodes", "1000000"], "'--episodes'", ""),
        (
            ["package", worker, "--out", str(tmp_path / "k"), "--video-steps", "1000000000"],
            "'--video-steps'",
            "",
        ),
        (["tune", "--level", "flat", "--seeds-per-trial", "1000000"], "'--seeds-per-trial'", ""),
        (["tune", "--level", "flat", "--n-jobs", "200"], "'--n-jobs'", "usable cores"),
        (
            ["tune", "--level", "flat", "--study-name", "../../../escaped"],
            "'--study-name'",
            "expected a name",
        ),
        (
            ["train-manager", "--workers", str(WORKERS), "--option-steps", "1000000000"],
            "'--option-steps'",
            "",
        ),
        (["train-manager", "--workers", str(WORKERS), "--manager-motion", "1e308"], "'--manager-motion'", ""),
        (["evaluate", "/dev/zero"], "", "device or pipe"),
        (["evaluate", str(HIERARCHY), "--state-worker", "../../etc"], "'--state-worker'", "its workers are"),
        (["train-manager", "--workers", str(WORKERS), "--prefer", "goal", "--bias", "1e308"], "", "bias"),
        (["train-flat", "--preference", "goal=1e308,avoid=1e308", "--out", str(bundle)], "", "at most 1e+06"),
        (["benchmark", "--ham-threshold", "nan", "--out", str(bundle)], "'--ham-threshold'", "nan"),
        (["benchmark", "--timesteps", str(10**20), "--out", str(bundle)], "'--timesteps'", "[1, 1000000000]"),
        (
            [
                "export-study",
                "--storage",
                f"sqlite:///{tmp_path}/nosuch.db",
                "--study-name",
                "s",
                "--out",
                "o",
            ],
            "'--storage'",
            "does not exist",
        ),
        (
            [
                "export-study",
                "--storage",
                "sqlite:///s.db",
                "--study-name",
                "../../x",
                "--out",
                str(tmp_path),
            ],
            "'--study-name'",
            "expected a name",
        ),
    ]
    results = run_batch([argv for argv, _, _ in cases])
    for (argv, option, needle), done in zip(cases, results):
        assert done.returncode == 2, (argv, done.stderr)
        assert done.stderr.count("\n") == 1 and done.stderr.startswith("error:"), (argv, done.stderr)
        assert option in done.stderr and needle in done.stderr, (argv, done.stderr)
    assert contents(mine) == before and not (mine / RUN_MARKER).exists() and not (mine / LOCK_FILE).exists()
    assert not (tmp_path / "escaped").exists() and not bundle.exists()
    assert not (tmp_path / "nosuch.db").exists()


def test_a_resumed_train_workers_with_another_algo_seed_or_config_is_refused_naming_the_option(tmp_path):
    from tests.helpers import TINY_CONFIG

    tiny = tmp_path / "tiny.yml"
    tiny.write_text(TINY_CONFIG)
    other = tmp_path / "other.yml"
    other.write_text(TINY_CONFIG.replace("  batch_size: 16\n", "  batch_size: 16\n  learning_rate: 0.01\n"))
    out = tmp_path / "w"
    base = ["train-workers", "--no-progress", "--workers", "goal", "--algo", "goal=ddpg", "--eval-freq", "0"]
    first = [*base, "--config", str(tiny), "--timesteps", "150", "--out", str(out)]
    resumed = ["train-workers", "--no-progress", "--workers", "goal", "--eval-freq", "0", "--resume"]
    cases = [
        (
            [*resumed, "--algo", "goal=td3", "--config", str(tiny), "--timesteps", "300"],
            "--algo of 'goal' was 'ddpg'",
        ),
        (
            [*resumed, "--algo", "goal=ddpg", "--config", str(tiny), "--seed", "5", "--timesteps", "300"],
            "--seed was 0",
        ),
        (
            [*resumed, "--algo", "goal=ddpg", "--config", str(other), "--timesteps", "300"],
            "learning_rate was",
        ),
    ]
    results = run_batch([first, *[[*argv, "--out", str(out)] for argv, _ in cases]])
    assert results[0].returncode == 0, results[0].stderr
    manifest = (out / "workers" / "manifest.json").read_bytes()
    for (argv, needle), done in zip(cases, results[1:]):
        assert done.returncode == 2 and needle in done.stderr, (argv, done.stderr)
        assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr
    assert (out / "workers" / "manifest.json").read_bytes() == manifest


@pytest.mark.parametrize(
    ("reward_terms", "needle"),
    [
        ({"goal": {"goal": float("nan")}}, "reward_terms.goal.goal: expected a finite weight"),
        ({"goal": {"goal": {"deeper": 1}}}, "reward_terms.goal.goal: expected a finite weight"),
        ({"nobody": "goal"}, "'nobody' is not one of the bundle's workers"),
        ({"goal": "../goal"}, "reward_terms.goal: expected a term name"),
        ({"goal": {"goal": 0.0}}, "positive sum"),
    ],
)
def test_a_bundles_reward_terms_are_checked_when_read(reward_terms, needle):
    from sb3_hddpg.hierarchy.selection import check_selection_settings

    with pytest.raises(LimitError, match=needle):
        check_selection_settings({"reward_terms": reward_terms}, ["goal", "avoid"], "b.zip: selection")


@pytest.mark.parametrize("value", [5e-324, -1e-300, 1e-10])
def test_env_settings_an_env_divides_by_are_normal_sized(value):
    from sb3_hddpg.artifacts.values import check_env_kwargs

    with pytest.raises(LimitError, match="sensor_range: expected 0 or a magnitude of at least 1e-09"):
        check_env_kwargs("hddpg/SnakeReach-v0", {"sensor_range": value}, "b.zip: env_kwargs")


def test_a_trial_stopped_by_the_user_is_not_reported_with_a_traceback():
    import logging

    import optuna

    from hddpg_zoo.tuning.study import _quiet_interruptions
    from sb3_hddpg.training.agent import TrainingInterrupted

    records: list[logging.LogRecord] = []
    collect = logging.Handler()
    collect.emit = records.append  # type: ignore[method-assign]
    logging.getLogger("optuna").addHandler(collect)

    def interrupted(trial: optuna.Trial) -> float:
        raise TrainingInterrupted("trial: interrupted at 10 of 100 steps")

    def broken(trial: optuna.Trial) -> float:
        raise ValueError("a real failure")

    try:
        study = optuna.create_study()
        with _quiet_interruptions(), pytest.raises(TrainingInterrupted):
            study.optimize(interrupted, n_trials=1)
        assert not [r for r in records if r.exc_info]
        with _quiet_interruptions(), pytest.raises(ValueError):
            study.optimize(broken, n_trials=1)
        assert [r for r in records if r.exc_info]  # a real failure still comes with its traceback
    finally:
        logging.getLogger("optuna").removeHandler(collect)


def test_a_write_that_cannot_start_names_the_file_asked_for_not_a_temporary(tmp_path):
    from sb3_hddpg.artifacts.io import atomic_write_json

    (tmp_path / "a-file").write_text("x")
    target = tmp_path / "a-file" / "summary.json"
    with pytest.raises(OSError) as raised:
        atomic_write_json(target, {"a": 1})
    assert f"Cannot write {str(target)!r}" in str(raised.value) and ".tmp" not in str(raised.value)

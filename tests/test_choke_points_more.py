"""
The third pass's leftovers, each tested at its choke point (docs/ROBUSTNESS.md, "third pass"):

1. every read of a file inside a run folder: ``artifacts/containment.py`` through
   ``artifacts/limits.py::read_file_bytes`` / ``check_run_file``;
2. a bundle's reward terms against the env's declared terms: ``hierarchy/bundle.py::checked_settings``;
3. the library's episode and frame counts: ``limits.COUNTS`` in ``evaluate`` and ``record_video``;
4. ``tune`` stopped by SIGTERM in a trial: exit 143, one line, its study still readable;
5. a resumed worker killed before its manifest entry: its checkpoint's record through ``check_resumed_agent``.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import signal
import sqlite3
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import gymnasium as gym
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import sb3_hddpg  # noqa: F401  (registers the ids)
from sb3_hddpg.artifacts.containment import RUN_MARKER
from sb3_hddpg.artifacts.limits import LimitError, check_run_file, read_file_bytes, read_json_file
from sb3_hddpg.hierarchy.bundle import BundleError
from sb3_hddpg.hierarchy.hierarchy import Hierarchy
from sb3_hddpg.hierarchy.loading import load_policy
from tests.cli_batch import run_batch
from tests.helpers import ConstantWorker

REPO = Path(__file__).resolve().parents[1]
RUN = REPO / "docs" / "results" / "models" / "seed-0"
HIERARCHY = RUN / "hddpg" / "hierarchy.zip"


def run_folder(tmp_path: Path) -> Path:
    """A run folder (its marker) holding a record, a model and a manifest, and a secret outside it."""
    run = tmp_path / "run"
    (run / "records" / "hddpg").mkdir(parents=True)
    (run / RUN_MARKER).write_text("{}")
    (run / "records" / "hddpg" / "seed-0.json").write_text('{"status": "done"}')
    (tmp_path / "secret.json").write_text('{"secret": 1}')
    return run


# ------------------------------------------------------------------ 1. reads inside a run folder
@pytest.mark.parametrize("where", ["record", "folder", "model"])
def test_every_read_inside_a_run_folder_refuses_a_link_leading_outside(tmp_path, where):
    run = run_folder(tmp_path)
    if where == "record":
        target = run / "records" / "hddpg" / "seed-1.json"
        target.symlink_to(tmp_path / "secret.json")
    elif where == "folder":
        (run / "records" / "flat").symlink_to(tmp_path)
        target = run / "records" / "flat" / "secret.json"
    else:
        (run / "hddpg").mkdir()
        target = run / "hddpg" / "hierarchy.zip"
        target.symlink_to(HIERARCHY)
    with pytest.raises(LimitError, match="leads outside it"):
        read_file_bytes(target, 1 << 20)
    with pytest.raises(LimitError, match="leads outside it"):
        check_run_file(target)
    if where == "model":
        with pytest.raises(LimitError, match="leads outside it"):
            load_policy(target)
        with pytest.raises(BundleError, match="leads outside it"):
            Hierarchy.load(target)


def test_a_link_that_stays_inside_and_files_outside_run_folders_are_read(tmp_path):
    run = run_folder(tmp_path)
    inner = run / "records" / "hddpg" / "seed-1.json"
    inner.symlink_to(run / "records" / "hddpg" / "seed-0.json")
    assert read_json_file(inner) == {"status": "done"}
    # the user's own link, outside any run folder, is the user's choice
    mine = tmp_path / "mine.json"
    mine.symlink_to(tmp_path / "secret.json")
    assert read_json_file(mine) == {"secret": 1}


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    depth=st.integers(0, 3),
    marker=st.sampled_from([RUN_MARKER, "benchmark.json", "workers/manifest.json", None]),
    outside=st.booleans(),
)
def test_run_folder_links_property(tmp_path_factory, depth, marker, outside):
    root = tmp_path_factory.mktemp("p")
    run = root / "run"
    folder = run.joinpath(*[f"d{i}" for i in range(depth)])
    folder.mkdir(parents=True)
    if marker is not None:
        (run / marker).parent.mkdir(parents=True, exist_ok=True)
        (run / marker).write_text("{}")
    (root / "secret").write_text("s")
    (run / "inside").write_text("i")
    (folder / "link").symlink_to(root / "secret" if outside else run / "inside")
    if marker is not None and outside:
        with pytest.raises(LimitError, match="leads outside it"):
            read_file_bytes(folder / "link", 10)
    else:
        assert read_file_bytes(folder / "link", 10) in (b"s", b"i")


def test_report_of_a_run_folder_with_a_linked_record_exits_2_naming_it(tmp_path):
    run = tmp_path / "run"
    shutil.copytree(REPO / "docs" / "results" / "record", run, ignore=shutil.ignore_patterns("*.png"))
    record = sorted((run / "records").glob("*/seed-0.json"))[0]
    record.unlink()
    record.symlink_to(tmp_path / "secret.json")
    (tmp_path / "secret.json").write_text("{}")
    done = run_batch([["report", str(run)]])[0]
    assert done.returncode == 2 and "leads outside it" in done.stderr and str(record) in done.stderr
    assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr


# ------------------------------------------------------------------ 2. a bundle's reward terms
def with_reward_terms(reward_terms: object) -> io.BytesIO:
    """The shipped hierarchy with its selection's ``reward_terms`` replaced."""
    out = io.BytesIO()
    with zipfile.ZipFile(HIERARCHY) as src, zipfile.ZipFile(out, "w") as dst:
        for info in src.infolist():
            data = src.read(info)
            if info.filename == "manifest.json":
                manifest = json.loads(data)
                manifest["selection"]["reward_terms"] = reward_terms
                data = json.dumps(manifest).encode()
            dst.writestr(info.filename, data)
    out.seek(0)
    return out


@pytest.mark.parametrize(
    ("reward_terms", "needle"),
    [
        ({"goal": "speed"}, "selection.reward_terms.goal: 'speed' is not one of the env's reward terms"),
        ({"goal": {"goal": 1.0, "nosuch": 1.0}}, "'nosuch' is not one of the env's reward terms"),
        ({"goal": {"goal": float("nan")}}, "reward_terms.goal.goal: expected a finite weight"),
        ({"goal": {"goal": float("inf")}}, "reward_terms.goal.goal: expected a finite weight"),
        ({"goal": {"goal": {"deeper": 1}}}, "reward_terms.goal.goal: expected a finite weight"),
    ],
)
def test_a_bundles_reward_terms_are_the_envs_declared_terms_when_loaded(reward_terms, needle):
    with pytest.raises(BundleError, match=needle.replace("(", r"\(")):
        Hierarchy.load(with_reward_terms(reward_terms))


def test_a_worker_without_a_reward_entry_must_be_named_after_a_term():
    from sb3_hddpg.hierarchy.selection import check_reward_terms

    with pytest.raises(LimitError, match=r"no entry for worker 'reach'.*'reach' is not one of the env's"):
        check_reward_terms({}, ["goal", "reach"], ["goal", "avoid"], "b.zip: selection.reward_terms")
    check_reward_terms({"reach": {"goal": 1.0}}, ["goal", "reach"], ["goal", "avoid"], "b.zip")
    Hierarchy.load(with_reward_terms({}))  # the shipped bundle's workers are named after terms


# ------------------------------------------------------------------ 3. the library's counts
@pytest.mark.parametrize("count", [0, -1, 10_001, 10**9, 2.5, True, "3"])
def test_the_librarys_evaluate_and_record_video_take_the_clis_bounds(tmp_path, count):
    from hddpg_zoo.media.video import record_video
    from sb3_hddpg.evaluation import evaluate

    env = gym.make("hddpg/SnakeReach-v0")
    try:
        with pytest.raises(ValueError, match=r"n_episodes: expected an integer in \[1, 10000\]"):
            evaluate(ConstantWorker(env.action_space.sample() * 0), env, n_episodes=count)
        with pytest.raises(ValueError, match=r"episodes: expected an integer in \[1, 10000\]"):
            record_video(
                ConstantWorker(env.action_space.sample() * 0), env, tmp_path / "v.gif", episodes=count
            )
        with pytest.raises(ValueError, match=r"max_frames: expected an integer in \[1, 100000\]"):
            record_video(
                ConstantWorker(env.action_space.sample() * 0), env, tmp_path / "v.gif", max_frames=10**9
            )
    finally:
        env.close()
    assert not (tmp_path / "v.gif").exists()


# ------------------------------------------------------------------ 5. a worker killed before its entry
def test_a_worker_killed_before_its_manifest_entry_is_checked_against_its_checkpoint(tmp_path):
    from tests.helpers import TINY_CONFIG

    tiny = tmp_path / "tiny.yml"
    tiny.write_text(TINY_CONFIG)
    other = tmp_path / "other.yml"
    other.write_text(TINY_CONFIG.replace("  batch_size: 16\n", "  batch_size: 16\n  learning_rate: 0.01\n"))
    out = tmp_path / "w"
    common = ["train-workers", "--no-progress", "--workers", "goal", "--eval-freq", "0", "--out", str(out)]
    first = [*common, "--algo", "goal=ddpg", "--config", str(tiny), "--timesteps", "150"]
    first += ["--checkpoint-freq", "120", "--keep-checkpoints"]
    resumed = [*common, "--resume", "--timesteps", "300"]
    cases = [
        ([*resumed, "--algo", "goal=td3", "--config", str(tiny)], "--algo of 'goal' was 'ddpg'"),
        ([*resumed, "--algo", "goal=ddpg", "--config", str(tiny), "--seed", "5"], "--seed was 0"),
        ([*resumed, "--algo", "goal=ddpg", "--config", str(other)], "learning_rate was"),
    ]
    done = run_batch([first])[0]
    assert done.returncode == 0, done.stderr
    # the state of a run killed after its checkpoint, before its first manifest entry
    (out / "workers" / "manifest.json").unlink()
    (out / "workers" / "goal.zip").unlink()
    state = json.loads((out / "checkpoints" / "goal" / "state.json").read_text())
    assert state["algo"] == "ddpg" and state["seed"] == 0 and "block" in state["config"]
    results = run_batch([argv for argv, _ in cases])
    for (argv, needle), result in zip(cases, results):
        assert result.returncode == 2 and needle in result.stderr, (argv, result.stderr)
        assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr
    assert not (out / "workers" / "goal.zip").exists()


# ------------------------------------------------------------------ 4. tune under SIGTERM
def test_tune_stopped_by_sigterm_in_a_trial_exits_143_in_one_line_and_keeps_its_study(tmp_path):
    from tests.helpers import TINY_CONFIG

    tiny = tmp_path / "tiny.yml"
    tiny.write_text(TINY_CONFIG)
    out = tmp_path / "t"
    argv = ["tune", "--level", "flat", "--n-trials", "3", "--timesteps", "6000", "--n-evaluations", "3"]
    argv += ["--eval-episodes", "1", "--config", str(tiny), "--out", str(out)]
    env = {**os.environ, "PYTHONPATH": str(REPO), "COLUMNS": "300"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "sb3_hddpg", *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        # a trial has started once its first evaluation is written (its scratch folder's curve)
        deadline = time.monotonic() + 600
        while not list(out.glob("trials/*/evaluations/*.json")) and time.monotonic() < deadline:
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.5)
        proc.send_signal(signal.SIGTERM)
        out_text, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 143, err  # 128 + SIGTERM
    # stderr: only Optuna's own progress lines ("[I ...] A new study created"), no trial failure, no traceback
    assert [line for line in err.splitlines() if line.strip() and not line.startswith("[I ")] == [], err
    stopped = out_text.strip().splitlines()[-1]
    assert stopped.startswith("tuning interrupted") and "re-run the same command" in stopped, out_text
    assert "Traceback" not in out_text + err and "--resume" not in out_text + err
    with sqlite3.connect(f"file:{out / 'study.db'}?mode=ro", uri=True) as db:
        states = [row[0] for row in db.execute("SELECT state FROM trials")]
    assert states and "RUNNING" not in states, states


# ------------------------------------------------------------------ held-out variants the probe found
def test_held_out_variants_end_in_one_line_naming_what_is_at_fault(tmp_path):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "README.md").write_text("# mine\n")
    fifo = tmp_path / "c.yml"
    os.mkfifo(fifo)
    cases = [
        (
            ["tune", "--level", "flat", "--n-trials", "1", "--out", str(mine)],
            "'--out'",
            "this tool did not write",
        ),
        (["tune", "--level", "flat", "--eval-episodes", "1000000"], "'--eval-episodes'", "[1, 10000]"),
        (["tune", "--level", "flat", "--n-evaluations", "1000000000"], "'--n-evaluations'", "[1, 10000]"),
        (
            ["record", str(HIERARCHY), "--max-steps", "1000000000", "--out", str(tmp_path / "r.gif")],
            "",
            "100000",
        ),
        (["tune", "--level", "flat", "--config", str(fifo)], "'--config'", "FIFO, socket or device"),
        (["train-flat", "--config", "/dev/zero", "--out", str(tmp_path / "f")], "'--config'", "FIFO, socket"),
    ]
    results = run_batch([argv for argv, _, _ in cases])
    for (argv, option, needle), done in zip(cases, results):
        assert done.returncode == 2 and option in done.stderr and needle in done.stderr, (argv, done.stderr)
        assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr
    assert sorted(p.name for p in mine.iterdir()) == ["README.md"]
    assert not (tmp_path / "f").exists() and not (tmp_path / "r.gif").exists()


@pytest.mark.parametrize(
    ("field", "value", "needle"),
    [
        ("seed", -5, "seed: expected an integer in [0, 4294967295]"),
        ("seed", 2.5, "seed: expected an integer"),
        (
            "env_kwargs",
            {"sensor_range": 1e-300},
            "env_kwargs.'sensor_range': expected 0 or a finite magnitude",
        ),
        ("env_kwargs", {"dt": float("inf")}, "env_kwargs.'dt': expected 0 or a finite magnitude"),
    ],
)
def test_a_workers_manifests_seed_and_env_numbers_are_checked_when_read(field, value, needle):
    from sb3_hddpg.artifacts.records.models import models_manifest_from_json

    manifest = json.loads((RUN / "workers" / "manifest.json").read_text())
    manifest["workers"]["goal"][field] = value
    with pytest.raises(LimitError, match=needle.replace("[", r"\[").replace("]", r"\]")):
        models_manifest_from_json(manifest, "workers", "m.json")


def test_sigterm_to_any_command_ends_it_in_one_line_with_143(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(REPO), "SDL_VIDEODRIVER": "dummy"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "sb3_hddpg", "rollout", "--episodes", "10000"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        time.sleep(12)  # started and rolling out (the command loads torch and SB3 first)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 143 and err.strip() == "error: interrupted", err

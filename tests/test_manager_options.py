"""``ManagerOptions`` is the one record of a manager's options: the functions that take them as keywords agree."""

from __future__ import annotations

import inspect
from dataclasses import fields

import pytest

from sb3_hddpg.hierarchy.hierarchy import Hierarchy
from sb3_hddpg.training.manager import train_manager
from sb3_hddpg.training.manager_setup import (
    MANAGER_OPTION_NAMES,
    ManagerOptions,
    manager_options,
    prepare_manager,
    setup_manager,
)
from sb3_hddpg.training.run_options import RUN_OPTION_NAMES


def test_prepare_manager_and_train_manager_take_one_options_record():
    assert list(inspect.signature(prepare_manager).parameters) == ["workers_dir", "options", "option_changes"]
    assert list(inspect.signature(train_manager).parameters) == [
        "workers_dir", "out_dir", "options", "run", "callback", "changes"
    ]  # fmt: skip
    # Keywords are the record's fields over the record given; None keeps the field, whose default is the record's.
    assert manager_options(None, {"prefer": "goal", "bias": None}, "f") == ManagerOptions(prefer="goal")
    assert manager_options(ManagerOptions(algo="sac"), {"gamma": 0.9}, "f") == ManagerOptions(
        algo="sac", gamma=0.9
    )
    with pytest.raises(TypeError, match="prepare_manager\\(\\) got an unexpected keyword argument 'prefr'"):
        prepare_manager("no-workers-here", prefr="goal")
    # train_manager sends each keyword to the record that has the field: the two share none.
    assert not set(MANAGER_OPTION_NAMES) & RUN_OPTION_NAMES
    assert {f.name for f in fields(ManagerOptions) if f.default is not None} >= {"bias", "algo", "trusted"}


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (
            ManagerOptions(worker_names="goal"),
            "Expected a sequence of worker names, actually the string 'goal'",
        ),
        (ManagerOptions(algo="nope"), "Unknown manager algorithm 'nope'"),
        (ManagerOptions(gamma=0.0), r"manager's gamma in \(0, 1\], actually: 0.0"),
        (ManagerOptions(gamma=1.5), r"manager's gamma in \(0, 1\], actually: 1.5"),
        (ManagerOptions(gamma=float("nan")), r"manager's gamma in \(0, 1\], actually: nan"),
        (ManagerOptions(gamma=True), r"manager's gamma in \(0, 1\], actually: True"),
    ],
)
def test_setup_manager_refuses_bad_options_before_loading_anything(tmp_path, options, message):
    with pytest.raises(ValueError, match=message):
        setup_manager(tmp_path / "no-workers-here", options)


def test_a_managers_gamma_replaces_its_blocks_and_its_saved_model_keeps_it(tmp_path):
    from sb3_hddpg.training.workers import train_workers
    from tests.cli_batch import run_batch

    train_workers(tmp_path / "w", seed=2, timesteps=100, eval_freq=0, eval_episodes=1)
    common = ["train-manager", "--workers", str(tmp_path / "w"), "--algo", "dqn", "--option-steps", "1"]
    # Both command lines in one interpreter (tests/cli_batch.py), each with its own exit code and output.
    refused, done = run_batch(
        [
            [*common, "--gamma", "0", "--out", str(tmp_path / "refused")],
            [*common, "--gamma", "0.97", "--timesteps", "60", "--eval-freq", "60", "--eval-episodes", "1",
             "--no-progress", "--out", str(tmp_path / "m")],
        ]
    )  # fmt: skip
    output = refused.stdout + refused.stderr
    assert refused.returncode == 2 and "--gamma" in output and "Traceback" not in output
    assert not (tmp_path / "refused").exists()
    assert done.returncode == 0, done.stdout + done.stderr
    bundle = Hierarchy.load(tmp_path / "m" / "hierarchy.zip")
    # The model keeps the discount it trained with; the bundle's config is the block as written.
    assert bundle.manager.gamma == pytest.approx(0.97) and bundle.config.option_steps == 1
    assert bundle.metadata["config"]["gamma"] == pytest.approx(0.9)

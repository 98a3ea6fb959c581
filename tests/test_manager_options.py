"""``ManagerOptions`` is the one record of a manager's options: the functions that take them as keywords agree."""

from __future__ import annotations

import inspect
from dataclasses import fields

import pytest

from sb3_hddpg.training.manager import train_manager
from sb3_hddpg.training.manager_setup import (
    MANAGER_OPTION_NAMES,
    ManagerOptions,
    prepare_manager,
    setup_manager,
)


def test_prepare_manager_takes_exactly_the_records_fields_and_leaves_their_defaults_to_it():
    parameters = list(inspect.signature(prepare_manager).parameters.values())[1:]
    assert [p.name for p in parameters] == list(MANAGER_OPTION_NAMES)
    # Every keyword left out is the record's default: a default is spelled in one place only.
    assert {p.name: p.default for p in parameters} == dict.fromkeys(MANAGER_OPTION_NAMES)
    train = inspect.signature(train_manager).parameters
    assert all(train[name].default is None for name in MANAGER_OPTION_NAMES)
    assert {f.name for f in fields(ManagerOptions) if f.default is not None} >= {"bias", "algo", "trusted"}


def test_train_manager_takes_the_records_fields_after_its_folders():
    names = list(inspect.signature(train_manager).parameters)
    assert names[2 : 2 + len(MANAGER_OPTION_NAMES)] == list(MANAGER_OPTION_NAMES)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (
            ManagerOptions(worker_names="goal"),
            "Expected a sequence of worker names, actually the string 'goal'",
        ),
        (ManagerOptions(algo="nope"), "Unknown manager algorithm 'nope'"),
    ],
)
def test_setup_manager_refuses_bad_options_before_loading_anything(tmp_path, options, message):
    with pytest.raises(ValueError, match=message):
        setup_manager(tmp_path / "no-workers-here", options)

"""Loaders register by entry point: the core imports no baseline, and only code (never a file) adds a loader."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from test_layering import imports_of, modules

from sb3_hddpg.baselines.random import RandomPolicy
from sb3_hddpg.hierarchy.loading import load_policy
from sb3_hddpg.policy_loaders import POLICY_LOADERS, LoadedPolicy, register_policy_loader

ENV_ID = "hddpg/SnakeReach-v0"


def test_the_core_imports_no_baseline_and_no_controller():
    core = [m for m in modules() if m.startswith(("sb3_hddpg.hierarchy", "sb3_hddpg.artifacts"))]
    reaching = {
        module: sorted(
            i
            for i in imports_of(module)
            if i.startswith(("sb3_hddpg.baselines", "sb3_hddpg.envs.snake.controllers"))
        )
        for module in core
    }
    assert not {module: found for module, found in reaching.items() if found}


def test_a_fresh_process_loads_the_builtin_loaders_on_first_use():
    script = (
        "import sys; from sb3_hddpg.hierarchy.loading import load_policy;"
        "assert 'sb3_hddpg.baselines.reference' not in sys.modules;"
        f"p = load_policy('random', env_id={ENV_ID!r}); assert type(p.policy).__name__ == 'RandomPolicy';"
        "assert 'sb3_hddpg.baselines.reference' in sys.modules"
    )
    subprocess.run([sys.executable, "-c", script], check=True)


def _constant_loader(path: Path, trusted: bool, allowed_env_ids) -> LoadedPolicy:
    env = gym.make(ENV_ID)
    return LoadedPolicy(
        RandomPolicy(env.action_space, seed=int(path.read_text())), ENV_ID, {}, "constant", path.stem
    )


@pytest.fixture
def constant_kind():
    register_policy_loader("constant", _constant_loader, suffixes=(".const",), names=("zero",))
    try:
        yield
    finally:
        POLICY_LOADERS.pop("constant")


def test_a_registered_loader_opens_its_files(constant_kind, tmp_path):
    (tmp_path / "mine.const").write_text("3")
    loaded = load_policy(tmp_path / "mine.const")
    assert loaded.kind == "constant" and loaded.name == "mine"
    obs = gym.make(ENV_ID).reset(seed=0)[0]
    np.testing.assert_array_equal(
        loaded.policy.predict(obs)[0], RandomPolicy(gym.make(ENV_ID).action_space, 3).predict(obs)[0]
    )


def test_claims_and_entry_points_are_checked_by_name(constant_kind):
    for kwargs, message in (
        ({"kind": "constant", "entry_point": _constant_loader}, "already registered"),
        ({"kind": "other", "entry_point": _constant_loader, "suffixes": (".json",)}, "'.json' already has"),
        ({"kind": "other", "entry_point": _constant_loader, "names": ("random",)}, "'random' already has"),
        ({"kind": "other", "entry_point": _constant_loader, "suffixes": ("json",)}, "such as '.json'"),
        ({"kind": "other", "entry_point": "os.system"}, "'module:function'"),
    ):
        with pytest.raises(ValueError, match=message):
            register_policy_loader(**kwargs)
    assert "other" not in POLICY_LOADERS


def test_a_path_that_looks_like_an_entry_point_is_only_a_path(tmp_path):
    # A name is looked up among registered names only: nothing a user or a file writes is imported.
    with pytest.raises(FileNotFoundError, match="No such file"):
        load_policy("sb3_hddpg.baselines.ham:load_ham")

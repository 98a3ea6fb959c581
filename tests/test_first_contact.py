"""What a new user meets first: a quick, ordered ``--help``, one torch thread where the library trains, plain words."""

from __future__ import annotations

import importlib
import os
import stat
import subprocess
import sys

import pytest

from sb3_hddpg.cli.app import COMMANDS, command_module
from sb3_hddpg.envs.headless import private_runtime_dir
from sb3_hddpg.metric_labels import manager_warnings
from tests.cli_runner import REPO

#: Modules that take seconds to import: ``hddpg-cli --help`` must parse before any of them loads.
HEAVY = ("torch", "stable_baselines3", "sb3_contrib", "jax", "sbx", "optuna", "matplotlib", "ray")


def _python(code: str, **env: str) -> subprocess.CompletedProcess:
    variables = {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    variables.update(PYTHONPATH=str(REPO), **env)
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=variables
    )


def test_help_imports_no_learning_library_and_lists_every_command_in_order_whole():
    done = _python(
        "import sys\n"
        "from sb3_hddpg.cli import main\n"
        "try:\n    main(['--help'])\nexcept SystemExit as end:\n    assert end.code == 0, end.code\n"
        f"print('HEAVY', sorted(m for m in {HEAVY!r} if m in sys.modules))",
        COLUMNS="80",
    )
    assert done.returncode == 0, done.stderr
    assert "HEAVY []" in done.stdout, done.stdout.splitlines()[-1]
    commands = done.stdout.split("Commands:")[1].split("HEAVY")[0]
    listed = [line.split()[0] for line in commands.splitlines() if line[:3].strip()]
    assert listed == list(COMMANDS)
    # Every command's line whole: wrapped if it must be, never cut with an ellipsis.
    assert "..." not in commands
    for _, line in COMMANDS.values():
        assert " ".join(line.split()) in " ".join(done.stdout.split())


def test_the_command_table_names_exactly_the_registered_commands():
    import typer

    from sb3_hddpg.cli.app import app

    for name in COMMANDS:
        importlib.import_module(command_module(name))
    registered = {
        name: command.callback.__module__ for name, command in typer.main.get_command(app).commands.items()
    }
    assert {name: command_module(name) for name in COMMANDS} == registered
    # The library's commands are its own modules, the harness's are hddpg_zoo's.
    assert command_module("train-workers") == "sb3_hddpg.cli.train"
    assert command_module("benchmark") == "hddpg_zoo.cli.benchmark"


def test_a_command_runs_from_the_lazy_table_and_an_unknown_one_is_one_error_line(tmp_path):
    done = _python("from sb3_hddpg.cli import main; main(['evaluate'])")
    assert done.returncode == 2 and done.stderr.startswith("error: Missing argument 'path'."), done.stderr
    unknown = _python("from sb3_hddpg.cli import main; main(['evaluat'])")
    assert unknown.returncode == 2 and unknown.stderr.startswith("error: No such command 'evaluat'")


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="torch's default is one thread on one CPU")
def test_the_managers_env_sets_one_torch_thread_unless_the_user_chose():
    code = (
        "import torch, gymnasium as gym\n"
        "{before}\n"
        "from sb3_hddpg import WorkerSelectionWrapper\n"
        "from sb3_hddpg.baselines.random import RandomPolicy\n"
        "env = gym.make('hddpg/SnakeReach-v0')\n"
        "WorkerSelectionWrapper(env, {{'goal': RandomPolicy(env.action_space), "
        "'avoid': RandomPolicy(env.action_space)}})\n"
        "print('THREADS', torch.get_num_threads())"
    )
    default = _python(code.format(before=""))
    assert "THREADS 1" in default.stdout, default.stderr[-2000:]
    cpus = len(os.sched_getaffinity(0))
    # A user who chose keeps the choice: by the environment, or by torch before the env is built.
    chosen = _python(code.format(before=""), OMP_NUM_THREADS=str(cpus))
    assert f"THREADS {cpus}" in chosen.stdout, chosen.stderr[-2000:]
    if cpus > 2:
        set_by_hand = _python(code.format(before="torch.set_num_threads(2)"))
        assert "THREADS 2" in set_by_hand.stdout


def test_a_collapsed_or_saturated_manager_is_said_in_words():
    collapsed = manager_warnings({"selection_rate": {"avoid": 0.0, "goal": 1.0}, "action_saturation": 1.0})
    assert collapsed[0] == "the manager chose goal on 100 % of steps: it acts as the goal worker alone"
    assert collapsed[1].startswith("100 % of the manager's outputs are pinned at ±1")
    assert manager_warnings({"selection_rate": {"avoid": 0.3, "goal": 0.7}, "action_saturation": 0.2}) == []
    # An index (a DQN manager) has no saturation; a worker alone is no manager.
    assert manager_warnings({"selection_rate": {"avoid": 0.4, "goal": 0.6}}) == []
    assert manager_warnings({"action_saturation": 1.0}) == []


def test_rendering_gets_a_private_runtime_folder_only_without_a_usable_one(monkeypatch, tmp_path):
    monkeypatch.delenv("XDG_RUNTIME_DIR", raising=False)
    made = private_runtime_dir()
    assert made is not None and os.environ["XDG_RUNTIME_DIR"] == made
    assert stat.S_IMODE(os.stat(made).st_mode) == 0o700
    own = tmp_path / "runtime"
    own.mkdir(mode=0o700)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(own))
    assert private_runtime_dir() is None and os.environ["XDG_RUNTIME_DIR"] == str(own)
    os.rmdir(made)

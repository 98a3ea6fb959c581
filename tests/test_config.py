"""Config parsing: RL Zoo's format, safe policy_kwargs, clear errors."""

import os
import subprocess
import sys

import pytest
from stable_baselines3 import DDPG
from stable_baselines3.common.utils import LinearSchedule
from torch import nn

from sb3_hddpg.training.config import (
    DEFAULT_CONFIG,
    Hyperparams,
    load_config_file,
    load_hyperparams,
    parse_block,
)
from sb3_hddpg.training.config_values import ConfigError, parse_policy_kwargs
from tests.cli_runner import REPO


def test_bundled_config_has_every_env_and_the_manager():
    config = load_config_file(DEFAULT_CONFIG)
    assert {"default", "hddpg/SnakeGoal-v0", "hddpg/SnakeAvoid-v0", "hddpg/SnakeReach-v0", "manager"} <= set(
        config
    )
    goal = load_hyperparams("hddpg/SnakeGoal-v0", DDPG)
    assert goal.algo_kwargs["policy_kwargs"] == {"net_arch": [256, 256]}  # the goal block's own networks
    avoid = load_hyperparams("hddpg/SnakeAvoid-v0", DDPG)
    # The avoid block keeps the shared values, through `<<: *ddpg`.
    assert avoid.algo_kwargs["policy_kwargs"] == {"net_arch": [64, 64]}
    assert goal.noise_type == "normal" and goal.n_timesteps > 0
    manager = load_hyperparams("manager", DDPG, manager=True)
    # The bundled manager block is the confirmed pick of its study: sampled selection over 8-step options.
    assert manager.wrapper_kwargs["selection"] == "mix" and manager.wrapper_kwargs["option_steps"] == 8
    assert manager.n_timesteps * manager.wrapper_kwargs["option_steps"] == 40_000  # the manager's env steps


def test_env_block_replaces_default_like_rl_zoo(tmp_path):
    path = tmp_path / "c.yml"
    path.write_text("default:\n  n_timesteps: 10\n  gamma: 0.5\nhddpg/SnakeGoal-v0:\n  n_timesteps: 20\n")
    assert load_hyperparams("hddpg/SnakeGoal-v0", DDPG, path).algo_kwargs == {}
    assert load_hyperparams("hddpg/SnakeAvoid-v0", DDPG, path).algo_kwargs == {"gamma": 0.5}


def test_policy_kwargs_round_trip_and_safety():
    kwargs = parse_policy_kwargs("dict(net_arch=[400, 300], activation_fn=nn.Tanh)")
    assert kwargs == {"net_arch": [400, 300], "activation_fn": nn.Tanh}
    assert parse_policy_kwargs("dict(activation_fn=torch.nn.Tanh, net_arch=[400, 300])") == kwargs
    assert parse_policy_kwargs("dict(net_arch=dict(pi=[64], qf=[400, 300]))")["net_arch"]["qf"] == [400, 300]
    for hostile in (
        "__import__('os').system('true')",
        "dict(a=open('x'))",
        "dict(activation_fn=nn.Module)",
        "[1, 2]",
    ):
        with pytest.raises(ConfigError):
            parse_policy_kwargs(hostile)


@pytest.mark.parametrize(
    ("block", "message"),
    [
        ({"n_timesteps": 10, "lr": 0.1}, r"Unknown keys in .*\['lr'\]"),
        ({"gamma": 0.9}, "Missing key 'n_timesteps'"),
        ({"n_timesteps": 0}, "n_timesteps"),
        ({"n_timesteps": 10, "noise_type": "pink"}, "noise_type"),
        ({"n_timesteps": 10, "noise_std": -1}, "noise_std"),
        ({"n_timesteps": 10, "policy": "CnnPolicy"}, "MlpPolicy"),
        ({"n_timesteps": 10, "wrapper_kwargs": {}}, "Unknown keys"),
        ({"n_timesteps": 10, "seed": 3}, "Unknown keys"),
        ({"n_timesteps": 10, "learning_rate": "exp_1e-3"}, "schedule 'lin_<initial value in \\(0, 1\\]>'"),
        ({"n_timesteps": 10, "learning_rate": "lin_"}, "actually: 'lin_'"),
        ({"n_timesteps": 10, "learning_rate": "lin_-1e-3"}, "learning_rate"),
        ({"n_timesteps": 10, "learning_rate": "lin_nan"}, "learning_rate"),
        ({"n_timesteps": 10, "gamma": "lin_0.9"}, "gamma"),
        (
            {"n_timesteps": 10, "callback": {"sb3_hddpg.callbacks.ControllerPrior": {"controller": [1]}}},
            "controller",
        ),
    ],
)
def test_bad_blocks(block, message):
    with pytest.raises(ConfigError, match=message):
        parse_block(block, DDPG, source="test")


def test_rl_zoos_linear_schedule():
    # RL Zoo's `lin_<initial>`: from the initial value at the start (progress remaining 1) to 0 at the end,
    # kept as a value that SB3 saves without code; the block as written stays in `raw` for manifests.
    hyperparams = parse_block({"n_timesteps": 10, "learning_rate": "lin_1e-3"}, DDPG, source="test")
    schedule = hyperparams.algo_kwargs["learning_rate"]
    assert isinstance(schedule, LinearSchedule)
    assert [schedule(p) for p in (1.0, 0.25, 0.0)] == pytest.approx([1e-3, 2.5e-4, 0.0])
    assert hyperparams.raw["learning_rate"] == "lin_1e-3"


def test_missing_file_and_bad_yaml(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_config_file(tmp_path / "none.yml")
    (tmp_path / "bad.yml").write_text("a: [1,\n")
    with pytest.raises(ConfigError, match="Invalid YAML"):
        load_config_file(tmp_path / "bad.yml")
    (tmp_path / "list.yml").write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="map env ids"):
        load_config_file(tmp_path / "list.yml")


def test_a_block_without_actor_terms_loads_no_actor_loss_code():
    # Every training asks its block for callbacks: one without an actor term must not import their modules.
    code = (
        "import sys\n"
        "import sb3_hddpg.training.agent\n"
        "from sb3_hddpg.training.config import Hyperparams\n"
        "assert Hyperparams({}, 10).callbacks() == []\n"
        "print(sorted(m for m in ('sb3_hddpg.callbacks.action_penalty', 'sb3_hddpg.callbacks.controller_prior')"
        " if m in sys.modules))\n"
    )
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["[]"]
    assert [type(c).__name__ for c in Hyperparams({}, 10, action_l2=0.1).callbacks()] == ["ActionL2Penalty"]

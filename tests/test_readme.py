"""The README's Python snippet runs as written (budgets lowered), with the project's hyperparameters."""

from __future__ import annotations

import re
import runpy
from pathlib import Path

import numpy as np
import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def readme_snippet(section: str = "## The Python API") -> str:
    """The first ``python`` code block after the heading ``section``."""
    text = README.read_text()
    start = text.index(section)
    match = re.search(r"```python\n(.*?)```", text[start:], flags=re.DOTALL)
    assert match is not None, f"no python block after {section!r}"
    return match.group(1)


def tiny(snippet: str) -> str:
    """The snippet with every training budget and episode count lowered, each substitution checked."""
    snippet, learns = re.subn(r"\.learn\(\s*[\d_]+\s*([,)])", r".learn(300\1", snippet)
    snippet, episodes = re.subn(r"n_episodes=\d+", "n_episodes=1", snippet)
    assert learns == 2 and episodes == 1, "the README snippet changed shape: update this test's substitutions"
    return snippet


def test_readme_python_snippet_runs_with_the_projects_hyperparameters(tmp_path, monkeypatch, capsys):
    from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise

    from sb3_hddpg.training.config import load_hyperparams

    monkeypatch.chdir(tmp_path)  # the snippet writes hierarchy.zip into the working folder
    script = tmp_path / "snippet.py"
    script.write_text(tiny(readme_snippet()))
    names = runpy.run_path(str(script), run_name="__main__")

    assert (tmp_path / "hierarchy.zip").is_file()
    printed = capsys.readouterr().out
    assert "mean_reach_reward" in printed and "'episodes': 1" in printed
    manager, workers, loaded = names["manager"], names["workers"], names["loaded"]
    # What the CLI trains with (zoo_configs/ddpg.yml), not SB3's DDPG defaults ([400, 300], no noise, gamma 0.99).
    from stable_baselines3 import DDPG

    from sb3_hddpg.callbacks.action_penalty import _MARK
    from sb3_hddpg.goal_relabeling import GoalRelabelingReplayBuffer

    keys = {"manager": "manager", "goal": "hddpg/SnakeGoal-v0", "avoid": "hddpg/SnakeAvoid-v0"}
    for name, model in {"manager": manager, **workers}.items():
        block = load_hyperparams(keys[name], DDPG, manager=name == "manager")
        assert model.actor.net_arch == block.algo_kwargs["policy_kwargs"]["net_arch"]
        assert model.gamma == block.algo_kwargs["gamma"]
        assert model.batch_size == block.algo_kwargs["batch_size"]
        if block.noise_type is None:
            assert model.action_noise is None
        else:  # the workers' Gaussian noise; the manager's Ornstein-Uhlenbeck noise
            noise_class = {"normal": NormalActionNoise, "ornstein-uhlenbeck": OrnsteinUhlenbeckActionNoise}
            assert isinstance(model.action_noise, noise_class[block.noise_type])
            assert model.action_noise._sigma == pytest.approx(
                np.full(model.action_space.shape, block.noise_std)
            )
        # The block's callbacks ran: the action penalty where the block asks for it.
        assert hasattr(model.critic, _MARK) == (block.action_l2 > 0)
    assert isinstance(workers["goal"].replay_buffer, GoalRelabelingReplayBuffer)
    block = load_hyperparams("manager", DDPG, manager=True)
    assert loaded.config.temperature == block.wrapper_kwargs["temperature"]
    assert loaded.config.preferences == {"goal": 1.15, "avoid": 1.0}
    assert loaded.env_id == "hddpg/SnakeReach-v0"

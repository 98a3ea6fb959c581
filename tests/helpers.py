"""Test doubles and small utilities shared by the tests."""

from __future__ import annotations

import signal
import subprocess
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

#: The smallest config that trains every agent (workers, manager, flat) in a few seconds.
TINY_CONFIG = """\
default: &tiny
  n_timesteps: 150
  policy: 'MlpPolicy'
  buffer_size: 1000
  learning_starts: 100
  batch_size: 16
  noise_type: 'normal'
  noise_std: 0.2
  policy_kwargs: "dict(net_arch=[16])"
manager:
  <<: *tiny
"""


class ConstantWorker:
    """A worker that always outputs the same action and records what it was shown."""

    def __init__(
        self,
        action: np.ndarray,
        observation_space: gym.Space | None = None,
        action_space: gym.Space | None = None,
    ):
        self.action = np.asarray(action, dtype=np.float32)
        if observation_space is not None:
            self.observation_space = observation_space
        if action_space is not None:
            self.action_space = action_space
        self.calls = 0
        self.last_obs: np.ndarray | None = None

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ):
        self.calls += 1
        self.last_obs = np.asarray(observation)
        return np.broadcast_to(self.action, (*np.shape(observation)[:-1], self.action.shape[0])).copy(), None


class ActionRecorder(gym.Wrapper):
    """Records every action that reaches the inner env (gymnasium's GenericTestEnv idea, on the real env)."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self.actions: list[np.ndarray] = []

    def step(self, action):
        self.actions.append(np.array(action, dtype=np.float32))
        return self.env.step(action)


def sigterm_once_written(
    process: subprocess.Popen[str], path: Path, what: str, timeout: float = 300, grace: float = 180
) -> tuple[str, str]:
    """
    Wait until ``path`` exists (a run's first evaluation, say), then send ``process`` SIGTERM and collect
    its output; fails naming ``what`` never happened.
    """
    deadline = time.time() + timeout
    while not path.exists() and time.time() < deadline:
        time.sleep(0.5)
    assert path.exists(), f"{what} never happened"
    process.send_signal(signal.SIGTERM)
    return process.communicate(timeout=grace)

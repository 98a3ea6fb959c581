"""Headless MuJoCo: an OpenGL context that cannot be made is one line naming MUJOCO_GL=egl, never a bad manifest."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3 import DDPG

from hddpg_zoo.media.video import record_video
from sb3_hddpg.envs.headless import HeadlessRenderingError, as_rendering_error
from sb3_hddpg.hierarchy.bundle import BundleError
from sb3_hddpg.hierarchy.hierarchy import Hierarchy
from sb3_hddpg.hierarchy.wrapper import WorkerSelectionWrapper

OSMESA = "'NoneType' object has no attribute 'glGetError'"


class GLFWError(Exception):
    """Like glfw's: raised by a render on a machine without a display."""


GLFWError.__module__ = "glfw"


@pytest.mark.parametrize(
    "error",
    [
        GLFWError("(65537) b'The GLFW library is not initialized'"),
        AttributeError(OSMESA),
        RuntimeError("an OpenGL platform library has not been loaded into this process"),
    ],
)
def test_opengl_failures_become_one_line_naming_the_fix(error):
    rendering = as_rendering_error(error)
    assert isinstance(rendering, HeadlessRenderingError)
    message = str(rendering)
    assert "MUJOCO_GL=egl" in message and "\n" not in message and "manifest" not in message


def test_other_errors_stay_what_they_are():
    assert as_rendering_error(AttributeError("'dict' object has no attribute 'items'")) is None
    assert as_rendering_error(ValueError("ILLEGAL value")) is None


def _tiny_bundle(tmp_path):
    env = gym.make("hddpg/SnakeReach-v0")
    small = {"net_arch": [16]}
    workers = {name: DDPG("MlpPolicy", env, policy_kwargs=small, seed=0) for name in ("goal", "avoid")}
    manager = DDPG("MlpPolicy", WorkerSelectionWrapper(env, workers), policy_kwargs=small, seed=0)
    return Hierarchy(manager, workers).save(tmp_path / "hierarchy.zip")


def test_a_bundle_whose_env_cannot_render_is_not_blamed_on_its_manifest(tmp_path, monkeypatch):
    path = _tiny_bundle(tmp_path)

    def no_opengl(*args, **kwargs):
        raise AttributeError(OSMESA)  # MuJoCo's import under MUJOCO_GL=osmesa without OSMesa

    monkeypatch.setattr(gym, "make", no_opengl)
    with pytest.raises(HeadlessRenderingError, match="MUJOCO_GL=egl") as error:
        Hierarchy.load(path)
    assert not isinstance(error.value, BundleError)


class _NoDisplay(gym.Wrapper):
    def render(self):
        raise GLFWError("(65537) b'The GLFW library is not initialized'")


def test_recording_without_a_display_names_the_fix(tmp_path):
    env = _NoDisplay(gym.make("hddpg/SnakeReach-v0", render_mode="rgb_array"))

    class Still:
        def predict(self, obs, state=None, episode_start=None, deterministic=True):
            return np.zeros(env.action_space.shape, dtype=np.float32), None

    with pytest.raises(HeadlessRenderingError, match="MUJOCO_GL=egl"):
        record_video(Still(), env, tmp_path / "out.gif")
    assert not (tmp_path / "out.gif").exists()

"""
Shared test set-up: headless pygame, one torch thread, SB3's stray log folders kept in pytest's, a
checkout-relative path helper, a Ray cluster.
"""

import contextlib
import os
import signal

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")
os.environ.setdefault("MPLBACKEND", "Agg")

import pytest
import torch

torch.set_num_threads(1)

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.fixture(scope="session", autouse=True)
def sb3_logdir(tmp_path_factory: pytest.TempPathFactory) -> None:
    """
    SB3's ``learn`` without a logger of the caller's makes an empty ``SB3-<date>`` folder in the system's
    temporary folder (SB3's ``configure``); a test run made hundreds. ``SB3_LOGDIR`` sends them all,
    subprocesses included, into this session's pytest folder.
    """
    os.environ["SB3_LOGDIR"] = str(tmp_path_factory.mktemp("sb3-logs"))


@pytest.fixture
def repo_root() -> str:
    return REPO_ROOT


@pytest.fixture(scope="module")
def ray_cluster(tmp_path_factory: pytest.TempPathFactory):
    """
    A local Ray cluster of 2 CPUs in this process, no dashboard, for one test module (seconds to start);
    skipped without Ray. Started with SIGINT ignored, as when the tests run in the background (``nohup``,
    ``make test &``, CI runners): Ray's workers inherit that, the case in which a non-forced ``ray.cancel``
    once reached no running task (hddpg_zoo/ray_executor.py, "Interruption").

    It is the library's :func:`~hddpg_zoo.ray_executor.private_ray`, run with ``HOME`` pointing
    at an empty folder of the test's own, which must still be empty when the cluster is gone: Ray's
    temporary files and authentication token go to folders the caller controls, never to ``~/.ray``.
    """
    ray = pytest.importorskip("ray")
    from hddpg_zoo.ray_executor import private_ray
    from tests import jobs

    ray.cloudpickle.register_pickle_by_value(jobs)  # Ray's workers cannot import the tests by name
    home = tmp_path_factory.mktemp("home")
    saved_home = os.environ.get("HOME")
    os.environ["HOME"] = str(home)
    try:
        with contextlib.ExitStack() as stack:
            previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
            try:
                stack.enter_context(private_ray(tmp_path_factory.mktemp("ray"), num_cpus=2))
            finally:
                signal.signal(signal.SIGINT, previous)
            yield ray
    finally:
        if saved_home is None:
            os.environ.pop("HOME", None)
        else:
            os.environ["HOME"] = saved_home
    left = sorted(str(p.relative_to(home)) for p in home.rglob("*"))
    assert not left, f"the Ray tests wrote into the home folder: {left[:10]}"

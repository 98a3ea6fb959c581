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
    A local Ray cluster of 2 CPUs, no dashboard, this process its driver, for one test module (seconds to
    start); skipped without Ray. The head runs as ``ray start`` in a process of its own: ``ray.init`` starting
    it here would fork this process (Ray's ``preexec_fn``), which JAX, loaded by an earlier test of the
    same process, warns would deadlock. Started with SIGINT ignored, as when the tests run in the
    background (``nohup``, ``make test &``, CI runners): Ray's workers inherit that, the case in which a
    non-forced ``ray.cancel`` once reached no running task (sb3_hddpg/experiments/ray_executor.py,
    "Interruption").
    """
    ray = pytest.importorskip("ray")
    from sb3_hddpg.experiments.ray_head import local_ray_head
    from tests import jobs

    ray.cloudpickle.register_pickle_by_value(jobs)  # Ray's workers cannot import the tests by name
    log = tmp_path_factory.mktemp("ray-cluster") / "head.log"
    with contextlib.ExitStack() as stack:
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
        try:
            head = stack.enter_context(local_ray_head(2, log))
        finally:
            signal.signal(signal.SIGINT, previous)
        ray.init(address=head.address, logging_level="WARNING")
        yield ray
        ray.shutdown()

"""
Torch's threads where the library trains: one per process, unless the user chose.

Small MLPs on a CPU learn fastest on one thread: with torch's default (one per core) the threads of a SAC
update wait on each other, several times slower than one thread on a busy two-core machine. The CLI and the
training functions run every agent with ``RunOptions.threads`` (1 by default); a user's own training loop on
the manager's env (:class:`~sb3_hddpg.hierarchy.wrapper.WorkerSelectionWrapper`, e.g. the README's
``SAC(...).learn``) gets one thread too, through :func:`use_one_thread_unless_chosen`, so that the library
runs as fast in a script as in the CLI.

A choice of the user's is kept: ``OMP_NUM_THREADS`` or ``MKL_NUM_THREADS`` set, or
``torch.set_num_threads(n)`` called with an ``n`` other than torch's default of one thread per CPU. To
use several threads anyway, call ``torch.set_num_threads(n)`` after building the env.
"""

from __future__ import annotations

import logging
import os

logger = logging.getLogger(__name__)

#: Environment variables that set torch's threads: a user who set one chose.
THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS")


def _cpus() -> int:
    """The CPUs this process may run on: torch's default thread count."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def use_one_thread_unless_chosen() -> bool:
    """
    Set torch to one thread in this process, unless the user chose its threads (see the module's docstring).

    :return: whether the thread count was changed.
    """
    import torch  # here, not at import: the CLI parses its options before torch loads

    if any(os.environ.get(name) for name in THREAD_VARIABLES):
        return False
    threads = torch.get_num_threads()
    if threads == 1 or threads != _cpus():
        return False  # already one, or a number the user set
    torch.set_num_threads(1)
    logger.info("torch set to 1 thread (from %d): small networks train fastest on one", threads)
    return True


__all__ = ["THREAD_VARIABLES", "use_one_thread_unless_chosen"]

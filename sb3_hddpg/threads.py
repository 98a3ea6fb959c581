"""
Torch's threads where the library trains: one per process, unless the user chose.

Small MLPs on a CPU learn several times faster on one thread than on torch's default of one per core, whose
threads wait on each other. The CLI trains with ``RunOptions.threads`` (1 by default), and a script's own
loop on the manager's env gets one thread through :func:`use_one_thread_unless_chosen`. A user's choice is
kept: ``OMP_NUM_THREADS`` or ``MKL_NUM_THREADS`` set, or ``torch.set_num_threads(n)`` called with another
``n`` than one per CPU (call it after building the env to use several).
"""

from __future__ import annotations

import logging
import os

logger = logging.getLogger(__name__)

#: Environment variables that set torch's threads: a user who set one chose.
THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS")


def use_one_thread_unless_chosen() -> bool:
    """
    Set torch to one thread in this process, unless the user chose its threads (see the module's docstring).

    :return: whether the thread count was changed.
    """
    import torch  # here, not at import: the CLI parses its options before torch loads

    if any(os.environ.get(name) for name in THREAD_VARIABLES):
        return False
    threads = torch.get_num_threads()
    # torch's default is one thread per CPU this process may run on
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    if threads == 1 or threads != cpus:
        return False  # already one, or a number the user set
    torch.set_num_threads(1)
    logger.info("torch set to 1 thread (from %d): small networks train fastest on one", threads)
    return True


__all__ = ["THREAD_VARIABLES", "use_one_thread_unless_chosen"]

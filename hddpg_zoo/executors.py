"""
``make_executor``: the executor a command's options name, local processes (the default), this process, or a
Ray cluster. Its own module so that the process runner does not import the Ray executor, which imports it.
"""

from __future__ import annotations

from hddpg_zoo.runner import Executor, InlineExecutor, LocalProcessExecutor


def make_executor(
    n_jobs: int | None,
    interrupt_grace: float | None = 0.0,
    inline: bool = False,
    ray_address: str | None = None,
) -> Executor:
    """
    The local executor for ``n_jobs`` processes, :class:`InlineExecutor` when ``inline``, or the Ray
    executor when ``ray_address`` is given.

    :param n_jobs: jobs at a time (``None``: 1 locally, every CPU of a Ray cluster).
    :param interrupt_grace: see :class:`LocalProcessExecutor` (local only: a Ray task does not see the
        terminal's Ctrl-C that local jobs see at once, so on an interrupt it is cancelled without waiting,
        which raises the same ``KeyboardInterrupt`` in it, and killed if still running
        :data:`~hddpg_zoo.ray_executor.CANCEL_GRACE` seconds later).
    :param inline: run in this process instead (local only).
    :param ray_address: run each job as a Ray task on the cluster at this address (``auto`` or
        ``HOST:PORT``, see :class:`~hddpg_zoo.ray_executor.RayExecutor`); ``None``: locally.
    """
    if ray_address is not None:
        from hddpg_zoo.ray_executor import RayExecutor  # lazily: Ray is optional

        return RayExecutor(ray_address, slots=n_jobs)
    return InlineExecutor() if inline else LocalProcessExecutor(n_jobs or 1, interrupt_grace)

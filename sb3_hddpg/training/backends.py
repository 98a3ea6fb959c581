"""
Training backends: SB3 (PyTorch, the default) and SBX (JAX), behind the one algorithm registry.

SBX (``sbx-rl``) is the SB3 maintainers' JAX implementation of the same algorithms with SB3's API; its jitted
updates cost far less per gradient step on small networks (docs/PERFORMANCE.md). An SBX model starts from the
weights SB3 would draw with the same seed and is exported to an ordinary SB3 model of the same algorithm when
saved (:mod:`sb3_hddpg.training.models`), so everything a user shares stays plain SB3. Nothing here imports
``jax`` or ``sbx`` at import time.
"""

from __future__ import annotations

import functools
import importlib.util
import logging
import os
import sys
from pathlib import Path
from typing import Any

from stable_baselines3.common.base_class import BaseAlgorithm

from sb3_hddpg.algorithms import ALGORITHMS, SBX_ALGORITHMS, algorithm, algorithm_class

logger = logging.getLogger(__name__)

#: Backend names accepted by ``--backend`` and the config key ``backend``.
BACKENDS = ("sb3", "sbx")
#: The backend used when neither the command line nor the config names one, also where SBX is installed: the
#: backends do not learn bit for bit alike, and the same command should give the same result everywhere.
DEFAULT_BACKEND = "sb3"
#: How to install the SBX backend.
INSTALL_HINT = 'pip install "sb3-hddpg[fast]"'
#: Algorithms the SBX backend trains and exports (SB3's classes of the same name).
SBX_ALGOS: dict[str, type[BaseAlgorithm]] = {name: ALGORITHMS[name] for name in SBX_ALGORITHMS}


class BackendError(ValueError):
    """A backend that cannot be used: unknown, not installed, or unable to run a given setting."""


def sbx_installed() -> bool:
    """Whether SBX and JAX can be imported (checked without importing them, which would fix XLA's threads)."""
    return all(importlib.util.find_spec(name) is not None for name in ("sbx", "jax", "flax", "optax"))


def check_backend(name: object) -> str:
    """
    Validate a backend name and that it can run here.

    :param name: ``"sb3"`` or ``"sbx"`` (any case).
    :return: the name, lower-cased; raises :class:`BackendError` naming the choices or the missing extra.
    """
    if not isinstance(name, str) or name.strip().lower() not in BACKENDS:
        raise BackendError(f"Unknown backend {name!r}; choose from {list(BACKENDS)}")
    name = name.strip().lower()
    if name == "sbx" and not sbx_installed():
        raise BackendError(f"The sbx backend needs SBX and JAX, which are not installed: {INSTALL_HINT}")
    return name


def resolve_backend(requested: str | None, configured: str | None = None) -> str:
    """
    The backend to train with, checked: the one requested (``--backend``), else the config block's, else
    :data:`DEFAULT_BACKEND`.
    """
    return check_backend(requested or configured or DEFAULT_BACKEND)


def check_algo(algo: str, backend: str) -> None:
    """Raise :class:`BackendError` if ``backend`` cannot train ``algo``."""
    if backend == "sbx" and algo.lower() not in SBX_ALGOS:
        raise BackendError(
            f"The sbx backend trains {sorted(SBX_ALGOS)}, not {algo!r}: use --backend sb3 for {algo}"
        )


#: The thread count XLA was configured with in this process (``None``: jax not configured by us).
_configured_threads: int | None = None


def configure_jax_threads(threads: int = 1) -> None:
    """
    Size XLA's CPU thread pool like ``torch.set_num_threads(threads)``.

    XLA reads its pool size from the environment once, when jax creates its CPU client: call this before jax
    is imported (afterwards a different count is logged as a warning). ``PJRT_NPROC`` sets the intra-op pool;
    ``intra_op_parallelism_threads`` in ``XLA_FLAGS`` is silently ignored by XLA.

    :param threads: threads for jitted computations in this process (>= 1).
    """
    global _configured_threads
    if threads < 1:
        raise ValueError(f"Expected threads >= 1, actually: {threads}")
    if "jax" in sys.modules:
        if _configured_threads is not None and _configured_threads != threads:
            logger.warning(
                "jax already runs with %d thread(s) in this process; threads=%d cannot take effect",
                _configured_threads,
                threads,
            )
        elif _configured_threads is None and os.environ.get("PJRT_NPROC") != str(threads):
            logger.warning("jax was imported before its threads were set; threads=%d may not apply", threads)
        return
    os.environ["PJRT_NPROC"] = os.environ["NPROC"] = str(threads)
    # jax's persistent compilation cache, for every compilation however short: a new process (a benchmark
    # task, a tuning process) then loads its updates instead of spending its first steps compiling them.
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "sb3-hddpg" / "jax"
    os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(cache))
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
    flags = [f for f in os.environ.get("XLA_FLAGS", "").split() if "xla_cpu_multi_thread_eigen" not in f]
    if threads == 1:
        flags.append("--xla_cpu_multi_thread_eigen=false")
    os.environ["XLA_FLAGS"] = " ".join(flags)
    _configured_threads = threads


def algo_class(name: str, backend: str = "sb3") -> type[BaseAlgorithm]:
    """
    The class for an algorithm name (``ddpg``, ``td3``, ``sac``, ``tqc``) on a training backend.

    :param name: the algorithm.
    :param backend: ``sb3`` (PyTorch) or ``sbx`` (JAX).
    """
    cls = algorithm_class(name)
    return sbx_class(name) if backend != "sb3" and check_backend(backend) == "sbx" else cls


def sbx_class(algo: str) -> type[BaseAlgorithm]:
    """The SBX class of an algorithm name (imports jax: call :func:`configure_jax_threads` first)."""
    check_algo(algo, "sbx")
    check_backend("sbx")
    if _configured_threads is None and "jax" not in sys.modules:
        configure_jax_threads(1)
    import sbx  # lazily: optional (the `fast` extra), and jax is slow to import

    record = algorithm(algo)
    cls = getattr(sbx, str(record.sbx))  # a name from our own registry, never from a file
    # SBX's deterministic actor-critics keep the schedule's first rate; SAC-like ones follow it themselves.
    return _scheduled_sbx_class(cls) if record.sbx_layout == "deterministic" else cls


@functools.cache
def _scheduled_sbx_class(base: Any) -> type:
    """
    SBX's TD3 or DDPG, following a learning-rate schedule as SB3's and SBX's SAC do: SBX's own keep the
    schedule's initial value. With an optimiser whose rate lives in its state (:func:`scheduled_adam`) it
    sets the rate from ``lr_schedule`` before each training call; with a plain one it trains as SBX's class.
    """

    def train(self: Any, gradient_steps: int, batch_size: int) -> None:
        optimizers = [self.policy.actor_state.opt_state, self.policy.qf_state.opt_state]
        if all(hasattr(state, "hyperparams") for state in optimizers):
            self._update_learning_rate(optimizers, self.lr_schedule(self._current_progress_remaining))
        base.train(self, gradient_steps, batch_size)

    # The name and module of the base, so that code telling SBX models from SB3 ones by module still does.
    return type(base.__name__, (base,), {"train": train, "__module__": base.__module__})


def scheduled_adam(learning_rate: float, **kwargs: object) -> Any:
    """
    optax's Adam with its learning rate in the optimiser state, so that a schedule can set it; a function of
    this module, so that a saved model (SBX pickles ``policy_kwargs``) refers to it by name.
    """
    import optax  # lazily: optional, with SBX

    return optax.inject_hyperparams(optax.adam)(learning_rate=learning_rate, **kwargs)

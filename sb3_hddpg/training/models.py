"""
A model on either training backend: built fresh, loaded from a run folder, and turned into the SB3 model a run
saves and shares. The SBX side lives in :mod:`sb3_hddpg.training.sbx_models`, imported only for SBX models.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from stable_baselines3.common.base_class import BaseAlgorithm

from sb3_hddpg.artifacts.limits import check_run_file
from sb3_hddpg.training.backends import algo_class, check_backend


def is_sbx_model(model: object) -> bool:
    """Whether ``model`` is an SBX (JAX) model rather than an SB3 one."""
    return type(model).__module__.split(".")[0] == "sbx"


def make_model(
    algo: str,
    backend: str,
    env: Any,
    kwargs: Mapping[str, Any],
    seed: int | None = None,
    policy: str = "MlpPolicy",
) -> BaseAlgorithm:
    """
    Build a fresh model of ``algo`` on ``backend``.

    With ``sbx``, the networks start from the weights SB3 draws for the same seed (copied from a freshly
    built SB3 policy), and the random states are left as SB3's constructor leaves them, so that exploration
    noise and replay sampling follow the same random streams on both backends.

    :param algo: the algorithm.
    :param backend: ``sb3`` or ``sbx``.
    :param env: the (vectorised) training env.
    :param kwargs: SB3 constructor arguments (from the config block, ``action_noise`` included).
    :param seed: the training seed.
    :param policy: the policy name (``MlpPolicy``).
    :return: the model, on the CPU.
    """
    backend = check_backend(backend)
    # SB3 writes into the policy_kwargs dict it is given (use_sde): keep the caller's (the config's) intact.
    kwargs = {**kwargs, "policy_kwargs": dict(kwargs.get("policy_kwargs") or {})}
    if backend == "sb3":
        return algo_class(algo)(policy, env, seed=seed, device="cpu", verbose=0, **kwargs)
    from sb3_hddpg.training.sbx_models import sbx_model  # SBX only

    return sbx_model(algo, env, kwargs, seed, policy)


def load_native(algo: str, backend: str, path: Any, env: Any = None) -> BaseAlgorithm:
    """Load a model a backend saved in a run folder (a checkpoint or ``best_model.zip``) onto ``env``."""
    cls = algo_class(algo, backend)
    check_run_file(path)
    model = cls.load(path, env=env, device="cpu")
    if is_sbx_model(model):
        from sb3_hddpg.training.sbx_models import share_compiled  # SBX only

        share_compiled(model)
    return model


def to_sb3(model: BaseAlgorithm) -> BaseAlgorithm:
    """
    The SB3 model to save and share for a trained model: SB3 models as they are, SBX models exported.

    The export builds an SB3 model of the same algorithm and settings (no env attached) and copies the
    actor, the critics, their targets and the entropy coefficient; optimiser moments are not copied
    (continue training from the run's native checkpoint).

    :param model: an SB3 or SBX model.
    :return: an SB3 model.
    """
    if not is_sbx_model(model):
        return model
    from sb3_hddpg.training.sbx_models import export_to_sb3  # SBX only

    return export_to_sb3(model)

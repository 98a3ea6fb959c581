"""
Training backends: SB3 (PyTorch, the default) and SBX (JAX), behind the one algorithm registry.

SBX (``sbx-rl``) is the SB3 maintainers' JAX implementation of the same algorithms with SB3's API; its jitted
updates cost far less per gradient step on small networks (docs/PERFORMANCE.md). An SBX model starts from the
weights SB3 would draw with the same seed (:func:`make_model`) and is exported to an ordinary SB3 model of the
same algorithm when saved (:func:`to_sb3`), so everything a user shares stays plain SB3. Nothing here imports
``jax`` or ``sbx`` at import time.
"""

from __future__ import annotations

import functools
import importlib.util
import inspect
import logging
import os
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm

from sb3_hddpg.algorithms import ALGORITHMS, REGISTRY, SBX_ALGORITHMS, Algorithm, algorithm, algorithm_class
from sb3_hddpg.artifacts.limits import check_run_file
from sb3_hddpg.artifacts.spec import build_without_env

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


def is_sbx_model(model: object) -> bool:
    """Whether ``model`` is an SBX (JAX) model rather than an SB3 one."""
    return type(model).__module__.split(".")[0] == "sbx"


def _sbx_record(model: object) -> Algorithm:
    import sbx  # lazily: optional, and jax is slow to import (only SBX models get here)

    # The first registered class in the model's MRO, the most derived (SBX's DDPG is a TD3; a model under the
    # action penalty is a subclass of its algorithm).
    records = {getattr(sbx, record.sbx): record for record in REGISTRY.values() if record.sbx is not None}
    found = next((records[cls] for cls in type(model).__mro__ if cls in records), None)
    if found is None:
        raise BackendError(
            f"Cannot export {type(model).__qualname__} to SB3; exportable: {sorted(SBX_ALGOS)}"
        )
    return found


def _activation_pairs() -> list[tuple[type[th.nn.Module], Any]]:
    """(torch activation class, the flax function computing the same) for every activation configs may name."""
    import flax.linen as fnn  # lazily: optional (the `fast` extra), slow to import, with jax

    return [
        (th.nn.ReLU, fnn.relu),
        (th.nn.Tanh, fnn.tanh),
        (th.nn.ELU, fnn.elu),
        (th.nn.LeakyReLU, fnn.leaky_relu),  # both slopes default to 0.01
        (th.nn.SiLU, fnn.silu),
        (th.nn.GELU, functools.partial(fnn.gelu, approximate=False)),  # torch's GELU is the exact one
        (th.nn.Sigmoid, fnn.sigmoid),
    ]


def _to_flax_activation(activation: object) -> Any:
    for torch_cls, flax_fn in _activation_pairs():
        if activation is torch_cls:
            return flax_fn
    raise BackendError(f"The sbx backend has no JAX counterpart of activation_fn {activation!r}")


def _to_torch_activation(activation: object) -> type[th.nn.Module]:
    for torch_cls, flax_fn in _activation_pairs():
        if activation is flax_fn or (
            getattr(activation, "func", None) is getattr(flax_fn, "func", flax_fn)
            and getattr(activation, "keywords", None) == getattr(flax_fn, "keywords", None)
        ):
            return torch_cls
    raise BackendError(f"No torch counterpart of the SBX activation_fn {activation!r}")


#: ``policy_kwargs`` both backends read the same way.
_SHARED_POLICY_KWARGS = {"net_arch", "activation_fn", "n_critics", "share_features_extractor"}
#: SBX policy options without an SB3 counterpart: only their defaults can be exported.
_SBX_ONLY_POLICY_DEFAULTS = {"dropout_rate": 0.0, "layer_norm": False, "use_sde": False}


def sbx_kwargs(algo: str, kwargs: Mapping[str, Any]) -> dict[str, Any]:
    """
    Translate SB3 constructor arguments (a config block's) into SBX's, refusing what SBX cannot honour.

    :param algo: an algorithm SBX trains (:data:`SBX_ALGOS`).
    :param kwargs: SB3 keyword arguments.
    :return: the SBX keyword arguments; raises :class:`BackendError` naming the key SBX lacks.
    """
    from sb3_hddpg.training.sbx_weights import layout_of  # SBX only

    record = algorithm(algo)
    cls = sbx_class(algo)
    accepted = set(inspect.signature(cls.__init__).parameters)
    out = dict(kwargs)
    for key in out:
        if key not in accepted:
            raise BackendError(f"The sbx backend's {cls.__name__} has no argument {key!r}: use --backend sb3")
    policy_kwargs = dict(out.get("policy_kwargs") or {})
    if policy_kwargs.get("use_sde") is False:  # SB3 writes its default into the dict it was given
        del policy_kwargs["use_sde"]
    extra = sorted(set(policy_kwargs) - _SHARED_POLICY_KWARGS - layout_of(record).policy_kwargs)
    if extra:
        raise BackendError(f"The sbx backend cannot honour policy_kwargs {extra}: use --backend sb3")
    if "activation_fn" in policy_kwargs:
        policy_kwargs["activation_fn"] = _to_flax_activation(policy_kwargs["activation_fn"])
    if "batch_norm_momentum" in policy_kwargs:
        # torch's BatchRenorm moves its statistics by momentum, flax's keeps momentum of the old ones.
        policy_kwargs["batch_norm_momentum"] = 1.0 - float(policy_kwargs["batch_norm_momentum"])
    if "batch_norm" in policy_kwargs:  # one switch for actor and critic in torch, two in SBX
        policy_kwargs["batch_norm_actor"] = policy_kwargs["batch_norm"]
    out["policy_kwargs"] = policy_kwargs
    if "qf_learning_rate" in accepted:
        # SB3 trains the critic at learning_rate; SBX's DDPG defaults its critic to 1e-3 whatever that is.
        out["qf_learning_rate"] = None
    if callable(out.get("learning_rate")) and record.sbx_layout == "deterministic":
        # SBX's SAC-like algorithms keep their rates in the optimiser state, TD3 and DDPG on request.
        policy_kwargs["optimizer_class"] = scheduled_adam
    return out


#: SB3 constructor arguments that an SBX model holds as attributes of the same name, exported as they are.
_EXPORTED_SETTINGS = (
    "buffer_size",
    "learning_starts",
    "batch_size",
    "tau",
    "gamma",
    "gradient_steps",
    "policy_delay",
    "target_policy_noise",
    "target_noise_clip",
    "target_entropy",
)


def _sb3_hyperparams(model: Any, record: Algorithm) -> dict[str, Any]:
    """The SB3 constructor arguments that reproduce an SBX model's settings."""
    accepted = set(inspect.signature(record.cls.__init__).parameters)
    train_freq = model.train_freq
    hparams: dict[str, Any] = {
        "learning_rate": model.learning_rate,
        # SB3 turns train_freq into a TrainFreq(frequency, unit) named tuple; hand it back as a plain tuple.
        "train_freq": (int(train_freq.frequency), train_freq.unit.value)
        if hasattr(train_freq, "unit")
        else train_freq,
    }
    for key in _EXPORTED_SETTINGS:
        value = getattr(model, key, None)
        if key in accepted and value is not None:
            hparams[key] = value.item() if isinstance(value, np.generic) else value
    if "top_quantiles_to_drop_per_net" in accepted:  # SBX's TQC keeps it among the policy's settings
        hparams["top_quantiles_to_drop_per_net"] = int(model.policy_kwargs["top_quantiles_to_drop_per_net"])
    if "ent_coef" in accepted and hasattr(model, "ent_coef_init"):
        hparams["ent_coef"] = model.ent_coef_init
        hparams["target_entropy"] = float(model.target_entropy)
    if "target_update_interval" in accepted:
        # SBX's SAC and TQC update their targets after every gradient step, SB3's target_update_interval=1.
        hparams["target_update_interval"] = 1
    return hparams


def _sb3_policy_kwargs(model: Any, record: Algorithm) -> dict[str, Any]:
    from sb3_hddpg.training.sbx_weights import layout_of  # SBX only

    policy_kwargs = dict(model.policy_kwargs)
    if policy_kwargs.get("optimizer_class") is scheduled_adam:
        # SB3's optimiser follows the schedule (learning_rate) by itself.
        del policy_kwargs["optimizer_class"]
    policy_kwargs.pop("top_quantiles_to_drop_per_net", None)  # an argument of SB3's TQC, not its policy's
    for key, default in _SBX_ONLY_POLICY_DEFAULTS.items():
        if key in policy_kwargs and policy_kwargs.pop(key) != default:
            raise BackendError(f"Cannot export an SBX model with {key}={model.policy_kwargs[key]!r} to SB3")
    if "batch_norm_actor" in policy_kwargs and policy_kwargs.pop("batch_norm_actor") != policy_kwargs.get(
        "batch_norm", True
    ):
        raise BackendError("Cannot export an SBX model with batch_norm_actor != batch_norm to SB3")
    if "batch_norm_momentum" in policy_kwargs:
        policy_kwargs["batch_norm_momentum"] = 1.0 - float(policy_kwargs["batch_norm_momentum"])
    extra = sorted(set(policy_kwargs) - _SHARED_POLICY_KWARGS - layout_of(record).policy_kwargs)
    if extra:
        raise BackendError(f"Cannot export an SBX model with policy_kwargs {extra} to SB3")
    if "activation_fn" in policy_kwargs:
        policy_kwargs["activation_fn"] = _to_torch_activation(policy_kwargs["activation_fn"])
    if policy_kwargs.get("n_critics") == record.default_n_critics:
        # SBX's DDPG writes its default of one critic into policy_kwargs; SB3's has the same default.
        policy_kwargs.pop("n_critics")
    return policy_kwargs


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
    record = algorithm(algo)
    # Any: SBX's SAC adds attributes (target_entropy) that BaseAlgorithm does not declare.
    model: Any = sbx_class(algo)(policy, env, seed=seed, device="cpu", verbose=0, **sbx_kwargs(algo, kwargs))
    from sb3_hddpg.training.sbx_weights import state_dict_to_sbx  # SBX only

    sb3_kwargs = {k: v for k, v in kwargs.items() if k not in ("action_noise", "policy_kwargs")}
    if record.target_entropy:  # "auto" reads an env the twin does not have; the SBX model has resolved it
        sb3_kwargs["target_entropy"] = float(model.target_entropy)
    twin = build_without_env(
        record.cls,
        model.observation_space,
        model.action_space,
        sb3_kwargs,
        kwargs["policy_kwargs"],
        seed=seed,
    )
    state_dict_to_sbx(model, twin, record)
    share_compiled(model)
    return model


def load_native(algo: str, backend: str, path: Any, env: Any = None) -> BaseAlgorithm:
    """Load a model a backend saved in a run folder (a checkpoint or ``best_model.zip``) onto ``env``."""
    cls = algo_class(algo, backend)
    check_run_file(path)
    model = cls.load(path, env=env, device="cpu")
    if is_sbx_model(model):
        share_compiled(model)
    return model


#: One set of jitted functions and optimisers per architecture and optimiser setting, shared by models.
_SHARED: dict[tuple[Any, ...], dict[str, tuple[Any, Any]]] = {}


def share_compiled(model: Any) -> None:
    """
    Make ``model`` reuse the apply functions and optimisers of an earlier model of the same architecture.

    The ``apply_fn`` and ``tx`` of SBX's train states are static parts of the jitted update's cache key, and
    every model creates its own, so each new model would recompile the update. Both are pure functions of
    the architecture and the optimiser's settings, so models that agree on those can share them.

    :param model: an SBX model (modified in place).
    """
    from sb3_hddpg.training.sbx_weights import layout_of  # SBX only

    policy = model.policy
    key = (
        type(model).__qualname__,
        repr(policy.actor),
        repr(policy.qf),
        float(model.lr_schedule(1)),
        float(model.qf_learning_rate),
        policy.optimizer_class,
        repr(sorted(policy.optimizer_kwargs.items())),
        repr(getattr(model, "ent_coef_init", None)),
    )
    states = {"actor_state": policy, **{name: policy for name in layout_of(_sbx_record(model)).critic_states}}
    if hasattr(model, "ent_coef_state"):
        states["ent_coef_state"] = model
    shared = _SHARED.setdefault(
        key,
        {name: (getattr(owner, name).apply_fn, getattr(owner, name).tx) for name, owner in states.items()},
    )
    for name, owner in states.items():
        apply_fn, tx = shared[name]
        setattr(owner, name, getattr(owner, name).replace(apply_fn=apply_fn, tx=tx))


def to_sb3(model: BaseAlgorithm) -> BaseAlgorithm:
    """
    The SB3 model to save and share for a trained model: SB3 models as they are, SBX models exported.

    The export builds an SB3 model of the same algorithm and settings (no env attached) and copies the
    actor, the critics, their targets and the entropy coefficient; optimiser moments are not copied
    (continue training from the run's native checkpoint).

    :param model: an SB3 or SBX model.
    :return: an SB3 model.
    """
    from sb3_hddpg.training.sbx_weights import sbx_to_state_dict  # SBX only

    if not is_sbx_model(model):
        return model
    record = _sbx_record(model)
    # No seed: it would re-seed the global random state (SB3's set_random_seed) mid-run.
    sb3_model: Any = build_without_env(
        record.cls,
        model.observation_space,
        model.action_space,
        _sb3_hyperparams(model, record),
        _sb3_policy_kwargs(model, record),
    )
    sb3_model.seed = model.seed
    state = sbx_to_state_dict(model, sb3_model, record)
    sb3_model.policy.load_state_dict(state, strict=True)
    sbx_model: Any = model
    if getattr(sb3_model, "log_ent_coef", None) is not None and hasattr(sbx_model, "ent_coef_state"):
        # SBX keeps a learned entropy coefficient in a flax train state BaseAlgorithm does not declare.
        log_ent_coef = float(np.asarray(sbx_model.ent_coef_state.params["log_ent_coef"]))
        sb3_model.log_ent_coef.data.fill_(log_ent_coef)
    sb3_model.num_timesteps = int(model.num_timesteps)
    sb3_model._n_updates = int(model._n_updates)
    return sb3_model

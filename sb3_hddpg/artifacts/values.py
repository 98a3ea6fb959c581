"""
Bounded values from files and the command line: the one schema of hyperparameters and env settings, each
refused in one line (:class:`LimitError`) naming the field with the expected and the actual value.
"""

from __future__ import annotations

import contextlib
import inspect
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TypeGuard

import gymnasium as gym
from gymnasium.envs.registration import registry

from sb3_hddpg.artifacts.limits import (
    FILE_RENDER_MODES,
    MAX_BATCH_SIZE,
    MAX_ENV_FLOAT,
    MAX_ENV_INTEGER,
    MAX_EPISODE_LENGTH,
    MAX_EVAL_EPISODES,
    MAX_GRADIENT_STEPS,
    MAX_ITEMS,
    MAX_LEARNING_STARTS,
    MAX_MAGNITUDE,
    MAX_N_ENVS,
    MAX_OPTION_STEPS,
    MAX_THREADS,
    MAX_TIMESTEPS,
    MAX_TRAIN_FREQ,
    MIN_ENV_FLOAT,
    LimitError,
    brief,
    check_env_id,
    check_name,
)
from sb3_hddpg.envs import ADAPTER_ENV_IDS, EnvUnavailableError


@dataclass(frozen=True)
class Bound:
    """
    The range of one numeric setting.

    :param kind: ``int`` (integral floats such as YAML's ``1e3`` are accepted as ints) or ``float``.
    :param low: the least value.
    :param high: the greatest value.
    :param low_open: ``low`` itself is excluded.
    :param high_open: ``high`` itself is excluded.
    :param also: values accepted outside the range (SB3's ``gradient_steps: -1``).
    """

    kind: type
    low: float
    high: float
    low_open: bool = False
    high_open: bool = False
    also: tuple[int, ...] = ()

    def describe(self) -> str:
        """The range as text, e.g. ``an integer in [1, 65536]``."""
        left, right = "(" if self.low_open else "[", ")" if self.high_open else "]"
        kind = "an integer" if self.kind is int else "a finite number"
        extra = f" or {', '.join(map(str, self.also))}" if self.also else ""
        low, high = (int(x) if self.kind is int else x for x in (self.low, self.high))
        return f"{kind} in {left}{low}, {high}{right}{extra}"

    def check(self, value: object, what: str) -> Any:
        """``value`` as ``kind`` when within the range; raises :class:`LimitError` naming ``what`` otherwise."""
        if not isinstance(value, bool) and value in self.also:
            return value
        number = _number(value, self.kind)
        if number is None or not self._within(number):
            raise LimitError(f"{what}: expected {self.describe()}, got {brief(value)}")
        return number

    def _within(self, number: float) -> bool:
        above = number > self.low if self.low_open else number >= self.low
        below = number < self.high if self.high_open else number <= self.high
        return above and below


def _number(value: object, kind: type) -> int | float | None:
    """``value`` as ``kind`` if it is a finite number of that kind (an integral float counts as an int)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return None
    if kind is int and isinstance(value, float) and not value.is_integer():
        return None
    return int(value) if kind is int else float(value)


def is_finite_number(value: object) -> TypeGuard[int | float]:
    """``value`` is an ``int`` or ``float`` (never a ``bool``) and finite: a number as a JSON record may hold it."""
    return _number(value, float) is not None


_UNIT = Bound(float, 0.0, 1.0)
_MAGNITUDE = Bound(float, 0.0, MAX_MAGNITUDE)

#: Numeric config keys (algorithm arguments and RL Zoo's own) -> their range (structures: :data:`STRUCTURED`).
HYPERPARAMETERS: dict[str, Bound] = {
    "n_timesteps": Bound(int, 1, MAX_TIMESTEPS),
    "n_envs": Bound(int, 1, MAX_N_ENVS),
    "noise_std": _MAGNITUDE,
    "batch_size": Bound(int, 1, MAX_BATCH_SIZE),
    "gradient_steps": Bound(int, 1, MAX_GRADIENT_STEPS, also=(-1,)),
    "learning_starts": Bound(int, 0, MAX_LEARNING_STARTS),
    "learning_rate": Bound(float, 0.0, 1.0, low_open=True),
    "gamma": Bound(float, 0.0, 1.0, high_open=True),
    "tau": Bound(float, 0.0, 1.0, low_open=True),
    "n_steps": Bound(int, 1, MAX_EPISODE_LENGTH),
    "policy_delay": Bound(int, 1, MAX_GRADIENT_STEPS),
    "target_policy_noise": _MAGNITUDE,
    "target_noise_clip": _MAGNITUDE,
    "stats_window_size": Bound(int, 1, MAX_EPISODE_LENGTH),
    "target_update_interval": Bound(int, 1, MAX_TRAIN_FREQ),
    "sde_sample_freq": Bound(int, 1, MAX_TRAIN_FREQ, also=(-1,)),
    "top_quantiles_to_drop_per_net": Bound(int, 0, 100),
    "relabel_fraction": _UNIT,
    "coefficient": _MAGNITUDE,
    "margin": Bound(float, 0.0, MAX_MAGNITUDE, low_open=True),
    # On-policy (PPO) and DQN-family arguments.
    "n_epochs": Bound(int, 1, MAX_GRADIENT_STEPS),
    "gae_lambda": _UNIT,
    "clip_range": Bound(float, 0.0, MAX_MAGNITUDE, low_open=True),
    "clip_range_vf": Bound(float, 0.0, MAX_MAGNITUDE, low_open=True),
    "vf_coef": _MAGNITUDE,
    "max_grad_norm": Bound(float, 0.0, MAX_MAGNITUDE, low_open=True),
    "target_kl": Bound(float, 0.0, MAX_MAGNITUDE, low_open=True),
    "exploration_fraction": _UNIT,
    "exploration_initial_eps": _UNIT,
    "exploration_final_eps": _UNIT,
}
#: Arguments that are booleans.
FLAGS = ("optimize_memory_usage", "use_sde", "use_sde_at_warmup", "normalize_advantage")
#: Arguments whose structured values :mod:`sb3_hddpg.training.config` checks (and bounds) itself.
STRUCTURED = (
    "policy_kwargs",
    "replay_buffer_class",
    "replay_buffer_kwargs",
    "train_freq",
    "buffer_size",
    "ent_coef",
    "target_entropy",
)
#: The run-control settings (:class:`~sb3_hddpg.training.run_options.RunOptions`, the CLI's options) -> range.
RUN_SETTINGS: dict[str, Bound] = {
    "timesteps": HYPERPARAMETERS["n_timesteps"],
    "n_envs": HYPERPARAMETERS["n_envs"],
    "plateau_patience": Bound(int, 1, MAX_EVAL_EPISODES),
    "eval_freq": Bound(int, 0, MAX_TIMESTEPS),
    "eval_episodes": Bound(int, 1, MAX_EVAL_EPISODES),
    "checkpoint_freq": Bound(int, 0, MAX_TIMESTEPS),
    "threads": Bound(int, 1, MAX_THREADS),
}


#: A manager block's ``wrapper_kwargs`` that are numbers -> their range.
WRAPPER_SETTINGS: dict[str, Bound] = {
    "option_steps": Bound(int, 1, MAX_OPTION_STEPS),
    "temperature": Bound(float, 0.0, MAX_MAGNITUDE, low_open=True),
    "floor": Bound(float, 0.0, 1.0, high_open=True),
    "option_gamma": Bound(float, 0.0, 1.0, low_open=True),
}

#: SAC's ``ent_coef`` / ``target_entropy`` may be ``"auto"`` or ``"auto_<initial value>"``.
_AUTO = re.compile(r"^auto(_[0-9.eE+-]{1,32})?$")


def check_hyperparameters(block: dict[str, object], source: str) -> None:
    """
    Bound the algorithm arguments of a config block in place (integral floats become ints): every key must
    be in :data:`HYPERPARAMETERS`, :data:`FLAGS` or :data:`STRUCTURED`.

    :param block: the block's algorithm arguments (RL Zoo's own keys already taken out).
    :param source: the block, for messages.
    """
    for key in list(block):
        value = block[key]
        if key in HYPERPARAMETERS:
            if key in ("learning_rate", "clip_range") and not isinstance(value, (int, float)):
                continue  # a schedule, parsed and checked by the config reader
            block[key] = HYPERPARAMETERS[key].check(value, f"{source}: {key}")
        elif key in FLAGS:
            if not isinstance(value, bool):
                raise LimitError(f"{source}: {key}: expected true or false, got {brief(value)}")
        elif key in ("ent_coef", "target_entropy"):
            block[key] = _auto_or_number(value, f"{source}: {key}")
        elif key not in STRUCTURED:
            raise LimitError(f"{source}: {key}: no bounds are declared for this argument; it is not accepted")


def _auto_or_number(value: object, what: str) -> str | float:
    """SAC's ``"auto"``, ``"auto_<initial value > 0>"`` or a bounded number."""
    if isinstance(value, str) and _AUTO.match(value):
        _, _, initial = value.partition("_")
        if initial:
            try:
                Bound(float, 0.0, MAX_MAGNITUDE, low_open=True).check(float(initial), what)
            except ValueError:
                raise LimitError(f"{what}: expected 'auto_<initial value > 0>', got {brief(value)}") from None
        return value
    return Bound(float, -MAX_MAGNITUDE, MAX_MAGNITUDE).check(value, what)


def check_train_freq(value: object, what: str) -> int | tuple[int, str]:
    """SB3's ``train_freq``: steps, or ``[n, "step" | "episode"]``, with ``n`` in [1, :data:`MAX_TRAIN_FREQ`]."""
    bound = Bound(int, 1, MAX_TRAIN_FREQ)
    if isinstance(value, (list, tuple)):
        if len(value) != 2 or value[1] not in ("step", "episode"):
            raise LimitError(f"{what}: expected n or [n, 'step' | 'episode'], got {brief(value)}")
        return (int(bound.check(value[0], what)), str(value[1]))
    return int(bound.check(value, what))


def check_wrapper_settings(settings: dict[str, object], source: str) -> None:
    """Bound the numeric settings of a manager block's ``wrapper_kwargs`` in place (:data:`WRAPPER_SETTINGS`)."""
    for key, bound in WRAPPER_SETTINGS.items():
        if key in settings:
            settings[key] = bound.check(settings[key], f"{source}: wrapper_kwargs.{key}")


# Env settings.

#: An adapter's own keyword arguments (see :mod:`sb3_hddpg.envs.adapters`); the rest go to its inner env.
ADAPTER_KWARGS = ("env_id", "terms", "term_bounds", "info_key", "term", "episode_steps", "render_mode")
#: Env settings that are episode lengths: bounded by :data:`MAX_EPISODE_LENGTH`.
EPISODE_LENGTH_KEYS = ("episode_steps", "max_episode_steps")
#: A parameter whose name says it names a file: never taken from a file someone else made.
PATH_KEY = re.compile(r"(file|path|dir|config|xml|asset|url)", re.IGNORECASE)
#: A string from a file: a short plain token (no separators, no leading dot or tilde).
PLAIN_STRING = re.compile(r"^[A-Za-z0-9_+-][A-Za-z0-9_.+-]{0,63}$")


def check_env_kwargs(
    env_id: str,
    env_kwargs: object,
    what: str,
    allowed_env_ids: Sequence[str] | None = None,
    trusted: bool = False,
) -> dict[str, Any]:
    """
    Env keyword arguments from a file or an option, before ``gym.make`` sees them: each key a parameter of
    the env's constructor (for an adapter, its own keys and the inner env's), each value checked by
    :func:`check_env_value`. An adapter's ``env_id`` passes :func:`~sb3_hddpg.artifacts.limits.check_env_id`
    with :func:`adaptable_env_ids` allowed too.

    :param env_id: the (checked) env id they are for.
    :param env_kwargs: the value from the file.
    :param what: the field, for the message.
    :param allowed_env_ids: more ids an adapter may adapt (as in ``check_env_id``).
    :param trusted: an adapter may adapt any registered id.
    :return: a copy; raises :class:`LimitError` naming the key otherwise.
    """
    if env_kwargs is None:
        return {}
    if not isinstance(env_kwargs, Mapping):
        raise LimitError(f"{what}: expected a mapping of keyword arguments, got {brief(env_kwargs)}")
    if len(env_kwargs) > MAX_ITEMS:
        raise LimitError(f"{what}: {len(env_kwargs)} keyword arguments is more than the limit of {MAX_ITEMS}")
    if env_id not in ADAPTER_ENV_IDS:
        return _check_constructor_kwargs(env_id, dict(env_kwargs), what)
    own = {k: v for k, v in env_kwargs.items() if k in ADAPTER_KWARGS}
    rest = {k: v for k, v in env_kwargs.items() if k not in ADAPTER_KWARGS}
    inner = own.pop("env_id", None)
    checked = _check_constructor_kwargs(env_id, own, what)
    if inner is not None:
        allowed = [*adaptable_env_ids(), *(allowed_env_ids or ())]
        checked = {"env_id": check_env_id(inner, f"{what}.env_id", allowed, trusted), **checked}
        checked.update(_check_constructor_kwargs(checked["env_id"], rest, what))
    elif rest:
        raise LimitError(f"{what}: {brief(sorted(map(str, rest)))} given without the adapted env's env_id")
    return checked


def check_make_kwargs(env_id: str, env_kwargs: object, what: str) -> dict[str, Any]:
    """A config block's ``env_kwargs``: :func:`check_env_kwargs` (trusted) and ``max_episode_steps``."""
    if not isinstance(env_kwargs, Mapping):
        raise LimitError(f"{what}: expected a mapping of keyword arguments, got {brief(env_kwargs)}")
    kwargs = dict(env_kwargs)
    limit = kwargs.pop("max_episode_steps", None)
    checked = check_env_kwargs(env_id, kwargs, what, trusted=True)
    if limit is not None:
        checked["max_episode_steps"] = _episode_length(limit, f"{what}.max_episode_steps")
    return checked


def _check_constructor_kwargs(env_id: str, kwargs: dict[str, Any], what: str) -> dict[str, Any]:
    try:
        parameters, open_ended = constructor_parameters(env_id, what)
    except EnvUnavailableError:
        # Its package is not installed: its records can still be read, as values of unknown parameters.
        parameters, open_ended = {}, True
    checked: dict[str, Any] = {}
    for key, value in kwargs.items():
        if not isinstance(key, str) or not (key in parameters or (open_ended and key.isidentifier())):
            raise LimitError(
                f"{what}: {brief(key)} is not a parameter of {env_id} (parameters: {sorted(parameters)})"
            )
        checked[key] = check_env_value(key, value, parameters.get(key), f"{what}.{key}")
    return checked


def constructor_parameters(env_id: str, what: str) -> tuple[dict[str, Any], bool]:
    """
    The named parameters of ``env_id``'s constructor with their defaults, over the classes whose ``__init__``
    passes ``**kwargs`` on, and whether the chain accepts any keyword; raises
    :class:`~sb3_hddpg.envs.EnvUnavailableError` when the env's module cannot be imported.
    """
    spec = gym.spec(env_id)
    if spec.entry_point is None:  # registered without one: gym.make could not build it either
        raise LimitError(f"{what}: {env_id!r} is registered without an entry point")
    creator = _creator(spec.entry_point, env_id, what)
    # ``EzPickle.__init__(*args, **kwargs)`` (MO-Gymnasium's envs) records arguments and takes none itself.
    functions = (
        [
            vars(k)["__init__"]
            for k in inspect.getmro(creator)
            if "__init__" in vars(k) and k is not object and k.__name__ != "EzPickle"
        ]
        if inspect.isclass(creator)
        else [creator]
    )
    parameters: dict[str, Any] = {}
    for function in functions:
        signature = inspect.signature(function)
        for name, p in signature.parameters.items():
            if name != "self" and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY):
                parameters.setdefault(name, p.default)
        if not any(p.kind is p.VAR_KEYWORD for p in signature.parameters.values()):
            return parameters, False
    return parameters, bool(functions)


def _creator(entry_point: object, env_id: str, what: str) -> Any:
    if callable(entry_point):
        return entry_point
    try:
        return gym.envs.registration.load_env_creator(str(entry_point))
    except (ImportError, gym.error.Error) as error:
        first = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise EnvUnavailableError(f"{what}: {env_id!r} cannot be made here: {brief(first)}") from None


def check_env_value(key: str, value: object, default: object, what: str) -> Any:
    """
    One env setting: episode lengths bounded, ``render_mode`` only :data:`FILE_RENDER_MODES`, no parameter named
    like a file, a value of the default's type, numbers, plain strings and lists bounded.

    :param key: the parameter.
    :param value: the value from the file.
    :param default: the constructor's default for it (``inspect.Parameter.empty``: none).
    :param what: the field, for the message.
    """
    if key in EPISODE_LENGTH_KEYS:
        return None if value is None else _episode_length(value, what)
    if key == "render_mode":
        if value not in FILE_RENDER_MODES:
            raise LimitError(
                f"{what}: expected one of {list(FILE_RENDER_MODES)} from a file, got {brief(value)}"
            )
        return value
    if PATH_KEY.search(key):
        raise LimitError(f"{what}: names a file or folder; a file may not choose one (got {brief(value)})")
    if key == "term_bounds":
        return _term_bounds(value, what)
    _check_kind(value, default, what)
    return _plain(value, what, depth=0)


def _episode_length(value: object, what: str) -> int:
    return int(Bound(int, 1, MAX_EPISODE_LENGTH).check(value, what))


def _env_float(value: object, what: str) -> Any:
    """A float env setting: within :data:`MAX_ENV_FLOAT`, and 0 or at least :data:`MIN_ENV_FLOAT` in magnitude."""
    checked = Bound(float, -MAX_ENV_FLOAT, MAX_ENV_FLOAT).check(value, what)
    if checked and abs(checked) < MIN_ENV_FLOAT:
        raise LimitError(
            f"{what}: expected 0 or a magnitude of at least {MIN_ENV_FLOAT:g} (an env divides by its settings), "
            f"actually: {checked!r}"
        )
    return checked


def _check_kind(value: object, default: object, what: str) -> None:
    """A value whose parameter has a number, boolean or string default must be one too."""
    if value is None or default is inspect.Parameter.empty or default is None:
        return
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise LimitError(f"{what}: expected true or false, got {brief(value)}")
    elif isinstance(default, int):
        # A float is allowed where the default merely looks whole (``goal_velocity=0``).
        Bound(float, -MAX_ENV_INTEGER, MAX_ENV_INTEGER).check(value, what)
    elif isinstance(default, float):
        _env_float(value, what)
    elif isinstance(default, str) and not isinstance(value, str):
        raise LimitError(f"{what}: expected a string, got {brief(value)}")


def _plain(value: object, what: str, depth: int) -> Any:
    """A plain value, bounded: numbers, plain strings, booleans, ``None``, lists and one level of mapping."""
    if value is None or isinstance(value, bool):
        return value
    if isinstance(value, int):
        return Bound(int, -MAX_ENV_INTEGER, MAX_ENV_INTEGER).check(value, what)
    if isinstance(value, float):
        return _env_float(value, what)
    if isinstance(value, str):
        if not PLAIN_STRING.match(value):
            raise LimitError(
                f"{what}: expected a plain word (letters, digits, '_', '-', '+', '.'; at most 64; no path), "
                f"got {brief(value)}"
            )
        return value
    if depth < 2 and isinstance(value, list) and len(value) <= MAX_ITEMS:
        return [_plain(item, what, depth + 1) for item in value]
    if depth < 1 and isinstance(value, Mapping) and len(value) <= MAX_ITEMS:
        return {check_name(k, what): _plain(v, f"{what}.{k}", depth + 1) for k, v in value.items()}
    raise LimitError(
        f"{what}: expected a number, a plain string, a boolean, a list of at most {MAX_ITEMS} of them or a "
        f"mapping of names to them, got {brief(value)}"
    )


def _term_bounds(value: object, what: str) -> dict[str, list[float]]:
    # Lazily: the env contract's checker is the one rule for bounds (finite, low < high, normalisable).
    from sb3_hddpg.envs.contract import check_bounds

    if not isinstance(value, Mapping) or len(value) > MAX_ITEMS:
        raise LimitError(f"{what}: expected a mapping of at most {MAX_ITEMS} terms to [low, high]")
    for term, pair in value.items():
        check_name(term, what)
        if not isinstance(pair, (list, tuple)) or len(pair) != 2:
            raise LimitError(f"{what}.{term}: expected [low, high], got {brief(pair)}")
        for number in pair:
            if _number(number, float) is None:
                raise LimitError(f"{what}.{term}: expected finite numbers [low, high], got {brief(pair)}")
    try:
        checked = check_bounds(value, "term_bounds")
    except ValueError as error:
        raise LimitError(f"{what}: {error}") from None
    return {term: list(pair) for term, pair in checked.items()}


def adaptable_env_ids() -> list[str]:
    """The ids an adapter may adapt by default: Gymnasium's own and MO-Gymnasium's (when installed)."""
    with contextlib.suppress(ImportError):
        # Lazily: optional (the `mo` extra); importing it registers its ids.
        import mo_gymnasium  # noqa: F401
    return [
        env_id
        for env_id, spec in registry.items()
        if isinstance(spec.entry_point, str) and spec.entry_point.startswith(ADAPTABLE_MODULES)
    ]


#: The packages whose registered envs an adapter may adapt by default.
ADAPTABLE_MODULES = ("mo_gymnasium.", "gymnasium.envs.")

"""
Hyperparameters in RL Zoo's format: ``zoo_configs/*.yml`` -> keyword arguments for an SB3 algorithm.

A config file maps an env id (or ``default``, or ``manager``) to a block of hyperparameters, as RL Zoo's
``hyperparams/*.yml`` do: the env's own block if present, else ``default`` (blocks are not merged). Files are
parsed with a safe YAML loader, and ``policy_kwargs`` strings without ``eval``.
"""

from __future__ import annotations

import copy
import inspect
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np
import yaml
from stable_baselines3 import DDPG
from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise
from stable_baselines3.common.utils import LinearSchedule

from sb3_hddpg.algorithms import algorithm_class
from sb3_hddpg.artifacts.limits import (
    MAX_CONFIG_NODES,
    MAX_JSON_BYTES,
    LimitError,
    brief,
    count_nodes,
    read_file_bytes,
)
from sb3_hddpg.artifacts.network_limits import check_buffer_size, check_network_size
from sb3_hddpg.artifacts.values import (
    HYPERPARAMETERS,
    check_env_value,
    check_hyperparameters,
    check_train_freq,
    check_wrapper_settings,
)
from sb3_hddpg.envs.snake.controllers import CONTROLLERS
from sb3_hddpg.training.backends import BACKENDS
from sb3_hddpg.training.config_values import ConfigError, parse_policy_kwargs, parse_schedule

#: The bundled config, also reachable as ``zoo_configs/ddpg.yml`` in a checkout.
DEFAULT_CONFIG = Path(__file__).parent.parent / "zoo_configs" / "ddpg.yml"


def default_config(algo: str = "ddpg") -> Path:
    """
    The bundled config of an algorithm: ``sb3_hddpg/zoo_configs/<algo>.yml``.

    :param algo: ``ddpg``, ``td3``, ``sac`` or ``tqc``.
    """
    path = DEFAULT_CONFIG.parent / f"{algo.lower()}.yml"
    if not path.exists():
        known = sorted(p.stem for p in DEFAULT_CONFIG.parent.glob("*.yml"))
        raise ConfigError(f"No bundled config for algorithm {algo!r}; bundled: {known}")
    return path


def config_source(path: str | Path, run_dir: str | Path | None = None) -> str:
    """
    How a manifest names the config file a block was read from, with no path of this machine in it: a bundled
    config as ``sb3_hddpg/zoo_configs/<algo>.yml``, a relative path as given, any other absolute path relative
    to the run folder ``run_dir`` (by its file name without one).

    :param path: the config file the block was read from.
    :param run_dir: the run folder the manifest belongs to.
    """
    path = Path(path)
    if not path.is_absolute():
        return path.as_posix()
    if path.parent.resolve() == DEFAULT_CONFIG.parent.resolve():
        return f"sb3_hddpg/zoo_configs/{path.name}"
    if run_dir is None:
        return path.name
    return Path(os.path.relpath(path, Path(run_dir).absolute())).as_posix()


#: The config block of the manager's DDPG (it has no registered env id of its own).
MANAGER_KEY = "manager"

#: RL Zoo keys that are not algorithm arguments and that we interpret.
ZOO_KEYS = {
    "n_timesteps",
    "policy",
    "n_envs",
    "noise_type",
    "noise_std",
    "policy_kwargs",
    "env_kwargs",
    "callback",
}
#: The replay buffers a config's ``replay_buffer_class`` key may name (RL Zoo evaluates the string; we look
#: it up here). Their env-dependent arguments are filled in from the training env.
REPLAY_BUFFERS = ("GoalRelabelingReplayBuffer",)
#: The callbacks a config's ``callback`` key may name (RL Zoo imports any class path; we import none).
CALLBACKS = {
    "sb3_hddpg.callbacks.ActionL2Penalty": "action_l2",
    "sb3_hddpg.callbacks.ControllerPrior": "controller_prior",
}
#: Each callback's keyword arguments.
CALLBACK_KWARGS = {"action_l2": {"coefficient", "margin"}, "controller_prior": {"controller", "coefficient"}}
#: Our own keys (RL Zoo does not know them): ``backend`` picks the training backend, ``sb3`` or ``sbx``.
OWN_KEYS = {"backend"}
#: Keys of the manager block only: arguments of WorkerSelectionWrapper.
MANAGER_ONLY_KEYS = {"wrapper_kwargs"}
#: Algorithm arguments that the training code sets itself and a config must not.
RESERVED_KEYS = {"env", "seed", "device", "verbose", "tensorboard_log", "action_noise", "_init_setup_model"}


@dataclass
class Hyperparams:
    """
    One parsed config block.

    :param algo_kwargs: keyword arguments for the algorithm's constructor (``action_noise`` excluded).
    :param n_timesteps: the training budget.
    :param policy: the policy name.
    :param n_envs: parallel training environments.
    :param noise_type: ``"normal"``, ``"ornstein-uhlenbeck"`` or ``None``.
    :param noise_std: the exploration noise's standard deviation.
    :param env_kwargs: keyword arguments for ``gym.make``.
    :param wrapper_kwargs: manager block only: keyword arguments for ``WorkerSelectionWrapper``.
    :param action_l2: the coefficient of :class:`~sb3_hddpg.callbacks.ActionL2Penalty` (0: none).
    :param action_l2_margin: the penalty's pre-activation margin (``None``: it penalises the action itself).
    :param controller_prior: :class:`~sb3_hddpg.callbacks.ControllerPrior`'s ``(controller, coefficient)``.
    :param backend: the training backend the block asks for (``None``: not set).
    :param raw: the block as written, for manifests.
    """

    algo_kwargs: dict[str, Any]
    n_timesteps: int
    policy: str = "MlpPolicy"
    n_envs: int = 1
    noise_type: str | None = None
    noise_std: float = 0.1
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    wrapper_kwargs: dict[str, Any] = field(default_factory=dict)
    action_l2: float = 0.0
    action_l2_margin: float | None = None
    controller_prior: tuple[str, float] | None = None
    backend: str | None = None
    raw: dict[str, Any] = field(default_factory=dict)

    def model_kwargs(self, env: Any) -> dict[str, Any]:
        """
        The algorithm's constructor arguments for ``env``: the block's, with the action noise sized to the
        env and a named replay buffer resolved, its env-dependent arguments read from ``env``.

        :param env: the training env (or a ``VecEnv``'s single env, for the buffer's arguments).
        """
        kwargs = dict(self.algo_kwargs)
        if kwargs.get("replay_buffer_class") == "GoalRelabelingReplayBuffer":
            from sb3_hddpg.goal_relabeling import GoalRelabelingReplayBuffer  # only for a block that names it

            kwargs["replay_buffer_class"] = GoalRelabelingReplayBuffer
            kwargs["replay_buffer_kwargs"] = {
                **GoalRelabelingReplayBuffer.env_kwargs(env),
                **(kwargs.get("replay_buffer_kwargs") or {}),
            }
        if self.noise_type is not None:
            n_actions = int(np.prod(env.action_space.shape))
            noise = NormalActionNoise if self.noise_type == "normal" else OrnsteinUhlenbeckActionNoise
            kwargs["action_noise"] = noise(
                mean=np.zeros(n_actions), sigma=self.noise_std * np.ones(n_actions)
            )
        return kwargs

    def callbacks(self) -> list[Any]:
        """The SB3 callbacks the block asks for (as RL Zoo would build them from its ``callback`` key)."""
        # Each imported only when asked for: a block without an actor term never loads the actor-loss code.
        callbacks: list[Any] = []
        if self.action_l2 > 0:
            from sb3_hddpg.callbacks.action_penalty import ActionL2Penalty

            callbacks.append(ActionL2Penalty(self.action_l2, self.action_l2_margin))
        if self.controller_prior is not None:
            from sb3_hddpg.callbacks.controller_prior import ControllerPrior

            callbacks.append(ControllerPrior(*self.controller_prior))
        return callbacks


def load_config_file(path: str | Path) -> dict[str, Any]:
    """
    Read a config file with a safe YAML loader.

    :param path: a ``.yml`` file.
    :return: the mapping of block names to blocks.
    """
    path = Path(path)
    try:
        # A regular file within the limit, checked before reading (a FIFO would block, /dev/zero never end).
        text = read_file_bytes(path, MAX_JSON_BYTES + 1).decode("utf-8")
    except FileNotFoundError:
        raise ConfigError(f"Config file not found: {str(path)!r}") from None
    except (LimitError, IsADirectoryError, PermissionError, UnicodeDecodeError) as error:
        raise ConfigError(f"Cannot read config file {str(path)!r}: {error}") from None
    if len(text) > MAX_JSON_BYTES:
        raise ConfigError(
            f"Config file {str(path)!r} is {len(text)} characters, over the {MAX_JSON_BYTES} limit"
        )
    try:
        data = yaml.safe_load(text)
    except RecursionError:
        raise ConfigError(f"Invalid YAML in {str(path)!r}: nested too deeply") from None
    except yaml.YAMLError as error:
        where = getattr(error, "problem_mark", None)
        line = f" at line {where.line + 1}" if where is not None else ""
        problem = getattr(error, "problem", None) or type(error).__name__
        raise ConfigError(f"Invalid YAML in {str(path)!r}{line}: {problem}") from None
    # An alias bomb ("billion laughs") loads cheaply but expands to billions of values when copied.
    nodes = count_nodes(data)
    if nodes > MAX_CONFIG_NODES:
        raise ConfigError(
            f"Config file {str(path)!r} expands to more than {MAX_CONFIG_NODES} values (YAML aliases?); refused"
        )
    if not isinstance(data, dict) or not all(isinstance(v, dict) for v in data.values()):
        raise ConfigError(f"Expected {str(path)!r} to map env ids to blocks of hyperparameters")
    return data


def block_name(config: dict[str, Any], key: str | tuple[str, ...]) -> str | None:
    """The first of ``key`` (one or several, most specific first) in ``config``, else ``default`` (RL Zoo's rule)."""
    return next((k for k in ((key,) if isinstance(key, str) else key) + ("default",) if k in config), None)


def select_block(
    config: dict[str, Any], key: str | tuple[str, ...], source: str = "config"
) -> dict[str, Any]:
    """The block :func:`block_name` selects, as a deep copy."""
    name = block_name(config, key)
    if name is None:
        first = key if isinstance(key, str) else key[0]
        blocks = brief(sorted(map(str, config)))
        raise ConfigError(f"No block for {first!r} and no 'default' block in {source}; blocks: {blocks}")
    return copy.deepcopy(config[name])


def parse_block(
    block: dict[str, Any], algo_class: type, source: str = "config", manager: bool = False
) -> Hyperparams:
    """
    Validate a block and split it into constructor arguments and RL Zoo's extra keys.

    :param block: the block as read from YAML.
    :param algo_class: the SB3 algorithm the block is for (its constructor's parameters are allowed keys).
    :param source: a name for messages, e.g. ``"zoo_configs/ddpg.yml[hddpg/SnakeGoal-v0]"``.
    :param manager: whether ``wrapper_kwargs`` is allowed.
    :return: the parsed hyperparameters.
    """
    try:
        return _parse_block(block, algo_class, source, manager)
    except LimitError as error:  # a bound of the value schema: the config's own kind of error
        raise ConfigError(str(error)) from None


def _parse_block(block: dict[str, Any], algo_class: type, source: str, manager: bool) -> Hyperparams:
    _check_keys(block, algo_class, source, manager)
    raw = copy.deepcopy(block)
    if "n_timesteps" not in block:
        raise ConfigError(f"Missing key 'n_timesteps' in {source}")
    # Each _pop_* takes its key out of ``block``: what is left are the algorithm's constructor arguments.
    n_timesteps = HYPERPARAMETERS["n_timesteps"].check(block.pop("n_timesteps"), f"{source}: n_timesteps")
    n_envs = HYPERPARAMETERS["n_envs"].check(block.pop("n_envs", 1), f"{source}: n_envs")
    policy = _pop_choice(block, "policy", ("MlpPolicy",), source) or "MlpPolicy"
    noise_type = _pop_choice(block, "noise_type", ("normal", "ornstein-uhlenbeck"), source)
    backend = _pop_choice(block, "backend", BACKENDS, source)
    noise_std = float(HYPERPARAMETERS["noise_std"].check(block.pop("noise_std", 0.1), f"{source}: noise_std"))
    penalty = _parse_callbacks(block.pop("callback", None), source)
    action_l2 = float(cast(float, penalty.get("action_l2", 0.0)))
    env_kwargs = _pop_mapping(block, "env_kwargs", source)
    for key, value in env_kwargs.items():
        # The values here; the keys against the env's constructor where the env is known (check_make_kwargs).
        env_kwargs[key] = check_env_value(
            str(key), value, inspect.Parameter.empty, f"{source}: env_kwargs.{key}"
        )
    wrapper_kwargs = _pop_mapping(block, "wrapper_kwargs", source)
    check_wrapper_settings(wrapper_kwargs, source)
    _check_algo_kwargs(block, algo_class.__name__, source)
    check_hyperparameters(block, source)
    return Hyperparams(
        algo_kwargs=block,
        n_timesteps=n_timesteps,
        policy=policy,
        n_envs=n_envs,
        noise_type=noise_type,
        noise_std=noise_std,
        env_kwargs=env_kwargs,
        wrapper_kwargs=wrapper_kwargs,
        action_l2=action_l2,
        action_l2_margin=cast("float | None", penalty.get("action_l2_margin")),
        controller_prior=cast("tuple[str, float] | None", penalty.get("controller_prior")),
        backend=backend,
        raw=raw,
    )


def _check_keys(block: dict[str, Any], algo_class: type, source: str, manager: bool) -> None:
    """Refuse a key that is neither the algorithm's constructor argument nor one we interpret."""
    constructor = set(inspect.signature(algo_class).parameters) - {"self", "policy"} - RESERVED_KEYS
    allowed = constructor | ZOO_KEYS | OWN_KEYS | (MANAGER_ONLY_KEYS if manager else set())
    unknown = sorted(set(block) - allowed)
    if unknown:
        raise ConfigError(f"Unknown keys in {source}: {brief(unknown)} (allowed: {sorted(allowed)})")


def _pop_choice(block: dict[str, Any], key: str, choices: tuple[str, ...], source: str) -> str | None:
    """``block[key]`` (taken out), one of ``choices`` (or its lower case); ``None`` when absent or null."""
    value = block.pop(key, None)
    if value is None:
        return None
    text = value.strip() if isinstance(value, str) else ""
    if text not in choices and text.lower() not in choices:
        raise ConfigError(f"Unknown {key} in {source}: {brief(value)} (use one of {list(choices)})")
    return text if text in choices else text.lower()


def _pop_mapping(block: dict[str, Any], name: str, source: str) -> dict[str, Any]:
    """``env_kwargs`` or ``wrapper_kwargs``: a mapping, empty when absent or null."""
    value = block.pop(name, {}) or {}
    if not isinstance(value, dict):
        raise ConfigError(f"Expected {name} in {source} to be a mapping, actually: {brief(value)}")
    return value


def _check_algo_kwargs(block: dict[str, Any], algo: str, source: str) -> None:
    """
    Check the algorithm's constructor arguments that SB3 would accept unchecked or allocate from (network
    and buffer sizes), and put the YAML spellings into SB3's types, in place.
    """
    if "policy_kwargs" in block and isinstance(block["policy_kwargs"], str):
        block["policy_kwargs"] = parse_policy_kwargs(block["policy_kwargs"], source)
    _check_replay_buffer(block, source)
    # Networks too large to build ([65536, 65536] is 17 GB) are refused before SB3 allocates them.
    check_network_size(algo, block.get("policy_kwargs"), what=f"{source}: policy_kwargs")
    if "train_freq" in block:
        block["train_freq"] = check_train_freq(block["train_freq"], f"{source}: train_freq")
    if "buffer_size" in block:  # RL Zoo writes 1e6
        size = block["buffer_size"]
        block["buffer_size"] = size = int(size) if isinstance(size, float) and size.is_integer() else size
        # Bounded before SB3 allocates it; a 64-wide observation stands in for the dimensions not known yet.
        check_buffer_size(size, 64, 8, f"{source}: buffer_size")
    if isinstance(block.get("learning_rate"), str):
        block["learning_rate"] = parse_schedule(block["learning_rate"], "learning_rate", source)
    for key in ("learning_rate", "gamma", "tau"):
        allowed = (int, float, LinearSchedule) if key == "learning_rate" else (int, float)
        if key in block and not isinstance(block[key], allowed):
            raise ConfigError(f"Expected {key} in {source} to be a number, actually: {brief(block[key])}")


def _check_replay_buffer(block: dict[str, Any], source: str) -> None:
    """A named replay buffer must be one of :data:`REPLAY_BUFFERS`, with only the arguments it takes."""
    buffer = block.get("replay_buffer_class")
    if buffer is not None and buffer not in REPLAY_BUFFERS:
        raise ConfigError(
            f"Unknown replay_buffer_class {str(buffer)!r:.100} in {source}; allowed: {list(REPLAY_BUFFERS)}"
        )
    buffer_kwargs = block.get("replay_buffer_kwargs", {}) or {}
    if not isinstance(buffer_kwargs, dict) or set(buffer_kwargs) - {"relabel_fraction"}:
        raise ConfigError(
            f"Expected replay_buffer_kwargs in {source} to set only relabel_fraction, actually: {buffer_kwargs!r:.200}"
        )
    if "relabel_fraction" in buffer_kwargs:
        buffer_kwargs["relabel_fraction"] = HYPERPARAMETERS["relabel_fraction"].check(
            buffer_kwargs["relabel_fraction"], f"{source}: replay_buffer_kwargs.relabel_fraction"
        )


def _parse_callbacks(value: object, source: str) -> dict[str, object]:
    """
    RL Zoo's ``callback`` key (a class path, or a list of paths or ``{path: kwargs}``), restricted to
    :data:`CALLBACKS`: the settings they carry, e.g. ``{"action_l2": 0.1}`` (and ``action_l2_margin``
    when given), ``{"controller_prior": ("ik", 5.0)}``. Nothing is imported.
    """
    settings: dict[str, object] = {}
    kwargs: Any
    for entry in [] if value is None else value if isinstance(value, list) else [value]:
        if not isinstance(entry, str) and not (isinstance(entry, dict) and len(entry) == 1):
            raise ConfigError(
                f"Expected callback entries in {source} to be class paths or {{path: kwargs}}, actually: {entry!r:.200}"
            )
        path, kwargs = (entry, {}) if isinstance(entry, str) else next(iter(entry.items()))
        if path not in CALLBACKS:
            raise ConfigError(
                f"Unknown callback {str(path)!r:.200} in {source}; allowed: {sorted(CALLBACKS)}"
            )
        name, kwargs = CALLBACKS[path], kwargs or {}
        if not isinstance(kwargs, dict) or set(kwargs) - CALLBACK_KWARGS[name]:
            raise ConfigError(
                f"Expected {path} in {source} to take only {sorted(CALLBACK_KWARGS[name])}, actually: "
                f"{kwargs!r:.200}"
            )
        default = 0.1 if name == "action_l2" else 1.0
        check = HYPERPARAMETERS["coefficient"].check
        coefficient = float(check(kwargs.get("coefficient", default), f"{source}: {path}.coefficient"))
        if name == "controller_prior":
            controller = kwargs.get("controller", "ik")
            if not isinstance(controller, str) or controller not in CONTROLLERS:  # a YAML list is unhashable
                raise ConfigError(
                    f"Unknown controller {brief(controller)} in {source}: {path}; choose from {sorted(CONTROLLERS)}"
                )
            if coefficient > 0:
                settings[name] = (str(controller), coefficient)
            continue
        settings[name] = coefficient
        if kwargs.get("margin") is not None:
            margin = HYPERPARAMETERS["margin"].check(kwargs["margin"], f"{source}: {path}.margin")
            settings[f"{name}_margin"] = float(margin)
    return settings


def load_hyperparams(
    key: str | tuple[str, ...], algo_class: type, path: str | Path | None = None, manager: bool = False
) -> Hyperparams:
    """
    Load, select and validate the block for ``key`` (an env id or ``"manager"``).

    :param key: the block to use, or several: the first the file holds (:func:`select_block`).
    :param algo_class: the algorithm the block configures.
    :param path: the config file; the bundled ``zoo_configs/ddpg.yml`` by default.
    :param manager: whether this is the manager's block.
    """
    path = Path(path) if path is not None else DEFAULT_CONFIG
    config = load_config_file(path)
    block = select_block(config, key, source=str(path))
    return parse_block(block, algo_class, source=f"{path}[{block_name(config, key)}]", manager=manager)


def agent_kwargs(
    key: str, env: object, config: str | Path | None = None, algo_class: type | None = None
) -> dict[str, Any]:
    """
    The project's hyperparameters for one agent, as keyword arguments of the algorithm's constructor, so
    that the Python API trains with what the CLI uses rather than SB3's defaults (the budget and the block's
    ``env_kwargs`` are not applied here)::

        goal = DDPG(**agent_kwargs("hddpg/SnakeGoal-v0", gym.make("hddpg/SnakeGoal-v0")))

    :param key: the config block: an env id (``hddpg/SnakeGoal-v0``...) or ``"manager"``.
    :param env: the training env (it sizes the action noise and is passed on as ``env``).
    :param config: a ``zoo_configs``-format file (default: the bundled ``ddpg.yml``).
    :param algo_class: the algorithm whose constructor the block must fit (default: SB3's ``DDPG``).
    :return: ``policy``, ``env``, the block's algorithm arguments and ``action_noise``; add ``seed`` etc.
    """
    if algo_class is None:
        algo_class = DDPG
    hyperparams = load_hyperparams(key, algo_class, config, manager=key == MANAGER_KEY)
    return {"policy": hyperparams.policy, "env": env, **hyperparams.model_kwargs(env)}


def agent_callbacks(key: str, config: str | Path | None = None) -> list[Any]:
    """
    The SB3 callbacks a config block asks for, to pass to ``learn`` with :func:`agent_kwargs`'s model.

    :param key: the config block: an env id or ``"manager"``.
    :param config: a ``zoo_configs``-format file (default: the bundled ``ddpg.yml``).
    """
    return load_hyperparams(key, DDPG, config, manager=key == MANAGER_KEY).callbacks()


def wrapper_kwargs(config: str | Path | None = None, algo: str = "ddpg") -> dict[str, Any]:
    """
    The manager block's ``wrapper_kwargs``: keyword arguments for ``WorkerSelectionWrapper`` and
    ``SelectionConfig``, as the CLI's manager gets them.

    :param config: a ``zoo_configs``-format file (default: the bundled config of ``algo``).
    :param algo: the manager's algorithm.
    """
    return dict(manager_hyperparams(algo, config).wrapper_kwargs)


def manager_hyperparams(algo: str = "ddpg", config: str | Path | None = None) -> Hyperparams:
    """
    The ``manager`` block a manager of ``algo`` trains from.

    :param algo: the manager's algorithm.
    :param config: a ``zoo_configs``-format file (default: ``algo``'s bundled one).
    """
    return load_hyperparams(MANAGER_KEY, algorithm_class(algo), config or default_config(algo), manager=True)

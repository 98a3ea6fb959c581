"""
What a new :class:`~sb3_hddpg.hierarchy.hierarchy.Hierarchy` takes from its models (the selection settings
of the wrapper its manager trained on, the env each model was trained on), what its manager observes, and the
checks that its models fit its env.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import gymnasium as gym
import numpy as np

from sb3_hddpg.artifacts.workers import reward_specs_of, states_of
from sb3_hddpg.envs.contract import state_layout_of
from sb3_hddpg.envs.headless import rendering_errors
from sb3_hddpg.envs.layout import StateLayout
from sb3_hddpg.hierarchy.manager_input import ManagerInput, subset_space
from sb3_hddpg.hierarchy.selection import SelectionConfig, check_preferences, get_selector
from sb3_hddpg.hierarchy.wrapper import WorkerSelectionWrapper
from sb3_hddpg.policy import Policy


def training_env(model: object) -> tuple[str, dict[str, Any]] | None:
    """``(env_id, env_kwargs)`` of an SB3 model's training env (kwargs beyond the registered ones), if it still
    has one."""
    get_env = getattr(model, "get_env", None)
    vec_env = get_env() if callable(get_env) else None
    if vec_env is None:
        return None
    try:
        envs = getattr(vec_env, "envs", None)  # in-process envs: read the spec without copying it
        spec = envs[0].unwrapped.spec if envs else vec_env.get_attr("spec", [0])[0]
    except Exception:  # an env in a subprocess that cannot answer: the model does not tell
        return None
    if spec is None:
        return None
    registered = gym.spec(spec.id).kwargs if spec.id in gym.registry else {}
    kwargs = {
        key: value
        for key, value in (spec.kwargs or {}).items()
        if key != "render_mode" and (key not in registered or registered[key] != value)
    }
    return spec.id, kwargs


def probe_env(env_id: str, env_kwargs: dict[str, Any]) -> tuple[StateLayout, gym.Space, gym.Space]:
    """``(layout, observation_space, action_space)`` of a hierarchy's env, from one env made for the purpose."""
    with rendering_errors():  # MuJoCo's OpenGL may fail on import: a problem of this machine, not the bundle
        probe = gym.make(env_id, **env_kwargs)
    layout = state_layout_of(probe)
    observation_space, action_space = probe.observation_space, probe.action_space
    probe.close()
    return layout, observation_space, action_space


def selection_config_of(
    manager: object, workers: Mapping[str, Policy], config: SelectionConfig | None
) -> SelectionConfig:
    """
    The selection settings of a new hierarchy: ``config``, else those of the ``WorkerSelectionWrapper`` the
    manager was trained on (if it still has its env), else the wrapper's defaults; the state components the
    workers carry are the default of ``worker_states`` either way.
    """
    if config is None:
        wrapper = selection_wrapper(manager)
        if wrapper is not None:
            return wrapper.selection_config()
        config = SelectionConfig(preferences=check_preferences({}, list(workers)))
    carried = {name: states for name, states in states_of(workers).items() if name in workers}
    if carried:
        config = replace(config, worker_states={**carried, **config.worker_states})
    rewards = reward_specs_of(workers)
    return replace(config, reward_terms={**rewards, **config.reward_terms}) if rewards else config


def selection_wrapper(manager: object) -> WorkerSelectionWrapper | None:
    """The ``WorkerSelectionWrapper`` a manager trains on, if it still has an in-process env."""
    get_env = getattr(manager, "get_env", None)
    vec_env = get_env() if callable(get_env) else None
    env = (getattr(vec_env, "envs", None) or [None])[0]
    while isinstance(env, gym.Wrapper):
        if isinstance(env, WorkerSelectionWrapper):
            return env
        env = env.env
    return None


def manager_input_of(
    config: SelectionConfig, observation_space: gym.Space, layout: StateLayout, n_workers: int
) -> ManagerInput:
    """What a manager with these selection settings observes of the shared env's ``observation_space``."""
    indices = layout.indices(config.manager_state) if config.manager_state else None
    n_preferences = n_workers if config.manager_preferences is not None else 0
    return ManagerInput(observation_space, indices, config.manager_motion, n_preferences)


def check_spaces(
    manager: Any,
    workers: Mapping[str, Policy],
    config: SelectionConfig,
    observation_space: gym.Space,
    action_space: gym.Space,
    layout: StateLayout,
    env_name: str,
) -> None:
    """
    Check that the manager and every worker that declares its spaces fit the env (named ``env_name``), each
    seeing its components of the state: a one-line ``ValueError`` naming the model and both spaces otherwise.
    """

    def subset(components: list[str] | None) -> gym.Space:
        return subset_space(observation_space, layout.indices(components) if components else None)

    checks = []
    if manager is not None:  # a GPI hierarchy has none
        manager_action = get_selector(config.selection).action_space(len(workers))
        manager_obs = manager_input_of(config, observation_space, layout, len(workers)).observation_space
        checks.append(("The manager", manager, manager_obs, manager_action, " (one per worker)"))
    checks += [
        (f"Worker {name!r}", worker, subset(config.worker_states.get(name)), action_space, "")
        for name, worker in workers.items()
    ]
    hint = "pass the env they were trained on as env_id= (and env_kwargs=)"
    for label, model, expected_obs, expected_action, action_note in checks:
        for kind, expected, actual, note in (
            ("observations", expected_obs, getattr(model, "observation_space", None), ""),
            ("actions", expected_action, getattr(model, "action_space", None), action_note),
        ):
            if actual is None or actual == expected:
                continue
            if getattr(actual, "shape", None) != getattr(expected, "shape", None):
                raise ValueError(
                    f"{label} has {kind} of shape {actual.shape}, but the hierarchy's env {env_name} needs "
                    f"{expected.shape}{note}: {hint}"
                )
            raise ValueError(
                f"{label} has {kind} of shape {actual.shape} like the hierarchy's env {env_name}, but "
                f"{space_difference(actual, expected)}: {hint}"
            )


def space_difference(actual: gym.Space, expected: gym.Space) -> str:
    """
    The first difference of two spaces of one shape, short enough for one line whatever their size: the
    type, the dtype, or the first bound that differs with its index.
    """
    if type(actual) is not type(expected):
        return f"a {type(actual).__name__} space where it needs a {type(expected).__name__}"
    if getattr(actual, "dtype", None) != getattr(expected, "dtype", None):
        return f"dtype {getattr(actual, 'dtype', None)} where it needs {getattr(expected, 'dtype', None)}"
    if isinstance(actual, gym.spaces.Box) and isinstance(expected, gym.spaces.Box):
        for bound in ("low", "high"):
            mine, theirs = getattr(actual, bound).ravel(), getattr(expected, bound).ravel()
            differs = np.flatnonzero(~((mine == theirs) | (np.isnan(mine) & np.isnan(theirs))))
            if differs.size:
                i = int(differs[0])
                return (
                    f"{bound}[{i}] = {mine[i]:g} where it needs {theirs[i]:g} ({differs.size} of {mine.size} "
                    f"{bound} bounds differ)"
                )
    shown = " ".join(f"{actual} != {expected}".split())
    return f"other bounds ({shown[:300]})"

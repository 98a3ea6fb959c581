"""
The checks that a hierarchy's models fit its env: what a manager observes of the shared env
(:func:`manager_input_of`) and :func:`check_spaces`, one line naming the model, the expected and the actual space.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import gymnasium as gym

from sb3_hddpg.envs.layout import StateLayout
from sb3_hddpg.hierarchy.manager_input import ManagerInput, subset_space
from sb3_hddpg.hierarchy.selection import SelectionConfig, get_selector
from sb3_hddpg.policy import Policy


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
    Check that the manager and every worker that declares its spaces fit the env: the manager sees the
    env's observation (or its ``manager_state`` components) and outputs one value per worker; each worker
    sees the env's observation (or its ``worker_states`` components) and outputs the env's action.

    :param env_name: the env as named in messages.
    :raises ValueError: one line naming the model, the expected and the actual space.
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
            # A Box with per-entry bounds prints its arrays over several lines: keep the message on one.
            shown = " ".join(f"{actual} != {expected}".split())
            raise ValueError(
                f"{label} has {kind} of shape {actual.shape} like the hierarchy's env {env_name}, but other "
                f"bounds or dtype ({shown}): {hint}"
            )

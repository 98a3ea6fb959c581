"""
The HAM baseline (paper Section 3.3): a hand-written switch between the same two trained workers.

Parr & Russell's Hierarchical Abstract Machines choose lower-level machines by hand-designed transitions.
The paper's HAM for the snake arm has one transition condition: the sum of the distances from the arm to
the obstacles. Below a threshold the avoid worker acts, otherwise the goal worker. Nothing is trained: the
switch is a policy like any other (SB3's ``predict``), so ``evaluate``, the benchmark and even a manager
(as a worker of :class:`~sb3_hddpg.hierarchy.wrapper.WorkerSelectionWrapper`) can use it.

The distance signal is the observation's ``joint_obstacle_distances``: per link, its clearance to the
closest obstacle surface divided by the env's ``sensor_range`` and clipped to ``[0, 1]``. A link with no
obstacle within sensor range contributes 1, so with ``n`` links the sum lies in ``[0, n]`` and
``n - sum`` measures how far obstacles have entered the arm's sensed neighbourhood.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from sb3_hddpg.artifacts.io import atomic_write_json
from sb3_hddpg.artifacts.manifests import load_workers
from sb3_hddpg.artifacts.records.ham import HamFile, ham_file, read_ham_file
from sb3_hddpg.envs.contract import state_layout_of
from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID
from sb3_hddpg.envs.layout import StateLayout
from sb3_hddpg.policy import Policy
from sb3_hddpg.policy_loaders import LoadedPolicy

#: The component of the shared state that the switch reads.
DISTANCE_COMPONENT = "joint_obstacle_distances"
#: The default switching margin: the avoid worker takes over once the summed normalised clearance is
#: this far below its maximum ``n_joints``, i.e. one link at half the sensor range from an obstacle
#: surface (0.15 reach units by default, about one link length), or several links a little inside it.
#: That is where the avoid reward starts to be lost (it pays clearance up to the sensor range) but
#: before contact, which the arm cannot undo within one step at full joint speed.
DEFAULT_MARGIN = 0.5
#: Spacing of the thresholds a sweep of the switch tries (:meth:`HAMSwitch.threshold_grid`).
THRESHOLD_STEP = 0.25


class HAMSwitch:
    """
    Switch between a goal worker and an avoid worker on the summed joint-to-obstacle distance.

    With ``s`` the sum of ``joint_obstacle_distances`` in the observation: the avoid worker acts when
    ``s < threshold``; with ``hysteresis = h > 0`` it keeps acting until ``s >= threshold + h``, so the arm
    does not chatter between the workers at the boundary. Without hysteresis every step decides anew.

    :param goal_worker: the policy that reaches for the goal.
    :param avoid_worker: the policy that keeps clear of obstacles.
    :param layout: the env's ``state_layout`` (to find the distances in the observation).
    :param threshold: the switching threshold on the summed distances, in ``[0, n_joints]`` (default:
        ``n_joints - DEFAULT_MARGIN``).
    :param hysteresis: the extra distance needed to switch back to the goal worker, >= 0.
    :param names: the display names of the two workers, as ``(goal, avoid)``; they are what
        ``last_selection`` reports.
    :param worker_states: worker name -> the state components it was trained on (env kwarg ``observe``);
        missing workers see the whole state.
    """

    def __init__(
        self,
        goal_worker: Policy,
        avoid_worker: Policy,
        layout: StateLayout,
        threshold: float | None = None,
        hysteresis: float = 0.0,
        names: tuple[str, str] = ("goal", "avoid"),
        worker_states: Mapping[str, Sequence[str]] | None = None,
    ) -> None:
        self._slice = layout[DISTANCE_COMPONENT]
        n_links = self._slice.stop - self._slice.start
        if threshold is None:
            threshold = n_links - DEFAULT_MARGIN
        if not math.isfinite(threshold) or not 0.0 <= threshold <= n_links:
            raise ValueError(
                f"Expected `threshold` in [0, {n_links}] (the range of the summed distances), actually: {threshold}"
            )
        if not math.isfinite(hysteresis) or hysteresis < 0:
            raise ValueError(f"Expected `hysteresis` to be a finite number >= 0, actually: {hysteresis}")
        if len(names) != 2 or names[0] == names[1]:
            raise ValueError(f"Expected two distinct worker names (goal, avoid), actually: {names}")
        self.workers: dict[str, Policy] = {names[0]: goal_worker, names[1]: avoid_worker}
        worker_states = dict(worker_states or {})
        unknown = sorted(set(worker_states) - set(names))
        if unknown:
            raise ValueError(f"worker_states names unknown workers {unknown}; workers: {list(names)}")
        # Each worker sees the state components it was trained on (all of them by default).
        self._worker_indices = {n: layout.indices(c) for n, c in worker_states.items()}
        self.names = list(names)
        self.layout = layout
        self.threshold = float(threshold)
        self.hysteresis = float(hysteresis)
        # The switch takes the full state: declare the spaces of a worker that sees all of it.
        full_view = [w for n, w in self.workers.items() if n not in self._worker_indices]
        for attribute in ("observation_space", "action_space"):
            if attribute == "observation_space" and not full_view:
                continue  # no worker declares the full state's space
            source = full_view[0] if attribute == "observation_space" else goal_worker
            if hasattr(source, attribute):
                setattr(self, attribute, getattr(source, attribute))
        # One flag per observation stream: whether the avoid worker is acting (hysteresis needs memory).
        self._avoiding = np.zeros(1, dtype=bool)
        self.last_selection: str | None = None

    def threshold_grid(self, from_zero: bool = False) -> list[float]:
        """
        The thresholds a sweep of this switch tries: every :data:`THRESHOLD_STEP` up to the number of links
        (24 for six), the range of the summed distances.

        :param from_zero: start at 0 (the goal worker in every state), as a front does; else at the first
            step, as a tuning that picks one threshold does.
        :return: the thresholds, increasing.
        """
        n_links = self._slice.stop - self._slice.start
        first = 0 if from_zero else 1
        return [step * THRESHOLD_STEP for step in range(first, round(n_links / THRESHOLD_STEP) + 1)]

    @property
    def reward_spec(self) -> dict[str, float]:
        """This switch's reward as a worker of a manager: goal and avoid in equal parts (it serves both)."""
        return {"goal": 1.0, "avoid": 1.0}

    def summed_distance(self, observation: np.ndarray) -> np.ndarray:
        """The summed normalised joint-to-obstacle distances of one observation or a batch."""
        return np.asarray(observation, dtype=np.float64)[..., self._slice].sum(axis=-1)

    def select(self, observation: np.ndarray) -> np.ndarray:
        """
        Which worker acts on each observation (``True``: avoid), updating the hysteresis memory.

        :param observation: shape ``(obs_dim,)`` or ``(batch, obs_dim)``.
        :return: a boolean array of shape ``(batch,)`` (``(1,)`` for a single observation).
        """
        distances = np.atleast_1d(self.summed_distance(observation))
        if self._avoiding.shape != distances.shape:
            self._avoiding = np.zeros(distances.shape, dtype=bool)
        enter = distances < self.threshold
        stay = self._avoiding & (distances < self.threshold + self.hysteresis)
        self._avoiding = enter | stay
        return self._avoiding.copy()

    def reset_episode(self, mask: np.ndarray | None = None) -> None:
        """
        Forget the hysteresis state (at an episode start), for every stream or those where ``mask`` is true.
        """
        if mask is None or np.shape(mask) != self._avoiding.shape:
            self._avoiding[:] = False
        else:
            self._avoiding[np.asarray(mask, dtype=bool)] = False
        for worker in self.workers.values():
            reset = getattr(worker, "reset_episode", None)
            if reset is not None:
                reset()

    def predict(
        self,
        observation: np.ndarray,
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, None]:
        """
        The action of the worker the switch selects, like SB3's ``predict``.

        :param observation: the shared state, shape ``(obs_dim,)`` or ``(batch, obs_dim)``; each row of a
            batch is its own stream with its own hysteresis memory.
        :param state: unused, for SB3 compatibility.
        :param episode_start: true entries reset those streams' hysteresis memory first.
        :param deterministic: passed to the workers.
        :return: the env action(s) and ``None``.
        """
        obs = np.asarray(observation, dtype=np.float32)
        if episode_start is not None and np.any(episode_start):
            self.reset_episode(np.atleast_1d(np.asarray(episode_start)))
        avoiding = self.select(obs)
        goal, avoid = (self.workers[n] for n in self.names)
        batch = obs if obs.ndim == 2 else obs[None]
        actions: np.ndarray | None = None
        for flag, name, worker in ((False, self.names[0], goal), (True, self.names[1], avoid)):
            rows = avoiding == flag
            if rows.any():
                view = batch[rows]
                if name in self._worker_indices:
                    view = view[:, self._worker_indices[name]]
                chosen = self._act(worker, view, deterministic)
                if actions is None:
                    actions = np.empty((len(batch), chosen.shape[1]), dtype=np.float32)
                actions[rows] = chosen
        assert actions is not None  # every row went to one of the two workers
        self.last_selection = self.names[int(avoiding[-1])]
        return (actions if obs.ndim == 2 else actions[0]), None

    @staticmethod
    def _act(worker: Policy, batch: np.ndarray, deterministic: bool) -> np.ndarray:
        action, _ = worker.predict(batch, deterministic=deterministic)
        return np.asarray(action, dtype=np.float32).reshape(len(batch), -1)


def save_ham(
    path: str | os.PathLike[str],
    workers_manifest: str | os.PathLike[str],
    threshold: float,
    hysteresis: float = 0.0,
    names: tuple[str, str] = ("goal", "avoid"),
    env_id: str = SNAKE_REACH_ENV_ID,
    env_kwargs: Mapping[str, Any] | None = None,
    metadata: Mapping[str, Any] | None = None,
) -> Path:
    """
    Write ``ham.json``: the switch's settings and where its workers are, relative to the json file.

    :param path: the json file to write.
    :param workers_manifest: the ``workers/manifest.json`` written by ``train_workers``.
    :param threshold: the switching threshold.
    :param hysteresis: the switching hysteresis.
    :param names: the goal and avoid worker names in that manifest.
    :param env_id: the env the switch acts in.
    :param env_kwargs: that env's keyword arguments.
    :param metadata: more JSON-able facts (seed, metrics...).
    :return: the path written.
    """
    path = Path(path)
    manifest = Path(workers_manifest)
    relative = os.path.relpath(manifest.resolve(), path.parent.resolve())
    record = ham_file(threshold, hysteresis, names, Path(relative).as_posix(), env_id, env_kwargs, metadata)
    return atomic_write_json(path, record.to_json())


def load_ham(
    path: str | os.PathLike[str], trusted: bool = False, allowed_env_ids: Sequence[str] | None = None
) -> tuple[HAMSwitch, HamFile]:
    """
    Load a switch written by :func:`save_ham`; its workers are verified and loaded by
    :func:`~sb3_hddpg.artifacts.manifests.load_workers` (weights only unless ``trusted``). Every field is
    checked first (:func:`~sb3_hddpg.artifacts.records.ham.read_ham_file`): the env id must be registered and
    allowed, the workers manifest a ``manifest.json`` path, the names plain names.

    :param path: the ``ham.json`` file.
    :param trusted: load the workers with SB3's full loader, and accept any registered env id.
    :param allowed_env_ids: registered env ids the file may name besides this package's own.
    :return: the switch and the file's record (:class:`~sb3_hddpg.artifacts.records.ham.HamFile`).
    """
    path = Path(path)
    meta = read_ham_file(path, trusted, allowed_env_ids)
    names = meta.names
    manifest = (path.parent / meta.workers_manifest).resolve()
    workers = load_workers(manifest.parent, names, trusted=trusted)
    env = gym.make(meta.env_id, **meta.env_kwargs)
    layout = state_layout_of(env)
    env.close()
    switch = HAMSwitch(
        workers[names[0]],
        workers[names[1]],
        layout,
        threshold=meta.threshold,
        hysteresis=meta.hysteresis,
        names=names,
        worker_states=workers.states,
    )
    return switch, meta


def load_ham_policy(path: Path, trusted: bool, allowed_env_ids: Sequence[str] | None) -> LoadedPolicy:
    """A ``ham.json`` as a policy with its env (the loader :mod:`sb3_hddpg.policy_loaders` registers for ``.json``)."""
    ham, meta = load_ham(path, trusted=trusted, allowed_env_ids=allowed_env_ids)
    return LoadedPolicy(ham, meta.env_id, dict(meta.env_kwargs), "ham", Path(path).stem, meta.to_json())

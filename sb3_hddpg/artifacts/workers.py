"""``Workers``: trained workers as loaded, each with the state components it sees, and their shared env."""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
from stable_baselines3.common.base_class import BaseAlgorithm

from sb3_hddpg.artifacts.limits import check_env_id
from sb3_hddpg.artifacts.records import ModelsManifest
from sb3_hddpg.artifacts.term_critic import TermCritic
from sb3_hddpg.artifacts.values import check_env_kwargs
from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID

#: The facts of a workers-manifest entry a bundle keeps about each worker.
BUNDLED_FACTS = ("reward_term", "reward_weights", "reward_bounds", "env_id", "metrics", "seed")


@dataclass(frozen=True)
class Workers(Mapping[str, BaseAlgorithm]):
    """
    Name -> trained worker (an SB3 model), in the manager's action order, as
    :func:`~sb3_hddpg.artifacts.manifests.load_workers` returns them: a read-only mapping that also knows the
    state components each worker saw in training and the shared env the manager acts in (:meth:`make_env`),
    so that ``Hierarchy(manager, workers)`` needs nothing more.

    :param models: name -> loaded model, in order.
    :param states: name -> the state components that worker sees (absent: the full state).
    :param env_id: the shared env's registered id (``None``: the manifest's is not usable, see ``env_problem``).
    :param env_kwargs: its keyword arguments.
    :param manifest: the workers manifest the models were loaded from.
    :param folder: the folder holding that manifest.
    :param env_problem: why the manifest's shared env is not usable, raised by :meth:`make_env`.
    :param critics: name -> the worker's per-term critic, for the workers that have one.
    """

    models: dict[str, BaseAlgorithm]
    states: dict[str, list[str]] = field(default_factory=dict)
    env_id: str | None = SNAKE_REACH_ENV_ID
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    manifest: ModelsManifest = field(default_factory=lambda: ModelsManifest("workers"))
    folder: Path | None = None
    env_problem: str = ""
    critics: dict[str, TermCritic] = field(default_factory=dict)

    def __getitem__(self, name: str) -> BaseAlgorithm:
        return self.models[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self.models)

    def __len__(self) -> int:
        return len(self.models)

    def __repr__(self) -> str:
        return f"Workers({list(self.models)}, env_id={self.env_id!r}, folder={str(self.folder)!r})"

    def make_env(self, **overrides: object) -> gym.Env:
        """
        The shared env as the workers were trained for it: ``gym.make(env_id, **env_kwargs)``.

        :param overrides: keyword arguments over ``env_kwargs`` (e.g. ``render_mode="rgb_array"``).
        """
        if self.env_id is None:
            raise ValueError(self.env_problem or "These workers name no shared env: make it yourself")
        return gym.make(self.env_id, **{**self.env_kwargs, **overrides})

    def bundle_meta(self) -> dict[str, dict[str, object]]:
        """Name -> the facts a bundle keeps about each worker, with ``source_sha256``, its file's hash."""
        entries = self.manifest.entries
        meta: dict[str, dict[str, object]] = {}
        for name in self.models:
            entry: Mapping[str, object] = entries.get(name, {})
            facts = {key: entry[key] for key in BUNDLED_FACTS if key in entry}
            if "sha256" in entry:
                facts["source_sha256"] = entry["sha256"]
            meta[name] = facts
        return meta


def shared_env_of(
    manifest: ModelsManifest,
    env_id: str | None,
    env_kwargs: Mapping[str, object] | None,
    trusted: bool = False,
    allowed_env_ids: Sequence[str] | None = None,
) -> tuple[str, dict[str, Any]]:
    """
    The shared env a manager over these workers acts in: ``env_id`` if given, else the manifest's
    ``shared_env`` (checked as any env read from a file), else the snake arm's.

    :param manifest: the workers manifest.
    :param env_id: an env id given by the caller, which wins.
    :param env_kwargs: keyword arguments given by the caller, over the manifest's.
    :param trusted: accept any registered env id.
    :param allowed_env_ids: registered env ids the manifest may name besides this package's own.
    :return: the env id and its keyword arguments.
    """
    if env_id is not None:
        return env_id, dict(env_kwargs or {})
    shared = manifest.shared_env
    if shared is None:
        return SNAKE_REACH_ENV_ID, dict(env_kwargs or {})
    found = check_env_id(
        shared.get("env_id"), "workers manifest: shared_env.env_id", allowed_env_ids, trusted=trusted
    )
    kwargs = check_env_kwargs(
        found,
        shared.get("env_kwargs"),
        "workers manifest: shared_env.env_kwargs",
        allowed_env_ids,
        trusted=trusted,
    )
    return found, {**kwargs, **(env_kwargs or {})}


def observed_components(manifest: ModelsManifest, names: Iterable[str]) -> dict[str, list[str]]:
    """
    The state components each worker was trained on, from its entry's ``env_kwargs["observe"]``.

    :param manifest: a workers manifest.
    :param names: the workers to look at.
    :return: name -> component names, for the workers trained on part of the state only.
    """
    out: dict[str, list[str]] = {}
    for name in names:
        env_kwargs = manifest.entries[name].get("env_kwargs") or {}
        observe = env_kwargs.get("observe") if isinstance(env_kwargs, dict) else None
        if observe is not None:
            if not isinstance(observe, list) or not all(isinstance(c, str) for c in observe):
                raise ValueError(
                    f"Worker {name!r}: env_kwargs.observe must be a list of names, actually: {observe!r:.200}"
                )
            out[name] = list(observe)
    return out


def states_of(workers: Mapping[str, object]) -> dict[str, list[str]]:
    """The state components each worker of ``workers`` sees, where it carries them (a :class:`Workers`)."""
    return dict(workers.states) if isinstance(workers, Workers) else {}


def reward_specs_of(workers: Mapping[str, object]) -> dict[str, dict[str, float]]:
    """
    The reward of each weighted worker of ``workers`` (term -> weight), where they carry their manifest (a
    :class:`Workers`); a per-term worker's reward is its name, so it is absent.

    :raises ValueError: one line naming the worker whose recorded ``reward_weights`` are not term -> number.
    """
    if not isinstance(workers, Workers):
        return {}
    specs: dict[str, dict[str, float]] = {}
    for name in workers:
        weights = workers.manifest.entries.get(name, {}).get("reward_weights")
        if weights is None:
            continue
        if not isinstance(weights, dict) or not all(
            isinstance(t, str) and isinstance(v, (int, float)) and not isinstance(v, bool)
            for t, v in weights.items()
        ):
            raise ValueError(
                f"Worker {name!r}: reward_weights must map term names to numbers, actually: {weights!r:.200}"
            )
        specs[name] = {t: float(v) for t, v in weights.items()}
    return specs

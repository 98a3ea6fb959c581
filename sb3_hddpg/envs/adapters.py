"""
Adapters: any Gymnasium env with several objectives as an env of the contract (:mod:`sb3_hddpg.envs.contract`).

:class:`MultiObjectiveEnv` (``hddpg/MultiObjective-v0``) adapts an MO-Gymnasium env (a vector reward and its
``reward_space``), :class:`InfoTermsEnv` (``hddpg/InfoTerms-v0``) an env that reports per-term rewards in
``info``. Both are made by id, so a manifest's env id and keyword arguments rebuild them::

    env = gym.make("hddpg/MultiObjective-v0", env_id="mo-mountaincarcontinuous-v0", terms=["time", "fuel"])
"""

from __future__ import annotations

import contextlib
import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any, SupportsFloat, TypeAlias

import gymnasium as gym
import numpy as np
from gymnasium.core import RenderFrame
from gymnasium.envs.registration import EnvSpec
from numpy.typing import NDArray

from sb3_hddpg.envs.contract import TermNormaliser, check_bounds, env_contract
from sb3_hddpg.envs.mujoco_log import route_mujoco_warnings

MULTI_OBJECTIVE_ENV_ID = "hddpg/MultiObjective-v0"
INFO_TERMS_ENV_ID = "hddpg/InfoTerms-v0"
#: The adapter ids, each with the keyword ``env_id`` naming the env it adapts.
ADAPTER_ENV_IDS = (MULTI_OBJECTIVE_ENV_ID, INFO_TERMS_ENV_ID)
#: Steps of the random-policy rollout that estimates bounds a ``reward_space`` leaves infinite.
ESTIMATE_STEPS = 2000
#: How far estimated bounds are widened beyond the range seen, as a fraction of it (a trained policy
#: reaches values a random one did not).
ESTIMATE_MARGIN = 0.25
MAX_TERMS = 32
#: A step's reward as the adapted env returns it: a number or an MO-Gymnasium vector.
RawReward: TypeAlias = SupportsFloat | NDArray[np.floating]


class EnvUnavailableError(ValueError):
    """An env that cannot be made here because an optional package it needs (highway-env, MuJoCo...) is missing."""


def registered_env_id(env_id: object) -> str:
    """``env_id`` if it is a registered id without a ``module:`` prefix, else a ``ValueError``."""
    if not isinstance(env_id, str) or ":" in env_id:
        raise ValueError(
            f"Expected `env_id` to be a registered env id without a module prefix, actually: {env_id!r}"
        )
    if env_id not in gym.registry:
        # Lazily: MO-Gymnasium is optional (the `mo` extra); it registers its ids when imported.
        with contextlib.suppress(ImportError):
            import mo_gymnasium  # noqa: F401
    if env_id not in gym.registry:
        raise ValueError(
            f"Expected `env_id` to be a registered env id, actually: {env_id!r} is not registered"
        )
    return env_id


def make_adapted(
    env_id: str, render_mode: str | None = None, episode_steps: int | None = None, **kwargs: Any
) -> gym.Env:
    """The env an adapter adapts: ``gym.make`` of a checked id, its time limit, without scalar-reward checks."""
    registered_env_id(env_id)
    if episode_steps is not None:
        if isinstance(episode_steps, bool) or not isinstance(episode_steps, int) or episode_steps < 1:
            raise ValueError(f"Expected `episode_steps` to be an integer >= 1, actually: {episode_steps!r}")
        kwargs["max_episode_steps"] = episode_steps
    if render_mode is not None:  # not passed otherwise: an env without rendering may not take it
        kwargs["render_mode"] = render_mode
    with warnings.catch_warnings():
        # Some MO-Gymnasium envs build float64 bounds into float32 spaces: noise on every make, not news.
        warnings.filterwarnings("ignore", message=".*precision lowered by casting to float32")
        try:
            # Gymnasium's checker expects a scalar reward; an MO-Gymnasium env returns a vector by design.
            env = gym.make(env_id, disable_env_checker=True, **kwargs)
        except (ImportError, gym.error.DependencyNotInstalled) as error:
            first = (str(error).splitlines() or [type(error).__name__])[0][:200]
            raise EnvUnavailableError(
                f"{env_id!r} cannot be made here, a dependency is missing: {first}"
            ) from None
    route_mujoco_warnings()  # not MUJOCO_LOG.TXT in the user's current folder
    return env


def _check_terms(terms: object, count: int | None) -> list[str]:
    if isinstance(terms, str) or not isinstance(terms, Sequence) or not terms:
        raise ValueError(f"Expected `terms` to be a non-empty list of names, actually: {terms!r:.200}")
    names = list(terms)
    if len(names) > MAX_TERMS or not all(isinstance(n, str) and n.isidentifier() for n in names):
        raise ValueError(f"Expected `terms` to be at most {MAX_TERMS} identifiers, actually: {names!r:.200}")
    if len(set(names)) != len(names):
        raise ValueError(f"Expected `terms` to name each term once, actually: {names}")
    if count is not None and len(names) != count:
        raise ValueError(
            f"Expected {count} `terms` (one per objective of the env), actually {len(names)}: {names}"
        )
    return names


class TermsAdapter(gym.Env[object, object]):
    """
    The shared part of the adapters; subclasses read the raw terms of a step.

    :param inner: the env adapted.
    :param bounds: term name -> per-step ``(low, high)``, finite.
    :param term: the term that is the step reward (a worker's view); ``None``: the normalised sum.
    """

    def __init__(self, inner: gym.Env, bounds: Mapping[str, tuple[float, float]], term: str | None) -> None:
        self.inner = inner
        self.reward_bounds = check_bounds(bounds)
        self.reward_terms = tuple(self.reward_bounds)
        if term is not None and term not in self.reward_bounds:
            raise ValueError(f"Expected `term` to be one of {list(self.reward_terms)}, actually: {term!r}")
        self.term = term
        self._normaliser = TermNormaliser(self.reward_bounds)
        self._all_terms = tuple((t, 1.0) for t in self.reward_terms)
        self.observation_space = inner.observation_space
        self.action_space = inner.action_space
        self.metadata = inner.metadata
        self.render_mode = inner.render_mode
        # Merged into the recorded spec, so that a rebuilt env normalises exactly as this one.
        self.estimated_bounds: dict[str, tuple[float, float]] = {}
        self._spec: EnvSpec | None = None

    @property
    def spec(self) -> EnvSpec | None:  # type: ignore[override]
        return self._spec

    @spec.setter
    def spec(self, value: EnvSpec | None) -> None:
        if value is not None and self.estimated_bounds:
            given = dict(value.kwargs.get("term_bounds") or {})
            merged = {t: list(b) for t, b in {**self.estimated_bounds, **given}.items()}
            value = replace(value, kwargs={**value.kwargs, "term_bounds": merged})
        self._spec = value

    @property
    def episode_steps(self) -> int | None:
        """The inner env's time limit in steps (``None``: it has none)."""
        inner_spec = self.inner.spec
        return inner_spec.max_episode_steps if inner_spec is not None else None

    def normalise_terms(self, terms: Mapping[str, float]) -> dict[str, float]:
        """Each raw term min-max normalised to [0, 1] with :attr:`reward_bounds`."""
        return self._normaliser(terms)

    def _terms(self, reward: RawReward, info: dict[str, object]) -> dict[str, float]:
        raise NotImplementedError

    def reset(
        self, *, seed: int | None = None, options: dict[str, object] | None = None
    ) -> tuple[object, dict[str, object]]:
        super().reset(seed=seed)
        return self.inner.reset(seed=seed, options=options)

    def step(self, action: object) -> tuple[object, float, bool, bool, dict[str, object]]:
        obs, reward, terminated, truncated, info = self.inner.step(action)
        terms = info["reward_terms"] = self._terms(reward, info)
        if self.term is not None:
            return obs, float(terms[self.term]), terminated, truncated, info
        return obs, float(self._normaliser.weighted_sum(terms, self._all_terms)), terminated, truncated, info

    def render(self) -> RenderFrame | list[RenderFrame] | None:
        return self.inner.render()

    def close(self) -> None:
        self.inner.close()


class MultiObjectiveEnv(TermsAdapter):
    """
    An MO-Gymnasium env (vector reward, ``reward_space``) as an env of the contract. Bounds come from
    ``reward_space`` where finite, else from ``term_bounds``, else from a seeded random-policy rollout of
    :data:`ESTIMATE_STEPS` steps widened by :data:`ESTIMATE_MARGIN` (with a warning, and recorded in the
    env's spec kwargs so that a manifest rebuilds it with the same bounds).

    :param env_id: the MO-Gymnasium id, e.g. ``"mo-mountaincarcontinuous-v0"``.
    :param terms: a name per objective, in the reward vector's order (default: ``obj0``..``objN``).
    :param term_bounds: term name -> ``[low, high]`` per step, overriding ``reward_space``.
    :param term: the term that is the step reward (a worker's view); ``None``: the sum of normalised terms.
    :param episode_steps: the inner env's time limit (default: its registered one).
    :param render_mode: passed to the inner env.
    :param env_kwargs: more keyword arguments of the inner env.
    """

    def __init__(
        self,
        env_id: str,
        terms: Sequence[str] | None = None,
        term_bounds: Mapping[str, Sequence[float]] | None = None,
        term: str | None = None,
        episode_steps: int | None = None,
        render_mode: str | None = None,
        **env_kwargs: object,
    ) -> None:
        from mo_gymnasium.wrappers import LinearReward  # lazily: optional (the `mo` extra)

        inner = make_adapted(env_id, render_mode, episode_steps, **env_kwargs)
        space = getattr(inner.unwrapped, "reward_space", None)
        if not isinstance(space, gym.spaces.Box) or len(space.shape) != 1:
            inner.close()
            raise ValueError(
                f"Expected {env_id!r} to be an MO-Gymnasium env with a 1-D Box `reward_space`, actually: {space!r}; "
                f"for an env with per-term rewards in `info`, use {INFO_TERMS_ENV_ID!r}"
            )
        count = int(space.shape[0])
        names = _check_terms(terms, count) if terms is not None else [f"obj{i}" for i in range(count)]
        given = check_bounds(term_bounds, "term_bounds") if term_bounds else {}
        unknown = sorted(set(given) - set(names))
        if unknown:
            raise ValueError(f"`term_bounds` names unknown terms {unknown}; terms: {names}")
        bounds = {
            name: given.get(name, (float(space.low[i]), float(space.high[i]))) for i, name in enumerate(names)
        }
        missing = [n for n, (lo, hi) in bounds.items() if not (math.isfinite(lo) and math.isfinite(hi))]
        estimated = _estimate_bounds(inner, names, missing, env_id) if missing else {}
        bounds.update(estimated)
        if term is not None and term not in names:
            inner.close()
            raise ValueError(f"Expected `term` to be one of {names}, actually: {term!r}")
        # A worker's view weighs its own objective 1 and the others 0: the ecosystem's own scalarisation.
        weight = np.ones(count) if term is None else np.eye(count)[names.index(term)]
        super().__init__(LinearReward(inner, weight=weight), bounds, term)
        self.estimated_bounds = estimated
        self._names = names

    def _terms(self, reward: RawReward, info: dict[str, object]) -> dict[str, float]:
        vector = np.asarray(info["vector_reward"], dtype=np.float64)
        return {name: float(vector[i]) for i, name in enumerate(self._names)}


class InfoTermsEnv(TermsAdapter):
    """
    A Gymnasium env that reports per-term rewards in ``info`` as an env of the contract: ``info[term]``
    (MuJoCo's ``reward_run``...) or ``info[info_key][term]`` (highway-env's ``info["rewards"]``).

    :param env_id: the env's registered id.
    :param terms: the info keys that are reward terms.
    :param term_bounds: term name -> ``[low, high]`` per step, for every term.
    :param info_key: the ``info`` entry holding the terms (default: the terms are top-level ``info`` keys).
    :param term: as :class:`MultiObjectiveEnv`'s, and so are ``episode_steps``, ``render_mode``, ``env_kwargs``.
    """

    def __init__(
        self,
        env_id: str,
        terms: Sequence[str],
        term_bounds: Mapping[str, Sequence[float]] | None = None,
        info_key: str | None = None,
        term: str | None = None,
        episode_steps: int | None = None,
        render_mode: str | None = None,
        **env_kwargs: object,
    ) -> None:
        names = _check_terms(terms, None)
        bounds = check_bounds(term_bounds or {}, "term_bounds")
        if set(bounds) != set(names):
            raise ValueError(
                f"Expected `term_bounds` for exactly the terms {names} (an env's info declares no bounds), "
                f"actually for {sorted(bounds)}"
            )
        self.info_key = info_key
        inner = make_adapted(env_id, render_mode, episode_steps, **env_kwargs)
        super().__init__(inner, {n: bounds[n] for n in names}, term)

    def _terms(self, reward: RawReward, info: dict[str, object]) -> dict[str, float]:
        source = info if self.info_key is None else info.get(self.info_key, {})
        where = "info" if self.info_key is None else f"info[{self.info_key!r}]"
        if not isinstance(source, Mapping):
            raise ValueError(f"{where} has no reward terms; it is a {type(source).__name__}")
        try:
            return {name: float(source[name]) for name in self.reward_terms}
        except (KeyError, TypeError) as missing:
            raise ValueError(
                f"{where} has no reward term {missing}; it has {sorted(map(str, source))[:20]}"
            ) from None


def _estimate_bounds(
    env: gym.Env, names: list[str], missing: list[str], env_id: str
) -> dict[str, tuple[float, float]]:
    """Per-step bounds of the ``missing`` terms from a seeded random-policy rollout, announced loudly."""
    seen: dict[str, list[float]] = {n: [] for n in missing}
    env.action_space.seed(0)
    env.reset(seed=0)
    for _ in range(ESTIMATE_STEPS):
        _, reward, terminated, truncated, _ = env.step(env.action_space.sample())
        for name in missing:
            seen[name].append(float(np.asarray(reward)[names.index(name)]))
        if terminated or truncated:
            env.reset()
    estimated = {}
    for name, values in seen.items():
        low, high = min(values), max(values)
        margin = ESTIMATE_MARGIN * (high - low) or max(abs(low), 1.0) * ESTIMATE_MARGIN
        estimated[name] = (low - margin, high + margin)
    shown = ",".join(f"{n}={lo:.4g}:{hi:.4g}" for n, (lo, hi) in estimated.items())
    message = (
        f"{env_id}: reward_space has no finite bounds for {missing}; ESTIMATED them from a {ESTIMATE_STEPS}-step "
        f"random-policy rollout as {shown}. A trained policy may leave them: give bounds you trust with "
        f"term_bounds (CLI: --term-bounds {shown}). The estimate is recorded with the env."
    )
    warnings.warn(message, UserWarning, stacklevel=3)
    return estimated


class TermReward(gym.Wrapper[object, object, object, object]):
    """
    One term of a contract env as its scalar reward: a worker's view of an env that meets the contract
    natively (the adapters' ``term`` argument does the same for adapted envs).

    :param env: an env that reports ``info["reward_terms"]``.
    :param term: the term that becomes the reward.
    """

    def __init__(self, env: gym.Env, term: str) -> None:
        terms = list(env_contract(env).reward_bounds)
        if term not in terms:
            raise ValueError(f"Expected `term` to be one of the env's terms {terms}, actually: {term!r}")
        super().__init__(env)
        self.term = term

    def step(self, action: object) -> tuple[object, float, bool, bool, dict[str, object]]:
        obs, _, terminated, truncated, info = self.env.step(action)
        return obs, float(info["reward_terms"][self.term]), terminated, truncated, info

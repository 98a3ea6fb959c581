"""
:func:`terms_env`: any env with several objectives resolved once to the shared env a manager acts in and a
view per term a worker learns on, each rebuilt from ``(env_id, env_kwargs)`` as manifests record them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym

from sb3_hddpg.envs.adapters import (
    ADAPTER_ENV_IDS,
    INFO_TERMS_ENV_ID,
    MULTI_OBJECTIVE_ENV_ID,
    TermReward,
    make_adapted,
    registered_env_id,
)
from sb3_hddpg.envs.contract import RewardTermsEnv, check_bounds, env_contract, find_declared
from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID, WORKER_ENV_IDS
from sb3_hddpg.names import check_plain_name


@dataclass(frozen=True)
class TermsEnv:
    """
    A multi-objective env as the hierarchy uses it: ``gym.make(env_id, **env_kwargs)`` is the shared env
    (it meets the env contract), and :meth:`term_view` names the env a worker on one term learns on.

    :param env_id: the shared env's id (one of this package's, an adapter's, or a user's own compliant env).
    :param env_kwargs: its keyword arguments.
    :param terms: its reward terms, in order.
    """

    env_id: str
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    terms: tuple[str, ...] = ()

    @property
    def config_key(self) -> str:
        """The ``zoo_configs`` block its agents read (the adapted env's id for an adapter, else :attr:`env_id`)."""
        return config_key(self.env_id, self.env_kwargs)

    def worker_config_keys(self, term: str) -> tuple[str, str]:
        """
        The ``zoo_configs`` blocks a worker on ``term`` reads, most specific first: ``<config_key>/<term>``
        (e.g. ``mo-halfcheetah-v5/energy``), then :attr:`config_key`.
        """
        return f"{self.config_key}/{term}", self.config_key

    def make(self, **extra: Any) -> gym.Env:
        """The shared env (``extra``: e.g. ``render_mode``)."""
        return gym.make(self.env_id, **self.env_kwargs, **extra)

    def term_view(self, term: str) -> tuple[str, dict[str, Any]]:
        """
        ``(env_id, env_kwargs)`` of the env whose reward is ``term``'s raw value: the snake's id for the
        term, an adapter with ``term=...``, or a native contract env itself (:func:`make_term_view` wraps it).
        """
        if term not in self.terms:
            raise ValueError(
                f"Unknown term {term!r}; the env {self.env_id!r} has the terms {list(self.terms)}"
            )
        if self.env_id == SNAKE_REACH_ENV_ID and term in WORKER_ENV_IDS:
            return WORKER_ENV_IDS[term], dict(self.env_kwargs)
        if self.env_id in ADAPTER_ENV_IDS:
            return self.env_id, {**self.env_kwargs, "term": term}
        return self.env_id, dict(self.env_kwargs)


def adapted_env_id(env_id: str, env_kwargs: Mapping[str, Any] | None = None) -> str:
    """
    The env ``gym.make(env_id, **env_kwargs)`` is, by the id people know it by: the adapted env's id
    (``env_kwargs["env_id"]``, e.g. ``mo-hopper-v5``) for one of the adapters, else ``env_id`` itself.
    It is also the ``zoo_configs`` block of agents trained on that env (:func:`config_key`).
    """
    inner = (env_kwargs or {}).get("env_id")
    return inner if env_id in ADAPTER_ENV_IDS and isinstance(inner, str) else env_id


config_key = adapted_env_id


def make_term_view(env_id: str, env_kwargs: Mapping[str, Any], term: str) -> gym.Env:
    """
    The env ``(env_id, env_kwargs)`` with ``term``'s raw value as its reward (module-level: picklable for
    subprocess envs), wrapped in :class:`~sb3_hddpg.envs.adapters.TermReward` unless the id already gives it.
    """
    env = gym.make(env_id, **env_kwargs)
    if env_id in WORKER_ENV_IDS.values() or env_kwargs.get("term") == term:
        return env
    return TermReward(env, term)


def terms_env(
    env_id: str,
    terms: Sequence[str] | None = None,
    term_bounds: Mapping[str, Sequence[float]] | None = None,
    info_key: str | None = None,
    episode_steps: int | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
) -> TermsEnv:
    """
    Resolve an env id to a :class:`TermsEnv`, choosing the adapter it needs: an env that meets the contract
    natively is used as it is, an MO-Gymnasium env goes through
    :class:`~sb3_hddpg.envs.adapters.MultiObjectiveEnv`, any other through
    :class:`~sb3_hddpg.envs.adapters.InfoTermsEnv` (``terms`` are then ``info`` keys that ``term_bounds`` cover).

    :param env_id: a registered id, without a module prefix.
    :param terms: term names (MO-Gymnasium: one per objective, default ``obj0..objN``; info terms: required).
    :param term_bounds: term -> ``[low, high]`` per step.
    :param info_key: the ``info`` entry holding the terms (info-terms envs only).
    :param episode_steps: the time limit of an adapted env (default: its registered one).
    :param env_kwargs: more keyword arguments of the env.
    :return: the resolved env; raises ``ValueError`` naming the problem.
    """
    kwargs = dict(env_kwargs or {})
    registered_env_id(env_id)
    if env_id in ADAPTER_ENV_IDS:
        if "env_id" not in kwargs:
            raise ValueError(
                f"{env_id!r} is an adapter and needs the env it adapts: name that env instead (e.g. "
                "--env mo-mountaincarcontinuous-v0); the adapter is chosen for it"
            )
        return _resolved(env_id, kwargs)
    adapter_kwargs: dict[str, Any] = {"env_id": env_id, **kwargs}
    if terms is not None:
        adapter_kwargs["terms"] = list(terms)
    if term_bounds:
        adapter_kwargs["term_bounds"] = {t: [float(v) for v in b] for t, b in term_bounds.items()}
    if episode_steps is not None:
        adapter_kwargs["episode_steps"] = episode_steps
    probe = make_adapted(env_id, **kwargs)
    try:
        native = find_declared(probe, lambda layer: isinstance(layer, RewardTermsEnv) or None) is not None
        vector = hasattr(probe.unwrapped, "reward_space")  # MO-Gymnasium's declared API
    finally:
        probe.close()
    if native and terms is None and not term_bounds and info_key is None:
        if episode_steps is not None:
            raise ValueError(f"{env_id!r} meets the env contract itself: set its time limit at registration")
        return _resolved(env_id, kwargs)
    if vector and info_key is None:
        return _resolved(MULTI_OBJECTIVE_ENV_ID, adapter_kwargs)
    if terms is None:
        raise ValueError(
            f"{env_id!r} declares no reward terms (no env contract, no MO-Gymnasium reward_space): name the "
            "per-term rewards of its `info` with `terms` (CLI: --terms) and give their `term_bounds`"
        )
    if info_key is not None:
        adapter_kwargs["info_key"] = info_key
    return _resolved(INFO_TERMS_ENV_ID, adapter_kwargs)


def _resolved(env_id: str, env_kwargs: dict[str, Any]) -> TermsEnv:
    try:
        env = gym.make(env_id, **env_kwargs)
    except TypeError as error:  # a missing or unknown constructor argument: the user's input
        raise ValueError(f"{env_id!r} cannot be made with {sorted(env_kwargs)}: {error}") from None
    try:
        contract: RewardTermsEnv = env_contract(env)
        if env_id == INFO_TERMS_ENV_ID:
            # One step now, so that terms missing from the env's info are refused before anything is written.
            env.reset(seed=0)
            env.action_space.seed(0)
            env.step(env.action_space.sample())
        terms = tuple(contract.reward_bounds)
        # An adapter that estimated bounds records them in its spec: keep them, so that every later
        # make (workers, manager, evaluation, a rebuilt bundle) normalises with the same bounds.
        spec_kwargs = env.unwrapped.spec.kwargs if env.unwrapped.spec is not None else {}
        if "term_bounds" in spec_kwargs:
            env_kwargs = {**env_kwargs, "term_bounds": spec_kwargs["term_bounds"]}
    finally:
        env.close()
    check_bounds(contract.reward_bounds, f"reward_bounds of {env_id!r}")  # a native env's are its own
    for term in terms:  # every env's terms pass here: each becomes a worker's file name
        check_plain_name(term, f"term of {env_id!r}")
    return TermsEnv(env_id, env_kwargs, terms)


def parse_terms(text: str) -> list[str]:
    """
    Term names from text such as ``"speed,energy"`` (the CLI's ``--terms``).

    :raises ValueError: one line naming the bad part.
    """
    names = [part.strip() for part in text.split(",")]
    for name in names:
        # A term names a worker's file: the plain-name rule first, then Python's (the adapters' own).
        check_plain_name(name, "term name")
        if not name.isidentifier():
            raise ValueError(
                f"term name: expected one that does not start with a digit or contain '-', got {name!r}"
            )
    if len(set(names)) != len(names):
        raise ValueError(f"Expected each term named once, got {text!r}")
    return names


def parse_term_bounds(text: str) -> dict[str, tuple[float, float]]:
    """
    Per-term bounds from text such as ``"speed=-1:3,energy=-2:0"`` (the CLI's ``--term-bounds``).

    :raises ValueError: one line naming the bad part.
    """
    bounds: dict[str, tuple[float, float]] = {}
    for part in text.split(","):
        name, _, text_pair = part.partition("=")
        low, sep, high = text_pair.partition(":")
        try:
            if not sep or not name.strip().isidentifier():
                raise ValueError
            pair = (float(low), float(high))
        except ValueError:
            raise ValueError(
                f"Expected TERM=LOW:HIGH[,TERM=LOW:HIGH...], got {part[:100]!r} in {text[:200]!r}"
            ) from None
        if name.strip() in bounds:
            raise ValueError(f"Expected each term bounded once, got {name.strip()!r} twice in {text[:200]!r}")
        bounds[name.strip()] = pair
    return check_bounds(bounds, "term_bounds")

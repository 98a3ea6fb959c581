"""
The hierarchy's side of MORL-baselines' protocol (:mod:`.morl_protocol`): its methods, each a registered
:class:`ProtocolMethod` that trains one policy for every weight within a budget of env steps, and the one
evaluator that plays any of them over the protocol's weights as MORL-baselines' ``eval_mo`` plays its own
learners (discounted vector returns of the env's raw objectives, per episode).

A method is one record (:func:`register_protocol_method`): another selector over other workers (a GPI
selector over weighted workers, say) joins the protocol without a change to the protocol's code.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import gymnasium as gym
import numpy as np

from sb3_hddpg.envs.adapters import ESTIMATE_STEPS, make_adapted
from sb3_hddpg.envs.terms_env import TermsEnv, terms_env
from sb3_hddpg.hierarchy.conditioning import PreferenceSpace
from sb3_hddpg.hierarchy.hierarchy import Hierarchy
from sb3_hddpg.training.manager import train_manager
from sb3_hddpg.training.run_options import RunOptions
from sb3_hddpg.training.workers import train_workers

#: The share of the budget the per-term workers train on, together; the conditioned manager takes the rest.
WORKER_SHARE = 0.8
#: The least weight the conditioned manager trains on and is told (its preferences are > 0): a weight of
#: the protocol ``w`` is told as ``floor + (1 - n floor) w``.
PREFERENCE_FLOOR = 0.01


@dataclass(frozen=True)
class SideRun:
    """
    What a method trains for: one seed on one env within a budget.

    :param env_id: MO-Gymnasium's id, at its registered time limit.
    :param discrete: whether the env's actions are discrete (DQN workers) or continuous.
    :param gamma: the protocol's discount.
    :param budget: env steps, every model's together.
    :param seed: the training seed.
    :param folder: where the method writes its models.
    """

    env_id: str
    discrete: bool
    gamma: float
    budget: int
    seed: int
    folder: Path


class WeightedPolicy(Protocol):
    """One policy for every weight of the objectives."""

    def set_weights(self, weights: Sequence[float]) -> None:
        """Act for ``weights`` (one per objective, on the simplex) from now on."""

    def reset_episode(self) -> None:
        """Forget what the last episode left (an option under way)."""

    def act(self, obs: np.ndarray) -> np.ndarray:
        """The action at ``obs``."""


@dataclass
class TrainedSide:
    """
    A method's result: its policy, its env, the env steps of each model and the seconds it trained.

    :param env_steps: model or phase (``workers/<term>``, ``manager``, ``bounds``) -> its env steps.
    """

    policy: WeightedPolicy
    env: TermsEnv
    env_steps: dict[str, int]
    wall_time_train_s: float


@dataclass(frozen=True)
class ProtocolMethod:
    """
    A method of the hierarchy's side.

    :param name: the name ``--methods`` takes.
    :param description: one line for the page.
    :param train: trains it: a :class:`SideRun` -> a :class:`TrainedSide`.
    :param actions: the only actions it takes (``"continuous"`` or ``"discrete"``), or ``None`` for both.
    """

    name: str
    description: str
    train: Callable[[SideRun], TrainedSide]
    actions: str | None = None


#: The hierarchy's methods, by name.
PROTOCOL_METHODS: dict[str, ProtocolMethod] = {}


def register_protocol_method(method: ProtocolMethod) -> ProtocolMethod:
    """Add ``method`` to :data:`PROTOCOL_METHODS` (a name is registered once)."""
    if method.name in PROTOCOL_METHODS:
        raise ValueError(f"A protocol method named {method.name!r} is registered already")
    PROTOCOL_METHODS[method.name] = method
    return method


def declared_objectives(env_id: str) -> tuple[np.ndarray, np.ndarray]:
    """
    The per-step ``(lows, highs)`` of the env's ``reward_space``, one per objective (some may be infinite).

    :param env_id: the protocol's env.
    """
    inner = make_adapted(env_id)
    try:
        space = inner.unwrapped.reward_space  # type: ignore[attr-defined]
        return np.asarray(space.low, dtype=np.float64), np.asarray(space.high, dtype=np.float64)
    finally:
        inner.close()


def constant_objectives(env_id: str) -> dict[str, float]:
    """
    The objectives the env declares constant (``reward_space``'s low = high: deep-sea-treasure's time, -1
    every step), by term name (``obj<i>``), with their value.

    :param env_id: the protocol's env.
    """
    return _constants(*declared_objectives(env_id))


def _constants(lows: np.ndarray, highs: np.ndarray) -> dict[str, float]:
    return {
        f"obj{i}": float(high)
        for i, (low, high) in enumerate(zip(lows, highs))
        if math.isfinite(low) and low >= high
    }


def pinned_env(env_id: str) -> tuple[TermsEnv, int]:
    """
    The env's adapter with its term bounds fixed once, and the env steps that cost: bounds its
    ``reward_space`` leaves infinite are estimated by one random rollout of :data:`ESTIMATE_STEPS` steps
    when the adapter is resolved, which keeps them in its arguments, so that no env made from it estimates
    them again. An objective the env declares constant (:func:`constant_objectives`) is bounded by
    ``(0, |value|)`` (``(0, 1)`` for 0), so that it normalises to the sign of its value: a weighted sum of
    normalised terms then ranks episodes of different lengths as the raw objective does (deep-sea-treasure's
    time, -1 every step: shorter is better). Pinned to 1 every step instead, the time worker and a manager
    weighing it would be paid for longer episodes.
    """
    lows, highs = declared_objectives(env_id)
    constant = {term: [0.0, abs(value) or 1.0] for term, value in _constants(lows, highs).items()}
    estimated = not (np.isfinite(lows).all() and np.isfinite(highs).all())
    return terms_env(env_id, term_bounds=constant or None), ESTIMATE_STEPS if estimated else 0


class ConditionedHierarchy:
    """A preference-conditioned :class:`Hierarchy` as a :class:`WeightedPolicy`."""

    def __init__(self, hierarchy: Hierarchy) -> None:
        self.hierarchy = hierarchy

    def set_weights(self, weights: Sequence[float]) -> None:
        n = len(self.hierarchy.names)
        told = PREFERENCE_FLOOR + (1.0 - n * PREFERENCE_FLOOR) * np.asarray(weights, dtype=np.float64)
        self.hierarchy.set_preference(dict(zip(self.hierarchy.names, (n * told).tolist())))

    def reset_episode(self) -> None:
        self.hierarchy.reset_episode()

    def act(self, obs: np.ndarray) -> np.ndarray:
        return self.hierarchy.predict(obs, deterministic=True)[0]


def train_conditioned(run: SideRun) -> TrainedSide:
    """
    Today's hierarchy: one worker per objective (DQN on discrete actions, DDPG on continuous), then a DQN
    manager choosing a worker every step, conditioned on the weight (Dirichlet over the simplex).
    """
    started = time.perf_counter()
    shared, bounds_steps = pinned_env(run.env_id)
    terms = list(shared.terms)
    # The bounds' rollout is paid first; the workers and the manager share what is left.
    available = run.budget - bounds_steps
    per_worker = int(available * WORKER_SHARE) // len(terms)
    manager_steps = available - per_worker * len(terms)
    if per_worker < 1 or manager_steps < 1:
        raise ValueError(
            f"A budget of {run.budget} env steps ({bounds_steps} to estimate bounds) trains no model"
        )
    algo = "dqn" if run.discrete else "ddpg"
    options = RunOptions(seed=run.seed, eval_freq=0, eval_episodes=1, keep_best=False)
    train_workers(
        run.folder, env=shared, algos=dict.fromkeys(terms, algo), run=options.replace(timesteps=per_worker)
    )
    space = PreferenceSpace(tuple(terms), "dirichlet", float(len(terms)), floor=PREFERENCE_FLOOR)
    hierarchy = train_manager(
        run.folder,
        run.folder / "conditioned",
        algo="dqn",
        option_steps=1,
        gamma=run.gamma,
        manager_preferences=space,
        env_id=shared.env_id,
        env_kwargs=dict(shared.env_kwargs),
        run=options.replace(timesteps=manager_steps),
    ).hierarchy
    steps = {f"workers/{t}": per_worker for t in terms}
    steps.update(manager=manager_steps, bounds=bounds_steps)
    return TrainedSide(ConditionedHierarchy(hierarchy), shared, steps, time.perf_counter() - started)


register_protocol_method(
    ProtocolMethod(
        "hddpg-conditioned",
        f"one worker per objective on {WORKER_SHARE} of the budget, then a DQN manager choosing a worker every "
        f"step, conditioned on the weight (Dirichlet over the simplex, weights >= {PREFERENCE_FLOOR})",
        train_conditioned,
    )
)


def play_front(
    policy: WeightedPolicy,
    env: gym.Env,
    weights: Sequence[Sequence[float]],
    episodes: int,
    eval_seed: int,
    gamma: float,
) -> tuple[list[list[list[float]]], list[list[list[float]]]]:
    """
    Every weight's episodes, played as MORL-baselines' ``eval_mo`` plays them (the env is reset with
    ``eval_seed`` before each weight's episodes, each episode then reset unseeded): per weight, per episode,
    the discounted and the undiscounted vector returns of the env's raw objectives.

    :param env: the env of the method's side (an adapter: its ``info["reward_terms"]`` are the raw objectives).
    """
    terms = list(env.unwrapped.reward_terms)  # type: ignore[attr-defined]
    discounted, returns = [], []
    for w in weights:
        policy.set_weights(w)
        env.reset(seed=eval_seed)
        played_discounted, played = [], []
        for _ in range(episodes):
            obs, _ = env.reset()
            policy.reset_episode()
            total, total_discounted, factor, done = np.zeros(len(terms)), np.zeros(len(terms)), 1.0, False
            while not done:
                obs, _, terminated, truncated, info = env.step(policy.act(obs))
                reward = np.array([info["reward_terms"][t] for t in terms], dtype=np.float64)
                total += reward
                total_discounted += factor * reward
                factor *= gamma
                done = terminated or truncated
            played_discounted.append(total_discounted.tolist())
            played.append(total.tolist())
        discounted.append(played_discounted)
        returns.append(played)
    return discounted, returns


__all__ = [
    "PROTOCOL_METHODS",
    "ConditionedHierarchy",
    "ProtocolMethod",
    "SideRun",
    "TrainedSide",
    "WeightedPolicy",
    "constant_objectives",
    "declared_objectives",
    "pinned_env",
    "play_front",
    "register_protocol_method",
    "train_conditioned",
]

"""
A manager's start from a teacher that needs no training: behaviour cloning on its choices before RL. The
teacher is the hand-written rule (:class:`HamStart`, HAM's threshold switch) or generalized policy
improvement over the workers' per-term critics (:class:`GpiStart`, at each episode's preference, for a
conditioned manager).

A freshly initialised manager starts far below the teacher and spends much of its budget getting back to
it. Here the teacher first drives the manager's own env for a number of decisions, and the manager's network
is fitted to its choices: a simplex manager's actor regressed onto ``+1`` for the teacher's worker and ``-1``
for the others; a discrete manager's Q-values by DQfD's large-margin loss plus their cross-entropy. The same
decisions go into the replay buffer with their real rewards, so RL starts at the teacher's level. SB3
managers only.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm

from sb3_hddpg.artifacts.term_critic import TermCritic
from sb3_hddpg.envs.contract import mix_terms
from sb3_hddpg.hierarchy.gpi import gpi_of
from sb3_hddpg.hierarchy.wrapper import WorkerSelectionWrapper

if TYPE_CHECKING:
    from sb3_hddpg.baselines.ham import HAMSwitch

#: The manager algorithms whose network a start fits: a deterministic or squashed actor, or a Q-net.
START_ALGOS = ("ddpg", "td3", "sac", "tqc", "crossq", "dqn")
#: DQfD's margin between HAM's choice and every other worker's Q-value.
MARGIN = 0.8


@dataclass(frozen=True)
class HamStart:
    """
    How a manager imitates HAM before RL.

    :param threshold: HAM's threshold on the summed joint-to-obstacle distances.
    :param decisions: manager decisions of HAM's to imitate (and to store in the replay buffer).
    :param epochs: passes of the fitting over those decisions.
    :param batch_size: decisions per gradient step.
    :param learning_rate: the fitting's Adam learning rate.
    :param hysteresis: HAM's hysteresis.
    """

    threshold: float
    decisions: int = 2000
    epochs: int = 30
    batch_size: int = 256
    learning_rate: float = 1e-3
    hysteresis: float = 0.0

    def __post_init__(self) -> None:
        if not np.isfinite(self.threshold) or self.threshold < 0:
            raise ValueError(
                f"Expected HAM's threshold to be a finite number >= 0, actually: {self.threshold}"
            )
        _check_fitting(self)


@dataclass(frozen=True)
class GpiStart:
    """
    How a conditioned manager imitates GPI over its workers' per-term critics before RL: at each decision
    GPI picks the worker for the term weights of the episode's preference (each worker's reward weighed by
    its preference factor); the workers need critics (``fit-critics`` gives them state-value ones).

    :param decisions: manager decisions of GPI's to imitate (and to store in the replay buffer).
    :param epochs: passes of the fitting over those decisions.
    :param batch_size: decisions per gradient step.
    :param learning_rate: the fitting's Adam learning rate.
    """

    decisions: int = 2000
    epochs: int = 30
    batch_size: int = 256
    learning_rate: float = 1e-3

    def __post_init__(self) -> None:
        _check_fitting(self)


def _check_fitting(start: HamStart | GpiStart) -> None:
    for name in ("decisions", "epochs", "batch_size"):
        if getattr(start, name) < 1:
            raise ValueError(
                f"Expected `{name}` >= 1 for the manager's start, actually: {getattr(start, name)}"
            )


def check_ham_workers(names: Sequence[str]) -> None:
    """Refuse workers without HAM's two, named ``goal`` and ``avoid``, in one line."""
    if not {"goal", "avoid"} <= set(names):
        raise ValueError(
            f"The start from HAM needs workers named 'goal' and 'avoid' (HAM's two), actually: {list(names)}"
        )


def ham_of(wrapper: WorkerSelectionWrapper, start: HamStart) -> tuple[HAMSwitch, int]:
    """The HAM switch over the wrapper's goal and avoid workers, and the avoid worker's index."""
    check_ham_workers(wrapper.worker_names)
    from sb3_hddpg.baselines.ham import HAMSwitch  # the hand-written switch, only for a start from it

    switch = HAMSwitch(
        wrapper.workers["goal"],
        wrapper.workers["avoid"],
        wrapper.layout,
        threshold=start.threshold,
        hysteresis=start.hysteresis,
        worker_states=wrapper.worker_states,
    )
    return switch, wrapper.worker_names.index("avoid")


def _choice_action(wrapper: WorkerSelectionWrapper, choice: int) -> np.ndarray:
    """The manager action that selects worker ``choice``: its index, or a corner of the simplex box."""
    if isinstance(wrapper.action_space, gym.spaces.Discrete):
        return np.array(choice)
    action = -np.ones(len(wrapper.worker_names), dtype=np.float32)
    action[choice] = 1.0
    return action


def _teacher(
    wrapper: WorkerSelectionWrapper, start: HamStart | GpiStart, critics: Mapping[str, TermCritic]
) -> tuple[Callable[[np.ndarray], int], Callable[[], None]]:
    """The teacher's choice (a worker index) for a full state, and what it does at an episode's start."""
    if isinstance(start, GpiStart):
        selector = gpi_of(wrapper.frozen, critics, wrapper.worker_names)
        # The manager's reward is sum_i p_i r_i, each r_i a weighting of the terms: GPI weighs the terms so.
        return (
            lambda state: selector.select(state, mix_terms(wrapper.reward_specs, wrapper.preferences))[0],
            lambda: None,
        )
    switch, avoid = ham_of(wrapper, start)
    goal = wrapper.worker_names.index("goal")
    return (lambda state: avoid if bool(switch.select(state)[0]) else goal), switch.reset_episode


def collect_start_decisions(
    env: gym.Env,
    start: HamStart | GpiStart,
    model: BaseAlgorithm | None = None,
    seed: int = 0,
    critics: Mapping[str, TermCritic] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """
    Let the teacher drive the manager's env for ``start.decisions`` decisions; store them in ``model``'s
    replay buffer if it has one.

    :param env: the manager's env (a ``WorkerSelectionWrapper``, possibly wrapped).
    :param start: the settings (HAM's or GPI's).
    :param model: the manager (``None``: only collect).
    :param seed: the first episode's seed.
    :param critics: worker name -> its per-term critic, for a start from GPI.
    :return: the manager observations and the teacher's choices (worker indices).
    """
    wrapper = env
    while not isinstance(wrapper, WorkerSelectionWrapper):
        if not isinstance(wrapper, gym.Wrapper):
            raise ValueError("A manager's start needs the manager's WorkerSelectionWrapper env")
        wrapper = wrapper.env
    choose, reset_episode = _teacher(wrapper, start, critics or {})
    buffer = getattr(model, "replay_buffer", None)
    observations: list[np.ndarray] = []
    choices: list[int] = []
    obs, _ = env.reset(seed=seed)
    reset_episode()
    episode = 0
    while len(choices) < start.decisions:
        full_state = wrapper._last_obs
        if full_state is None:
            raise RuntimeError("The manager's env was not reset")
        choice = choose(full_state)
        action = _choice_action(wrapper, choice)
        next_obs, reward, terminated, truncated, info = env.step(action)
        observations.append(obs)
        choices.append(choice)
        if buffer is not None:
            timeout = truncated and not terminated
            buffer.add(
                obs[None], next_obs[None], np.asarray(action).reshape(1, -1), np.array([reward]),
                np.array([terminated or truncated]), [{**info, "TimeLimit.truncated": timeout}],
            )  # fmt: skip
        obs = next_obs
        if terminated or truncated:
            episode += 1
            obs, _ = env.reset(seed=seed + episode)
            reset_episode()
    return np.asarray(observations, dtype=np.float32), np.asarray(choices, dtype=np.int64)


def imitate(
    model: BaseAlgorithm, observations: np.ndarray, choices: np.ndarray, start: HamStart | GpiStart
) -> float:
    """
    Fit the manager's network to the teacher's choices (see the module's note).

    :return: the share of the decisions on which the fitted manager's choice is the teacher's.
    """
    policy: Any = model.policy
    policy.set_training_mode(True)
    discrete = isinstance(model.action_space, gym.spaces.Discrete)
    network = policy.q_net if discrete else policy.actor
    optimiser = th.optim.Adam(network.parameters(), lr=start.learning_rate)
    obs = th.as_tensor(observations, device=policy.device)
    target = th.as_tensor(choices, device=policy.device)
    space: Any = model.action_space
    n_workers = int(space.n) if discrete else int(space.shape[0])
    corners = 2.0 * th.nn.functional.one_hot(target, n_workers).float() - 1.0
    generator = th.Generator().manual_seed(0)
    for _ in range(start.epochs):
        order = th.randperm(len(obs), generator=generator)
        for first in range(0, len(obs), start.batch_size):
            batch = order[first : first + start.batch_size]
            loss = _loss(network, obs[batch], target[batch], corners[batch], discrete)
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
    policy.set_training_mode(False)
    _copy_targets(policy, discrete)
    with th.no_grad():
        chosen = (network(obs) if discrete else _deterministic(network, obs)).argmax(dim=1)
    return float((chosen == target).float().mean())


def _deterministic(actor: Any, obs: th.Tensor) -> th.Tensor:
    # SAC-like actors take `deterministic`; DDPG/TD3's are deterministic already.
    try:
        return actor(obs, deterministic=True)
    except TypeError:
        return actor(obs)


def _loss(network: Any, obs: th.Tensor, target: th.Tensor, corners: th.Tensor, discrete: bool) -> th.Tensor:
    if not discrete:
        return th.nn.functional.mse_loss(_deterministic(network, obs), corners)
    q_values = network(obs)
    margins = MARGIN * (1.0 - th.nn.functional.one_hot(target, q_values.shape[1]).float())
    expert = q_values.gather(1, target[:, None]).squeeze(1)
    # The margin keeps HAM's choice on top; the cross-entropy gives a gradient on every decision, also
    # those already on top (the margin's is zero there), so the fit converges in few passes.
    margin = ((q_values + margins).max(dim=1).values - expert).mean()
    return margin + th.nn.functional.cross_entropy(q_values, target)


def _copy_targets(policy: object, discrete: bool) -> None:
    pairs = [("q_net", "q_net_target")] if discrete else [("actor", "actor_target")]
    for source, target in pairs:
        if hasattr(policy, source) and getattr(policy, target, None) is not None:
            getattr(policy, target).load_state_dict(getattr(policy, source).state_dict())


def start_hook(
    start: HamStart | GpiStart,
    env_factory: Callable[[], gym.Env],
    seed: int,
    report: dict[str, Any],
    critics: Mapping[str, TermCritic] | None = None,
) -> Callable[[BaseAlgorithm], None]:
    """
    The function :func:`~sb3_hddpg.training.agent.train_agent` calls on a fresh manager: collect the
    teacher's decisions, fill the replay buffer and fit the network; ``report`` gets the settings and the
    agreement.

    :param critics: worker name -> its per-term critic, for a start from GPI.
    """

    def prepare(model: BaseAlgorithm) -> None:
        if not isinstance(model.policy, th.nn.Module):
            raise ValueError("A manager's start fits SB3 (torch) managers: use --backend sb3")
        with contextlib.closing(env_factory()) as env:
            observations, choices = collect_start_decisions(env, start, model, seed=seed, critics=critics)
        agreement = imitate(model, observations, choices, start)
        report.update({**asdict(start), "agreement": agreement})

    return prepare

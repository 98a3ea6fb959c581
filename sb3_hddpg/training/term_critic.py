"""
Training a worker's per-term critic (:class:`~sb3_hddpg.artifacts.term_critic.TermCritic`) by TD on the
transitions it collected: policy evaluation of the worker's own policy, one head per normalised term,
``y_k = r_k + gamma * (1 - done) * Q'_k(s', pi(s'))`` with a Polyak-averaged target network (for a discrete
worker ``Q_k(s, a)`` of every action, the next action its greedy one). It costs gradient steps, no env steps.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.utils import polyak_update

from sb3_hddpg.artifacts.limits import MAX_BATCH_SIZE
from sb3_hddpg.artifacts.term_critic import TermCritic, TermCriticSpec
from sb3_hddpg.artifacts.transitions import Transitions
from sb3_hddpg.callbacks.term_record import TermRecorder

#: The most gradient steps a critic takes by default (fewer when fewer transitions were collected).
DEFAULT_CRITIC_STEPS = 20_000


@dataclass(frozen=True)
class TermCriticOptions:
    """
    How a worker's per-term critic is trained.

    :param steps: gradient steps (``None``: one per stored transition, at most :data:`DEFAULT_CRITIC_STEPS`).
    :param batch_size: transitions per step.
    :param net_arch: hidden layer sizes.
    :param learning_rate: Adam's step size.
    :param tau: the target network's Polyak coefficient.
    :param gamma: the discount of the values: one for every worker of a support, not each worker's own, so
        that GPI and the support compare values of one kind.
    """

    steps: int | None = None
    batch_size: int = 256
    net_arch: tuple[int, ...] = (64, 64)
    learning_rate: float = 1e-3
    tau: float = 0.02
    gamma: float = 0.99

    def __post_init__(self) -> None:
        if not 0.0 <= self.gamma < 1.0:
            raise ValueError(f"Expected `gamma` in [0, 1), actually: {self.gamma}")
        if self.steps is not None and (
            isinstance(self.steps, bool) or not 1 <= int(self.steps) <= 10_000_000
        ):
            raise ValueError(f"Expected `steps` in [1, 10000000], actually: {self.steps}")
        if not 1 <= self.batch_size <= MAX_BATCH_SIZE:
            raise ValueError(f"Expected `batch_size` in [1, {MAX_BATCH_SIZE}], actually: {self.batch_size}")
        if not (0 < self.learning_rate < 1 and 0 < self.tau <= 1):
            raise ValueError(
                f"Expected `learning_rate` and `tau` in (0, 1), actually: {self.learning_rate}, {self.tau}"
            )


def recorded_transitions(recorder: TermRecorder) -> Transitions:
    """The transitions of ``recorder``'s buffer that it recorded terms for, flattened over envs."""
    buffer = recorder.buffer
    if buffer is None or not recorder.filled.any():
        raise ValueError("No transitions were recorded: train the worker before its critic")
    rows, envs = np.nonzero(recorder.filled)
    if buffer.optimize_memory_usage:
        next_obs = buffer.observations[(rows + 1) % buffer.buffer_size, envs]
    else:
        next_obs = buffer.next_observations[rows, envs]
    dones = buffer.dones[rows, envs] * (1.0 - buffer.timeouts[rows, envs])
    return Transitions(
        buffer.observations[rows, envs].reshape(len(rows), -1).astype(np.float32),
        buffer.actions[rows, envs].reshape(len(rows), -1),
        next_obs.reshape(len(rows), -1).astype(np.float32),
        recorder.terms[rows, envs],
        (1.0 - dones).astype(np.float32),
    )


def fit_term_critic(
    policy: BaseAlgorithm,
    transitions: Transitions,
    terms: Sequence[str],
    options: TermCriticOptions | None = None,
    seed: int = 0,
) -> tuple[TermCritic, dict[str, float]]:
    """
    Train a per-term critic of ``policy`` on ``transitions``.

    :param policy: the worker (an SB3 model; its ``predict`` gives ``pi(s')``).
    :param transitions: its stored transitions with their normalised terms.
    :param terms: the terms' names, in the order of ``transitions.terms``' columns.
    :param options: the training settings.
    :param seed: seeds the critic's initial weights and batches.
    :return: the critic and its training facts (``steps``, ``transitions``, the last ``td_loss``).
    """
    options = options or TermCriticOptions()
    spec = TermCriticSpec.for_spaces(
        terms, policy.observation_space, policy.action_space, options.net_arch, options.gamma
    )
    generator = torch.Generator().manual_seed(seed)
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        critic = TermCritic(spec)
    target = copy.deepcopy(critic)
    optimizer = torch.optim.Adam(critic.parameters(), lr=options.learning_rate)
    # The policy is fixed: its next actions are computed once, not once per batch.
    next_actions, _ = policy.predict(transitions.next_obs, deterministic=True)
    data = {
        "obs": torch.as_tensor(transitions.obs),
        "next_obs": torch.as_tensor(transitions.next_obs),
        "terms": torch.as_tensor(transitions.terms, dtype=torch.float32),
        "continues": torch.as_tensor(transitions.continues, dtype=torch.float32).reshape(-1, 1),
    }
    if spec.discrete:
        data["actions"] = torch.as_tensor(transitions.actions, dtype=torch.long).reshape(-1)
        data["next_actions"] = torch.as_tensor(np.asarray(next_actions), dtype=torch.long).reshape(-1)
    else:
        data["actions"] = torch.as_tensor(transitions.actions, dtype=torch.float32)
        data["next_actions"] = torch.as_tensor(critic.scale_actions(np.asarray(next_actions)))
    steps = int(options.steps if options.steps is not None else min(len(transitions), DEFAULT_CRITIC_STEPS))
    loss_value = float("nan")
    for _ in range(steps):
        batch = torch.randint(
            len(transitions), (min(options.batch_size, len(transitions)),), generator=generator
        )
        loss = _td_loss(critic, target, {k: v[batch] for k, v in data.items()}, spec.gamma)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        polyak_update(critic.parameters(), target.parameters(), options.tau)
        loss_value = float(loss.detach())
    critic.eval()
    return critic, {"steps": steps, "transitions": len(transitions), "td_loss": loss_value}


def _td_loss(
    critic: TermCritic, target: TermCritic, batch: dict[str, torch.Tensor], gamma: float
) -> torch.Tensor:
    """The mean squared TD error over every term head of one batch."""
    rows = torch.arange(len(batch["obs"]))

    def q(network: TermCritic, obs: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        return network(obs)[rows, actions] if critic.spec.discrete else network(obs, actions)

    with torch.no_grad():
        targets = batch["terms"] + gamma * batch["continues"] * q(
            target, batch["next_obs"], batch["next_actions"]
        )
    return torch.nn.functional.mse_loss(q(critic, batch["obs"], batch["actions"]), targets)

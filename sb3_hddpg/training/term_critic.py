"""
Training a worker's per-term critic (:class:`~sb3_hddpg.artifacts.term_critic.TermCritic`) by TD: policy
evaluation of the worker's own policy, one head per normalised term, with a Polyak-averaged target network.

- On the transitions it collected in training, over its own observation:
  ``y_k = r_k + gamma * (1 - done) * Q'_k(s', pi(s'))`` (for a discrete worker ``Q_k(s, a)`` of every action,
  the next action its greedy one). It costs gradient steps, no env steps.
- On rollouts of its final policy in the shared env (:func:`rollout_transitions`): a continuous worker's
  state value over the full state, ``y_k = r_k + gamma * (1 - done) * V'_k(s')``, what GPI needs when a
  worker sees part of the state (on the snake, the goal worker does not see the obstacles); a discrete
  worker's ``Q_k(s, a)`` over its own observation, as above (GPI over discrete workers takes an action, so
  it needs values of every action). It costs the rollouts' env steps.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import hashlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.utils import polyak_update

from sb3_hddpg.artifacts.io import atomic_write_bytes, holds_folder_lock
from sb3_hddpg.artifacts.limits import MAX_BATCH_SIZE
from sb3_hddpg.artifacts.manifests import load_workers, save_manifest
from sb3_hddpg.artifacts.term_critic import TERM_CRITIC_MEMBER, TermCritic, TermCriticSpec, with_term_critic
from sb3_hddpg.artifacts.transitions import Transitions
from sb3_hddpg.callbacks.term_record import TermRecorder
from sb3_hddpg.envs.contract import TermNormaliser, env_contract, state_layout_of
from sb3_hddpg.hierarchy.frozen import FrozenWorker
from sb3_hddpg.threads import use_one_thread_unless_chosen

#: The most gradient steps a critic takes by default (fewer when fewer transitions were collected).
DEFAULT_CRITIC_STEPS = 20_000
#: The first episode seed of the rollouts a state-value critic is fitted on: its own range, far from every
#: evaluation set of :mod:`sb3_hddpg.episode_sets` (they start at 10,000 and are 5,000 episodes each).
ROLLOUT_FIRST_SEED = 1_000_000


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
    :param rollout_steps: for a critic fitted on rollouts, the env steps of its policy's rollouts.
    :param noise: for a critic fitted on rollouts, so that it also values states (and actions) just off the
        policy's path: the std of the Gaussian noise on a continuous worker's actions (as a share of the
        action range's half), or the probability of a uniformly random action of a discrete worker.
    """

    steps: int | None = None
    batch_size: int = 256
    net_arch: tuple[int, ...] = (64, 64)
    learning_rate: float = 1e-3
    tau: float = 0.02
    gamma: float = 0.99
    rollout_steps: int = 40_000
    noise: float = 0.1

    def __post_init__(self) -> None:
        if not 0.0 <= self.gamma < 1.0:
            raise ValueError(f"Expected `gamma` in [0, 1), actually: {self.gamma}")
        if self.steps is not None and (
            isinstance(self.steps, bool) or not 1 <= int(self.steps) <= 10_000_000
        ):
            raise ValueError(f"Expected `steps` in [1, 10000000], actually: {self.steps}")
        if not 1 <= self.batch_size <= MAX_BATCH_SIZE:
            raise ValueError(f"Expected `batch_size` in [1, {MAX_BATCH_SIZE}], actually: {self.batch_size}")
        if isinstance(self.rollout_steps, bool) or not 1 <= int(self.rollout_steps) <= 10_000_000:
            raise ValueError(f"Expected `rollout_steps` in [1, 10000000], actually: {self.rollout_steps}")
        if not 0.0 <= self.noise <= 1.0:
            raise ValueError(f"Expected `noise` in [0, 1], actually: {self.noise}")
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


#: A state-value critic's settings, as chosen on the snake's development episodes: a wider net and a shorter
#: horizon than the buffer critic's (contacts are near-term events).
STATE_CRITIC_OPTIONS = TermCriticOptions(steps=20_000, net_arch=(256, 256), gamma=0.95)


def rollout_transitions(
    worker: FrozenWorker,
    env: gym.Env,
    bounds: Mapping[str, Sequence[float]],
    options: TermCriticOptions,
    seed: int = 0,
) -> Transitions:
    """
    Roll ``worker`` out in the shared ``env`` for ``options.rollout_steps`` env steps with exploration,
    episode ``k`` reset with seed ``ROLLOUT_FIRST_SEED + k``: on-policy transitions over the full state. A
    continuous worker's actions get Gaussian noise and are not kept (a state value needs none); a discrete
    worker's are its own or, with probability ``options.noise``, uniformly random, and are kept as indices.

    :param worker: the worker, frozen with the indices of the state it sees.
    :param env: the shared env (full observations, ``info["reward_terms"]`` every step).
    :param bounds: term name -> per-step ``(low, high)``, the env contract's.
    :param options: the rollouts' length and noise.
    :param seed: seeds the noise.
    """
    normaliser = TermNormaliser(bounds)
    terms = tuple(normaliser.bounds)
    space = env.action_space
    rng = np.random.default_rng(seed)
    if isinstance(space, gym.spaces.Discrete):
        n_actions, discrete = int(space.n), True

        def explore(own: np.ndarray) -> np.ndarray:
            return np.asarray(rng.integers(n_actions) if rng.random() < options.noise else np.ravel(own)[0])

    elif isinstance(space, gym.spaces.Box):
        low, high, discrete = space.low, space.high, False
        scale = options.noise * (high - low) / 2.0

        def explore(own: np.ndarray) -> np.ndarray:
            return np.clip(own + rng.normal(0.0, 1.0, low.shape) * scale, low, high)

    else:
        raise ValueError(f"Expected a Box or Discrete action space for a worker's critic, actually: {space}")
    n = int(options.rollout_steps)
    obs_dim = int(np.prod(env.observation_space.shape or (1,)))
    states = np.zeros((n + 1, obs_dim), dtype=np.float32)
    next_states = np.zeros((n, obs_dim), dtype=np.float32)
    actions = np.zeros((n, 1 if discrete else 0), dtype=np.int64 if discrete else np.float32)
    rewards = np.zeros((n, len(terms)), dtype=np.float32)
    continues = np.ones(n, dtype=np.float32)
    episode = 0
    obs, _ = env.reset(seed=ROLLOUT_FIRST_SEED)
    worker.reset_episode()
    for step in range(n):
        states[step] = np.ravel(obs)
        action = explore(worker.act(np.asarray(obs)))
        actions[step] = np.ravel(action)[: actions.shape[1]]  # a continuous worker's are not kept
        obs, _, terminated, truncated, info = env.step(np.asarray(action).astype(space.dtype))
        normalised = normaliser(info["reward_terms"])
        rewards[step] = [normalised[term] for term in terms]
        next_states[step] = np.ravel(obs)
        continues[step] = 0.0 if terminated else 1.0
        if terminated or truncated:
            episode += 1
            obs, _ = env.reset(seed=ROLLOUT_FIRST_SEED + episode)
            worker.reset_episode()
    return Transitions(states[:n], actions, next_states, rewards, continues)


def fit_term_critic(
    policy: BaseAlgorithm | None,
    transitions: Transitions,
    terms: Sequence[str],
    options: TermCriticOptions | None = None,
    seed: int = 0,
) -> tuple[TermCritic, dict[str, float]]:
    """
    Train a per-term critic of ``policy`` on ``transitions``.

    :param policy: the worker (an SB3 model; its ``predict`` gives ``pi(s')``); ``None``: a state-value
        critic of the policy that collected ``transitions`` (:func:`rollout_transitions`), over their states.
    :param transitions: its stored transitions with their normalised terms.
    :param terms: the terms' names, in the order of ``transitions.terms``' columns.
    :param options: the training settings.
    :param seed: seeds the critic's initial weights and batches.
    :return: the critic and its training facts (``steps``, ``transitions``, the last ``td_loss``).
    """
    options = options or TermCriticOptions()
    if policy is None:
        width = int(transitions.obs.shape[1])
        spec = TermCriticSpec(tuple(terms), width, 0, (), (), tuple(options.net_arch), float(options.gamma))
    else:
        spec = TermCriticSpec.for_spaces(
            terms, policy.observation_space, policy.action_space, options.net_arch, options.gamma
        )
    generator = torch.Generator().manual_seed(seed)
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        critic = TermCritic(spec)
    target = copy.deepcopy(critic)
    optimizer = torch.optim.Adam(critic.parameters(), lr=options.learning_rate)
    data = {
        "obs": torch.as_tensor(transitions.obs),
        "next_obs": torch.as_tensor(transitions.next_obs),
        "terms": torch.as_tensor(transitions.terms, dtype=torch.float32),
        "continues": torch.as_tensor(transitions.continues, dtype=torch.float32).reshape(-1, 1),
    }
    if policy is not None:  # a state value needs no actions: the transitions' own were the policy's
        # The policy is fixed: its next actions are computed once, not once per batch, from observations in
        # its own shape (the transitions' are flat: highway's 5x5 grid is 25 values).
        shape = policy.observation_space.shape or ()
        next_obs = transitions.next_obs.reshape(len(transitions), *shape)
        next_actions = np.asarray(policy.predict(next_obs, deterministic=True)[0])
        if spec.discrete:
            data["actions"] = torch.as_tensor(transitions.actions, dtype=torch.long).reshape(-1)
            data["next_actions"] = torch.as_tensor(next_actions, dtype=torch.long).reshape(-1)
        else:
            data["actions"] = torch.as_tensor(transitions.actions, dtype=torch.float32)
            data["next_actions"] = torch.as_tensor(critic.scale_actions(next_actions))
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

    def q(network: TermCritic, obs: torch.Tensor, actions: torch.Tensor | None) -> torch.Tensor:
        if critic.spec.state_value:
            return network(obs)
        return network(obs)[rows, actions] if critic.spec.discrete else network(obs, actions)

    with torch.no_grad():
        targets = batch["terms"] + gamma * batch["continues"] * q(
            target, batch["next_obs"], batch.get("next_actions")
        )
    return torch.nn.functional.mse_loss(q(critic, batch["obs"], batch.get("actions")), targets)


@holds_folder_lock(lambda call: call.arguments["out_dir"])
def fit_state_critics(
    out_dir: str | Path,
    names: Sequence[str] | None = None,
    options: TermCriticOptions = STATE_CRITIC_OPTIONS,
    seed: int = 0,
) -> dict[str, dict[str, object]]:
    """
    Give each worker of a run folder a critic fitted on rollouts of its policy (:func:`rollout_transitions`)
    in place of the critic its zip holds, the critics GPI and a start from GPI act with: a continuous worker a
    state value over the shared env's full state (kind ``state_value``), a discrete one its ``Q(s, a)`` over
    its own observation (kind ``discrete``). Each zip is rewritten whole and the manifest records the new hash
    and the critic's facts, its rollouts' ``env_steps`` among them.

    :param out_dir: the run folder of ``train-workers`` (or its ``workers`` folder): its workers all act with
        continuous actions or all with discrete ones (GPI compares critics of one kind only).
    :param names: which workers (default: all).
    :param options: the critics' settings (default: :data:`STATE_CRITIC_OPTIONS`).
    :param seed: seeds the rollouts' noise and the critics' training.
    :return: worker name -> the critic's facts, as the manifest records them.
    """
    use_one_thread_unless_chosen()  # torch's default of one thread per core makes these small nets crawl
    workers = load_workers(out_dir, names=names)
    if workers.folder is None:
        raise ValueError(f"{str(out_dir)!r}: no workers folder")
    everyone = load_workers(out_dir) if names else workers
    discrete = {n: isinstance(m.action_space, gym.spaces.Discrete) for n, m in everyone.items()}
    if len(set(discrete.values())) > 1:
        raise ValueError(
            f"{str(workers.folder)!r} mixes discrete workers {[n for n, d in discrete.items() if d]} with "
            "continuous ones: their critics would be of two kinds, which GPI does not compare"
        )
    manifest_path = workers.folder / "manifest.json"
    manifest = workers.manifest
    done: dict[str, dict[str, object]] = {}
    with contextlib.closing(workers.make_env()) as env:
        bounds = dict(env_contract(env).reward_bounds)
        layout = state_layout_of(env)
        for name, model in workers.items():
            indices = layout.indices(workers.states[name]) if name in workers.states else None
            transitions = rollout_transitions(FrozenWorker(model, indices), env, bounds, options, seed)
            if discrete[name] and indices is not None:  # its Q is over what it sees, as GPI gives it
                seen = {"obs": transitions.obs[:, indices], "next_obs": transitions.next_obs[:, indices]}
                transitions = dataclasses.replace(transitions, **seen)
            policy = model if discrete[name] else None
            critic, fit_facts = fit_term_critic(policy, transitions, list(bounds), options, seed)
            path = workers.folder / str(manifest.entries[name]["file"])
            data = with_term_critic(path.read_bytes(), critic)
            kind = "discrete" if discrete[name] else "state_value"
            facts = {"member": TERM_CRITIC_MEMBER, "terms": list(bounds), "kind": kind,
                     "env_steps": len(transitions), **fit_facts}  # fmt: skip
            atomic_write_bytes(path, data)
            entry = {
                **manifest.entries[name],
                "sha256": hashlib.sha256(data).hexdigest(),
                "term_critic": facts,
            }
            manifest = manifest.with_entry(name, entry)
            save_manifest(manifest_path, manifest)
            done[name] = facts
    return done

"""
The ``hddpg-gpi`` method of the hierarchy's side of MORL-baselines' protocol (:mod:`.morl_sides`): per-term
workers with per-term critics, a support of weighted workers grown by optimistic linear support
(:func:`~sb3_hddpg.training.grow.grow`), and generalized policy improvement over all of them
(:class:`~sb3_hddpg.hierarchy.gpi.GpiSelector`) for each weight the protocol plays. No manager is trained.

Why the protocol's weight is not the critics' weight. The weighted workers learn, and every critic values,
the per-step min-max normalised terms ``n_i = (r_i - lo_i) / range_i`` (the pinned env's bounds), while the
protocol weighs the raw objectives ``r_i``. With ``L = sum_t gamma^t`` over the rest of the episode, a
policy's discounted raw value is ``V_i = lo_i L + range_i N_i``, so ``w . V = sum_i w_i range_i N_i +
(w . lo) L``:

- the first part is GPI at the coefficients ``w_i range_i`` on the normalised critics;
- the offset ``(w . lo) L`` is the same for every worker and action only when episodes have a fixed length
  (half-cheetah never terminates). When the env has a constant objective ``c`` that normalises to ``n_c != 0``
  every step, its critic is ``N_c = n_c L``: the exact coefficient of ``c`` is then
  ``w_c range_c + (w . lo) / n_c``, which may be negative. A GPI hierarchy refuses negative preferences
  (the library's weights are >= 0), so the policy here calls the selector itself, whose scores take any real
  coefficients.
- Otherwise (minecart, hopper: episodes of varying length, no constant objective) the offset is unknown and
  left out: GPI then ranks by the first part only, an approximation wherever episode lengths differ.

The constant objective is pinned with its sign (:func:`~.morl_sides.pinned_env`: deep-sea-treasure's time,
-1 every step, normalises to -1, ``lo = 0``), not to 1: a per-term worker learns its raw term, so only then
does the time worker's corner of the simplex mean what ``grow`` takes it to mean
(shorter episodes), and the weighted workers it grows at inner corners rank episodes as a non-negative raw
weighting does. On deep-sea-treasure the coefficients are then exactly ``w_i range_i`` (``w . lo = 0``).
"""

from __future__ import annotations

import contextlib
import functools
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from hddpg_zoo.benchmark.methods import worker_steps
from hddpg_zoo.benchmark.morl_sides import (
    ProtocolMethod,
    SideRun,
    TrainedSide,
    constant_objectives,
    pinned_env,
    register_protocol_method,
)
from sb3_hddpg.artifacts.manifests import load_workers
from sb3_hddpg.artifacts.workers import Workers
from sb3_hddpg.envs.contract import env_contract, state_layout_of
from sb3_hddpg.envs.terms_env import TermsEnv
from sb3_hddpg.hierarchy.frozen import FrozenWorker
from sb3_hddpg.hierarchy.gpi import GpiSelector, gpi_of
from sb3_hddpg.training.grow import SupportOptions, grow
from sb3_hddpg.training.run_options import RunOptions
from sb3_hddpg.training.term_critic import TermCriticOptions
from sb3_hddpg.training.workers import train_workers

#: The weighted workers the support may add beyond one per objective; every worker gets an equal share.
GPI_EXTRA_WORKERS = 3
#: Each share is a whole multiple of this: SB3's DQN collects ``train_freq`` steps at a time (4 in the bundled
#: config) and would overshoot a share that is not one, past the budget.
STEP_QUANTUM = 4


def gpi_coefficients(
    weights: Sequence[float],
    terms: Sequence[str],
    bounds: Mapping[str, Sequence[float]],
    constant: Mapping[str, float] | None = None,
) -> dict[str, float]:
    """
    The coefficients on the normalised critics that rank by the protocol's weight of the raw objectives
    (module docstring): ``w_i range_i`` per term, and on the first constant objective ``c`` with a non-zero
    normalised value ``n_c`` also ``(w . lo) / n_c``, the offset its critic (``n_c`` times the discounted
    remaining length) carries. They may be negative.

    :param weights: the protocol's weight, one per term of ``terms``.
    :param terms: the objectives, in the weight's order.
    :param bounds: term -> the per-step ``(low, high)`` the terms are normalised with.
    :param constant: the objectives constant every step -> their raw value.
    """
    lows = {t: float(bounds[t][0]) for t in terms}
    ranges = {t: float(bounds[t][1]) - lows[t] for t in terms}
    coefficients = {t: float(w) * ranges[t] for t, w in zip(terms, weights)}
    normalised = {t: (float(v) - lows[t]) / ranges[t] for t, v in (constant or {}).items() if t in lows}
    carriers = [t for t in terms if normalised.get(t, 0.0) != 0.0]
    if carriers:
        offset = sum(float(w) * lows[t] for t, w in zip(terms, weights))
        coefficients[carriers[0]] += offset / normalised[carriers[0]]
    return coefficients


class GpiPolicy:
    """
    GPI over a support's workers as a :class:`~.morl_sides.WeightedPolicy` of the env's raw objectives.

    :param selector: the GPI selector over the workers and their normalised critics.
    :param terms: the objectives, in the protocol's weight order.
    :param bounds: term -> the per-step ``(low, high)`` the critics' terms are normalised with.
    :param constant: the objectives constant every step -> their raw value.
    """

    def __init__(
        self,
        selector: GpiSelector,
        terms: Sequence[str],
        bounds: Mapping[str, Sequence[float]],
        constant: Mapping[str, float],
    ) -> None:
        self.selector = selector
        self.terms = list(terms)
        self.bounds = {t: tuple(float(v) for v in bounds[t]) for t in self.terms}
        self.constant = dict(constant)
        self.coefficients: dict[str, float] = {}
        self.set_weights([1.0 / len(self.terms)] * len(self.terms))

    def set_weights(self, weights: Sequence[float]) -> None:
        """
        Play the protocol's weight from now on.

        :param weights: the weight of the raw objectives, one per term of ``terms``.
        """
        self.coefficients = gpi_coefficients(weights, self.terms, self.bounds, self.constant)

    def reset_episode(self) -> None:
        """GPI decides anew at every step: nothing carries over."""

    def act(self, obs: np.ndarray) -> np.ndarray:
        """
        GPI's action at the current weight's coefficients.

        :param obs: the shared env's observation.
        """
        # Not through Hierarchy.set_preference: the coefficients may be negative, which it refuses.
        _, action = self.selector.select(np.asarray(obs, dtype=np.float32), self.coefficients)
        return action


def gpi_selector(folder: Path) -> GpiSelector:
    """
    The GPI selector over a folder's workers and their critics, each seeing its own state components.

    :param folder: the run folder (its ``workers/``).
    """
    workers = load_workers(folder)
    return gpi_of(frozen_workers(workers), workers.critics, list(workers))


def frozen_workers(workers: Workers) -> list[FrozenWorker]:
    """Loaded workers frozen for GPI, in their order, each seeing its own entries of the shared state."""
    with contextlib.closing(workers.make_env()) as env:
        layout = state_layout_of(env)
    return [
        FrozenWorker(model, layout.indices(workers.states[name]) if name in workers.states else None)
        for name, model in workers.items()
    ]


def trained_steps(folder: Path) -> dict[str, int]:
    """
    Each worker's env steps as its manifest records them (``workers/<name>``), critics' rollouts included.

    :param folder: the run folder (its ``workers/manifest.json``).
    """
    return {f"workers/{name}": steps for name, steps in worker_steps(folder).items()}


def train_gpi_workers(
    run: SideRun, extra_workers: int = GPI_EXTRA_WORKERS, continuous_algo: str = "ddpg"
) -> tuple[TermsEnv, dict[str, tuple[float, float]], int]:
    """
    One worker per objective (DQN on discrete actions, ``continuous_algo`` on continuous), then the weighted
    workers ``grow`` adds at the corner weights of largest optimistic gain, every worker with a per-term critic
    at the protocol's discount, its transitions kept, and an equal share of one budget.

    :param run: the env, seed, budget, discount and folder of the run.
    :param extra_workers: the weighted workers the support may add (0: the per-term workers alone, which then
        share the whole budget).
    :param continuous_algo: the per-term workers' algorithm on continuous actions, read with its bundled
        ``zoo_configs`` block of the env; the weighted workers take their heaviest term's.
    :return: the shared env, its per-term bounds, and the env steps spent estimating them.
    """
    shared, bounds_steps = pinned_env(run.env_id)
    terms = list(shared.terms)
    available = run.budget - bounds_steps
    share = available // (len(terms) + extra_workers) // STEP_QUANTUM * STEP_QUANTUM
    if share < 1:
        raise ValueError(
            f"A budget of {run.budget} env steps ({bounds_steps} to estimate bounds) trains no model"
        )
    critic = TermCriticOptions(gamma=run.gamma)
    options = RunOptions(seed=run.seed, eval_freq=0, eval_episodes=1, keep_best=False)
    algo = "dqn" if run.discrete else continuous_algo
    train_workers(
        run.folder,
        env=shared,
        algos=dict.fromkeys(terms, algo),
        run=options.replace(timesteps=share),
        term_critic=critic,
        keep_transitions=True,
    )
    # Whatever the per-term workers left of their shares stays unspent: the support takes its own shares.
    support_budget = min(extra_workers * share, available - sum(trained_steps(run.folder).values()))
    if support_budget >= 1:
        grow(
            run.folder,
            SupportOptions(len(terms) + extra_workers, support_budget),
            run=options,
            env=shared,
            term_critic=critic,
        )
    with contextlib.closing(shared.make()) as env:
        bounds = dict(env_contract(env).reward_bounds)
    return shared, bounds, bounds_steps


def train_gpi(
    run: SideRun, extra_workers: int = GPI_EXTRA_WORKERS, continuous_algo: str = "ddpg"
) -> TrainedSide:
    """
    :func:`train_gpi_workers`' support; GPI over all of its workers plays each weight.

    :param run: the env, seed, budget, discount and folder of the run.
    :param extra_workers: the weighted workers the support may add (0: GPI over the per-term workers alone).
    :param continuous_algo: the per-term workers' algorithm on continuous actions.
    """
    started = time.perf_counter()
    shared, bounds, bounds_steps = train_gpi_workers(run, extra_workers, continuous_algo)
    policy = GpiPolicy(gpi_selector(run.folder), list(shared.terms), bounds, constant_objectives(run.env_id))
    steps = {**trained_steps(run.folder), "bounds": bounds_steps}
    return TrainedSide(policy, shared, steps, time.perf_counter() - started)


GPI_METHOD = register_protocol_method(
    ProtocolMethod(
        "hddpg-gpi",
        f"one worker per objective and up to {GPI_EXTRA_WORKERS} weighted workers grown by optimistic linear "
        "support, each with per-term critics and an equal share of the budget; GPI over them plays each weight, "
        "its coefficients on the normalised critics ranking by the raw weight exactly where episodes have one "
        "length (half-cheetah) or an objective is constant (deep-sea-treasure's time, pinned with its sign), "
        "and on minecart and hopper without the offset the episode's length adds (an approximation)",
        train_gpi,
    )
)

GPI_TERMS_METHOD = register_protocol_method(
    ProtocolMethod(
        "hddpg-gpi-terms",
        "GPI as hddpg-gpi's over the per-term workers alone, which share the whole budget (no support is grown: "
        "where the convex coverage set is the objectives' own optima, its budget goes to finding them)",
        functools.partial(train_gpi, extra_workers=0),
    )
)

GPI_SAC_METHOD = register_protocol_method(
    ProtocolMethod(
        "hddpg-gpi-sac",
        "hddpg-gpi with SAC workers at CAPQL's learner settings (its discount 0.99, [256, 256] networks, "
        "learning rate, batch and buffer; SB3's automatic entropy coefficient, since the workers learn "
        "normalised terms where CAPQL's fixed 0.2 weighs raw ones), on continuous actions",
        functools.partial(train_gpi, continuous_algo="sac"),
        actions="continuous",
    )
)

GPI_TERMS_SAC_METHOD = register_protocol_method(
    ProtocolMethod(
        "hddpg-gpi-terms-sac",
        "GPI over hddpg-gpi-sac's per-term SAC workers alone, which share the whole budget (no weighted workers, "
        "whose critics hddpg-gpi-sac's GPI can overrate)",
        functools.partial(train_gpi, extra_workers=0, continuous_algo="sac"),
        actions="continuous",
    )
)


__all__ = [
    "GPI_EXTRA_WORKERS",
    "GPI_METHOD",
    "GPI_SAC_METHOD",
    "GPI_TERMS_METHOD",
    "GPI_TERMS_SAC_METHOD",
    "STEP_QUANTUM",
    "GpiPolicy",
    "frozen_workers",
    "gpi_coefficients",
    "gpi_selector",
    "train_gpi",
    "train_gpi_workers",
]

"""
The ``hddpg-gpi-raw`` methods of the protocol's hierarchy side: :mod:`.morl_gpi`'s per-term workers, valued by
critics of the raw objectives, and GPI over the workers' own actions.

Why another critic. The workers' critics value the normalised terms ``n_i = (r_i - lo_i) / range_i``, so a
weight ``w`` of the raw objectives ranks by ``sum_i w_i range_i N_i`` only up to the offset ``(w . lo) L``,
``L`` the discounted length of the rest of the episode (:mod:`.morl_gpi`). Where episodes differ in length
that offset decides: minecart's fuel term is at least -1 a step and about -0.005 when idle, so it normalises
to about 1 a step, and GPI valued the cart that never went home above every other (at 150k env steps every
weight played one 1,000-step episode without ore). A critic fitted on the raw terms (``lo + range n`` of the
same transitions) has no offset: ``w . Q`` is the raw weight's value on episodes of any length.

Why over the workers' own actions. A critic is fitted on its worker's own transitions, so it is least
reliable at the actions the worker rarely takes, which GPI over actions reads: on minecart it chose, for
every weight, an action no worker takes (braking for 1,000 steps).

``hddpg-gpi-raw`` decides at every step; ``hddpg-gpi-raw-hold`` decides at the episode's first step and
follows that worker to the end (the front of the workers themselves: it cannot dither between two workers
heading apart, as per-step GPI did on minecart at weights between its two ores).
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from hddpg_zoo.benchmark.morl_gpi import frozen_workers, train_gpi_workers, trained_steps
from hddpg_zoo.benchmark.morl_sides import (
    ProtocolMethod,
    SideRun,
    TrainedSide,
    register_protocol_method,
)
from sb3_hddpg.artifacts.manifests import load_workers
from sb3_hddpg.artifacts.transitions import TRANSITIONS_SUFFIX, Transitions
from sb3_hddpg.hierarchy.gpi import GpiSelector
from sb3_hddpg.training.term_critic import TermCriticOptions, fit_term_critic


def raw_selector(folder: Path, bounds: Mapping[str, Sequence[float]], gamma: float, seed: int) -> GpiSelector:
    """
    GPI over a folder's workers, each valued by a critic of the raw objectives fitted on the transitions it
    kept (``train_workers(keep_transitions=True)``), over the workers' own actions.

    :param folder: the run folder (its ``workers/``).
    :param bounds: term -> the per-step ``(low, high)`` the kept transitions' terms are normalised with.
    :param gamma: the critics' discount (the protocol's).
    :param seed: seeds each critic's initial weights and batches.
    """
    workers = load_workers(folder)
    critics = []
    for name, model in workers.items():
        kept = Transitions.load(folder / "workers" / f"{name}{TRANSITIONS_SUFFIX}")
        terms = workers.critics[name].spec.terms  # the kept terms' columns, in this order
        lows = np.array([bounds[t][0] for t in terms], dtype=np.float32)
        ranges = np.array([bounds[t][1] for t in terms], dtype=np.float32) - lows
        raw = dataclasses.replace(kept, terms=kept.terms * ranges + lows)
        critics.append(fit_term_critic(model, raw, terms, TermCriticOptions(gamma=gamma), seed)[0])
    frozen = frozen_workers(workers)
    return GpiSelector(frozen, critics, over_actions=False)


class RawGpiPolicy:
    """
    GPI over raw-objective critics as a :class:`~.morl_sides.WeightedPolicy`.

    :param selector: :func:`raw_selector`'s.
    :param terms: the objectives, in the protocol's weight order.
    :param hold: follow the worker picked at an episode's first step to its end.
    """

    def __init__(self, selector: GpiSelector, terms: Sequence[str], hold: bool) -> None:
        self.selector = selector
        self.terms = list(terms)
        self.hold = hold
        self.preference: dict[str, float] = {}
        self.held: int | None = None
        self.set_weights([1.0 / len(self.terms)] * len(self.terms))

    def set_weights(self, weights: Sequence[float]) -> None:
        """Play the protocol's weight of the raw objectives (one per term of ``terms``) from now on."""
        self.preference = {t: float(w) for t, w in zip(self.terms, weights)}

    def reset_episode(self) -> None:
        """A held worker is held for one episode."""
        self.held = None

    def act(self, obs: np.ndarray) -> np.ndarray:
        """GPI's action at the current weight, or the held worker's."""
        obs = np.asarray(obs, dtype=np.float32)
        if self.held is not None:  # a frozen worker picks its own entries of the state
            return np.asarray(self.selector.workers[self.held].act(obs))
        index, action = self.selector.select(obs, self.preference)
        if self.hold:
            self.held = index
        return action


def train_gpi_raw(run: SideRun, hold: bool = False, continuous_algo: str = "ddpg") -> TrainedSide:
    """
    :func:`~.morl_gpi.train_gpi_workers`' per-term workers alone, sharing the budget, each keeping its
    transitions; then each worker's raw-objective critic (:func:`raw_selector`); GPI over them plays each
    weight.

    :param run: the env, seed, budget, discount and folder of the run.
    :param hold: follow the worker picked at an episode's first step to its end.
    :param continuous_algo: the workers' algorithm on continuous actions, with its bundled block of the env.
    """
    started = time.perf_counter()
    shared, bounds, bounds_steps = train_gpi_workers(run, 0, continuous_algo)
    terms = list(shared.terms)
    policy = RawGpiPolicy(raw_selector(run.folder, bounds, run.gamma, run.seed), terms, hold)
    steps = {**trained_steps(run.folder), "bounds": bounds_steps}
    return TrainedSide(policy, shared, steps, time.perf_counter() - started)


GPI_RAW_METHOD = register_protocol_method(
    ProtocolMethod(
        "hddpg-gpi-raw",
        "hddpg-gpi-terms' per-term workers, each valued by a critic of the raw objectives (no offset on episodes "
        "of varying length), and GPI over the workers' own actions at every step",
        train_gpi_raw,
    )
)

GPI_RAW_HOLD_METHOD = register_protocol_method(
    ProtocolMethod(
        "hddpg-gpi-raw-hold",
        "hddpg-gpi-raw deciding at an episode's first step only: the worker GPI picks there plays the episode",
        functools.partial(train_gpi_raw, hold=True),
    )
)

GPI_RAW_SAC_METHOD = register_protocol_method(
    ProtocolMethod(
        "hddpg-gpi-raw-sac",
        "hddpg-gpi-raw over SAC workers at CAPQL's learner settings (hddpg-gpi-terms-sac's workers), on "
        "continuous actions",
        functools.partial(train_gpi_raw, continuous_algo="sac"),
        actions="continuous",
    )
)


__all__ = [
    "GPI_RAW_HOLD_METHOD",
    "GPI_RAW_METHOD",
    "GPI_RAW_SAC_METHOD",
    "RawGpiPolicy",
    "raw_selector",
    "train_gpi_raw",
]

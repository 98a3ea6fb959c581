"""
Generalized policy improvement (GPI; Barreto et al. 2017, "Successor features for transfer in RL"): acting
for a weighting ``w`` of the reward terms with the workers' per-term critics, without training a manager.

For continuous-action workers the worker ``i`` maximising ``w . Q_i(s, pi_i(s))`` acts (or ``w . V_i(s)``
with state-value critics, which see the full state); for discrete-action workers the action
``argmax_a max_i w . Q_i(s, a)`` is taken. For every ``w`` the result is at least as good
as each worker alone, up to the critics' errors; ``Hierarchy`` uses it for ``selection="gpi"``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from sb3_hddpg.artifacts.term_critic import TermCritic
from sb3_hddpg.envs.weighted import check_term_weights
from sb3_hddpg.hierarchy.frozen import FrozenWorker

#: The selection mode of a hierarchy that acts by GPI (no manager; the preference weighs the terms).
GPI_SELECTION = "gpi"
#: GPI over the workers' own actions: the worker maximising ``w . Q_i(s, pi_i(s))`` acts, also for discrete
#: workers, whose critics are then read only where their data is (their own actions).
GPI_POLICIES_SELECTION = "gpi-policies"
#: Every selection mode that acts by GPI.
GPI_SELECTIONS = (GPI_SELECTION, GPI_POLICIES_SELECTION)


class GpiSelector:
    """
    GPI over workers that each carry a per-term critic (``Hierarchy.gpi`` builds one over loaded workers).

    :param workers: the frozen workers (each with the observation indices it sees).
    :param critics: each worker's critic, in the same order: over the same terms, of one discount, all of
        one kind (continuous, discrete or state values).
    :param over_actions: for discrete workers, take ``argmax_a max_i w . Q_i(s, a)`` (GPI over actions); else
        the action of the worker maximising ``w . Q_i(s, pi_i(s))``. A critic fitted on a worker's own
        transitions or rollouts is least reliable at the actions the worker rarely takes, which only GPI over
        actions reads.
    """

    def __init__(
        self, workers: Sequence[FrozenWorker], critics: Sequence[TermCritic], over_actions: bool = True
    ) -> None:
        if len(workers) != len(critics) or not workers:
            raise ValueError(
                f"Expected one critic per worker, actually {len(critics)} for {len(workers)} workers"
            )
        specs = [critic.spec for critic in critics]
        for what, values in (
            ("over the same terms", [s.terms for s in specs]),
            ("of one discount (their values would not compare)", [s.gamma for s in specs]),
            (
                "of one kind (continuous, discrete or state values)",
                [(s.discrete, s.state_value) for s in specs],
            ),
        ):
            if any(value != values[0] for value in values):
                raise ValueError(f"Expected every critic {what}, actually: {values}")
        terms = specs[0].terms
        for index, (worker, critic) in enumerate(zip(workers, critics)):
            space = getattr(worker.worker, "observation_space", None)
            size = int(np.prod(space.shape)) if space is not None and space.shape else None
            if size is not None and size != critic.spec.obs_dim and not critic.spec.state_value:
                raise ValueError(
                    f"Worker {index} observes {size} values, its critic {critic.spec.obs_dim}: not its critic"
                )
        self.workers = list(workers)
        self.critics = list(critics)
        #: The terms the preference weighs, in the critics' order.
        self.terms = tuple(terms)
        self.discrete = critics[0].spec.discrete
        self.over_actions = over_actions
        self.state_value = critics[0].spec.state_value

    def scores(self, obs: np.ndarray, preference: Mapping[str, float]) -> tuple[np.ndarray, list[np.ndarray]]:
        """
        ``w . Q_i`` of every worker for one observation: shape ``(n_workers,)`` for continuous workers (of
        each one's own action, or of the state), ``(n_workers, n_actions)`` for discrete ones; and each
        worker's own action (none with state-value critics).
        """
        w = np.array([float(preference.get(term, 0.0)) for term in self.terms], dtype=np.float32)
        if self.state_value:  # values of the state alone: only the chosen worker need act
            return np.array([critic.values(obs[None])[0] @ w for critic in self.critics]), []
        actions = [worker.act(obs) for worker in self.workers]
        rows = []
        for worker, critic, action in zip(self.workers, self.critics, actions):
            seen = obs if worker.obs_indices is None else obs[..., worker.obs_indices]
            values = critic.values(seen[None], None if self.discrete else np.asarray(action)[None])
            rows.append(values[0] @ w)
        return np.stack(rows), actions

    def select(self, obs: np.ndarray, preference: Mapping[str, float]) -> tuple[int, np.ndarray]:
        """
        The index of the worker GPI picks for one observation at ``preference`` (term -> weight), and the env
        action (for discrete workers GPI's, which may differ from that worker's own greedy one).
        """
        scores, actions = self.scores(obs, preference)
        if self.discrete and self.over_actions:
            worker, action = np.unravel_index(int(np.argmax(scores)), scores.shape)
            return int(worker), np.asarray(action, dtype=np.int64)
        if self.discrete:  # each worker valued at its own action
            own = [int(np.asarray(a).reshape(-1)[0]) for a in actions]
            best = int(np.argmax(scores[np.arange(len(own)), own]))
            return best, np.asarray(own[best], dtype=np.int64)
        best = int(np.argmax(scores))
        return best, np.asarray(actions[best] if actions else self.workers[best].act(obs))


def check_gpi_preference(preference: Mapping[str, object], terms: Sequence[str]) -> dict[str, float]:
    """
    A GPI hierarchy's preference: term -> weight, finite and >= 0 with a positive sum; a term not named gets
    the unweighted 1 (as a conditioned manager's names do). Only the ratio matters.

    :raises ValueError: one line naming the problem.
    """
    return check_term_weights({**dict.fromkeys(terms, 1.0), **dict(preference)}, list(terms), "preference")


def gpi_of(
    workers: Sequence[FrozenWorker],
    critics: Mapping[str, TermCritic],
    names: Sequence[str],
    selection: str = GPI_SELECTION,
) -> GpiSelector:
    """
    The GPI selector over named workers and their critics (a ``ValueError`` naming any without one), over
    actions or over the workers' own actions as ``selection`` (one of :data:`GPI_SELECTIONS`) says.
    """
    missing = [name for name in names if name not in critics]
    if missing:
        raise ValueError(
            f"GPI needs a per-term critic for every worker; {missing} have none (train-workers trains one for "
            "every off-policy worker)"
        )
    return GpiSelector(workers, [critics[name] for name in names], over_actions=selection == GPI_SELECTION)


def check_gpi_manager(manager: object | None, selection: str) -> None:
    """A hierarchy has a manager unless it selects by GPI, which acts with its workers' critics only."""
    if (manager is None) != (selection in GPI_SELECTIONS):
        raise ValueError(
            f"Expected a manager for selection {selection!r}, or none for {list(GPI_SELECTIONS)}"
            if manager is None
            else f"Selection {selection!r} acts with the workers' critics: it takes no manager"
        )

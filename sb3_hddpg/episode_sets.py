"""
The named sets of evaluation episodes: which seeds each kind of decision or score is measured on. Episode
``k`` of a set is reset with seed ``first_seed + k``; the sets are far apart, so that no choice is ever made
on the episodes that score the result of record (the final test set, scored only with ``final_test``).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class EpisodeSet:
    """
    One named block of episode seeds and what it is for.

    :param name: its name in records and docs.
    :param first_seed: the seed of its first episode (episode ``k``: ``first_seed + k``).
    :param role: what it is used for, one line for the docs.
    :param size: how many episodes the block holds: no other set starts within it.
    """

    name: str
    first_seed: int
    role: str
    size: int = 5_000

    def seeds(self, episodes: int) -> range:
        """
        The seeds of the first ``episodes`` episodes of the set.

        :raises ValueError: more episodes than the block holds (they would run into another set).
        """
        if not 1 <= episodes <= self.size:
            raise ValueError(
                f"Expected episodes of set {self.name!r} in [1, {self.size}], actually: {episodes}"
            )
        return range(self.first_seed, self.first_seed + episodes)

    def describe(self, episodes: int) -> dict[str, int | str]:
        """The record of an evaluation on the first ``episodes`` episodes of the set."""
        seeds = self.seeds(episodes)
        return {"name": self.name, "first_seed": seeds.start, "episodes": len(seeds)}


CURVE = EpisodeSet(
    "curve", 10_000, "learning curves; each learner's kept checkpoint; ham-tuned's threshold grid"
)
DEVELOPMENT = EpisodeSet(
    "development",
    15_000,
    "development scores: config values, study re-runs, benchmark runs without --final-test",
)
FRONTIER = EpisodeSet("frontier", 20_000, "post-hoc studies: the switch frontier over each seed's workers")
TUNING = EpisodeSet("tuning", 30_000, "hyperparameter studies: every trial's evaluations and pruning")
FINAL_TEST = EpisodeSet(
    "final-test", 900_000, "the final test set: scored once by the runs of record (benchmark --final-test)"
)
#: Episodes per trained model on the final test set.
FINAL_TEST_EPISODES = 100

#: Every set by name, in the order of the docs.
EPISODE_SETS: dict[str, EpisodeSet] = {s.name: s for s in (CURVE, DEVELOPMENT, FRONTIER, TUNING, FINAL_TEST)}


def episode_set(name: str) -> EpisodeSet:
    """
    The set of a name.

    :raises ValueError: an unknown name, naming the known ones.
    """
    if name not in EPISODE_SETS:
        raise ValueError(f"Unknown episode set {name!r}; choose from {list(EPISODE_SETS)}")
    return EPISODE_SETS[name]


__all__ = [
    "CURVE",
    "DEVELOPMENT",
    "EPISODE_SETS",
    "FINAL_TEST",
    "FINAL_TEST_EPISODES",
    "FRONTIER",
    "TUNING",
    "EpisodeSet",
    "episode_set",
]

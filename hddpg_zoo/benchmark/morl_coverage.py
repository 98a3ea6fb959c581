"""
Which points of a known front's convex coverage set each side of a protocol run recovers: on the envs whose
true front MO-Gymnasium knows (deep-sea-treasure-concave, minecart), the page counts them per side and seed,
and says in how many seeds each of the hierarchy's methods recovers every point a peer recovers.

A point of the convex coverage set is recovered where the side's front, at the point's inner weighting (the
region where it alone is optimal: :func:`~sb3_hddpg.training.linear_support.convex_coverage_set`), comes
within a small share of the known front's spread of utilities there: a linear-utility user at that weighting
then loses next to nothing. Points of a concave part of the front belong to no convex coverage set: no
weighting of the terms reaches them, and none is counted.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from hddpg_zoo.benchmark.morl_protocol_run import ProtocolRecord
from sb3_hddpg.training.linear_support import convex_coverage_set

#: The share of the known front's spread of utilities at a point's weighting within which it is recovered.
RECOVERY_SHARE = 0.01


def recovered_points(known: Sequence[Sequence[float]], front: Sequence[Sequence[float]]) -> frozenset[int]:
    """
    The indices (into ``known``) of the convex coverage set's points that ``front`` recovers.

    :param known: the true front, one row per point.
    :param front: a side's front (the protocol's per-weight mean discounted returns).
    """
    points = np.asarray(known, dtype=np.float64)
    played = np.asarray(front, dtype=np.float64)
    found = set()
    for index, weights in convex_coverage_set(points).items():
        utilities = points @ weights
        slack = RECOVERY_SHARE * float(utilities.max() - utilities.min())
        if float(np.max(played @ weights)) >= utilities[index] - slack:
            found.add(index)
    return frozenset(found)


def coverage_lines(records: Mapping[str, Mapping[int, ProtocolRecord]]) -> list[str]:
    """
    The page's block: per side the points recovered a seed and the seeds recovering all of them, then per
    hierarchy method and peer the seeds where the method recovers every point the peer recovers (none
    where the env's true front is unknown).
    """
    known = next(r for by in records.values() for r in by.values()).known_front
    if known is None:
        return []
    size = len(convex_coverage_set(np.asarray(known, dtype=np.float64)))
    found = {
        method: {seed: recovered_points(known, r.front) for seed, r in by.items()}
        for method, by in records.items()
    }
    lines = [
        f"Points of the true front's convex coverage set ({size}) recovered: a side recovers one where its "
        f"front's best utility at the point's weighting is within {RECOVERY_SHARE:.0%} of the true front's "
        "spread of utilities there.",
        "",
        "| side | points recovered a seed | seeds recovering every point |",
        "|---|---|---|",
    ]
    for method, by_seed in found.items():
        counts = [len(points) for points in by_seed.values()]
        lines.append(
            f"| {method} | {np.mean(counts):.3g} of {size} | {sum(c == size for c in counts)} of {len(counts)} |"
        )
    lines.append("")
    sides = {method: next(iter(by.values())).side for method, by in records.items()}
    for method in (m for m, side in sides.items() if side == "hierarchy"):
        for peer in (m for m, side in sides.items() if side == "peer"):
            seeds = sorted(set(found[method]) & set(found[peer]))
            covered = sum(found[peer][s] <= found[method][s] for s in seeds)
            lines.append(
                f"- {method} recovers every point {peer} recovers in {covered} of {len(seeds)} seeds."
            )
    return [*lines, ""]


__all__ = ["RECOVERY_SHARE", "coverage_lines", "recovered_points"]

"""
Which points of a known front's convex coverage set each side of a protocol run recovers: on the envs whose
true front MO-Gymnasium knows (deep-sea-treasure-concave, minecart), the page counts them per side and seed,
and says in how many seeds each of the hierarchy's methods recovers every point a peer recovers.

A point of the convex coverage set is recovered where the side's front, at the point's inner weighting (the
region where it alone is optimal: :func:`convex_coverage_set`), comes
within a small share of the known front's spread of utilities there: a linear-utility user at that weighting
then loses next to nothing. Points of a concave part of the front belong to no convex coverage set: no
weighting of the terms reaches them, and none is counted.

On every env the page also counts, per seed, a peer's non-dominated points beyond every mixture of the
hierarchy's front (:func:`~.front_mixtures.points_beyond`): the points a manager switching between the
hierarchy's policies cannot reach, which a learner blending the objectives in one policy can.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from hddpg_zoo.benchmark.front_mixtures import points_beyond
from hddpg_zoo.benchmark.front_pages import MIXTURE_TOLERANCE
from hddpg_zoo.benchmark.morl_protocol_run import ProtocolRecord, hierarchy_peer_pairs
from sb3_hddpg.training.linear_support import corner_weights

#: The share of the known front's spread of utilities at a point's weighting within which it is recovered.
RECOVERY_SHARE = 0.01


def convex_coverage_set(values: np.ndarray, tolerance: float = 1e-7) -> dict[int, np.ndarray]:
    """
    The minimal convex coverage set of ``values`` (one row per policy or return, one column per term): the
    distinct rows that alone maximise ``w . V`` over some open region of weightings, each with an inner
    weighting of that region (the mean of the corner weights where it is optimal), where it beats every other
    distinct row by more than ``tolerance``. A row optimal only where it ties with others (on an edge of the
    front, weakly dominated, or a duplicate of an earlier row) is left out.

    :return: row index (the first of equal rows) -> its weighting, in row order.
    """
    values = np.atleast_2d(np.asarray(values, dtype=np.float64))
    _, first = np.unique(values, axis=0, return_index=True)
    rows = np.sort(first)
    distinct = values[rows]
    optimal_at: dict[int, list[np.ndarray]] = {}
    for w in corner_weights(distinct):
        scores = distinct @ w
        for row in np.flatnonzero(scores >= scores.max() - tolerance):
            optimal_at.setdefault(int(row), []).append(w)
    found: dict[int, np.ndarray] = {}
    for index, corners in sorted(optimal_at.items()):
        inner = np.mean(corners, axis=0)
        scores = distinct @ inner
        if np.all(np.delete(scores, index) < scores[index] - tolerance):
            found[int(rows[index])] = inner
    return found


def recovered_points(
    known: Sequence[Sequence[float]],
    front: Sequence[Sequence[float]],
    coverage: Mapping[int, np.ndarray] | None = None,
) -> frozenset[int]:
    """
    The indices (into ``known``) of the convex coverage set's points that ``front`` recovers.

    :param known: the true front, one row per point.
    :param front: a side's front (the protocol's per-weight mean discounted returns).
    :param coverage: ``known``'s convex coverage set, if already found (else it is found here).
    """
    points = np.asarray(known, dtype=np.float64)
    played = np.asarray(front, dtype=np.float64)
    found = set()
    for index, weights in (coverage if coverage is not None else convex_coverage_set(points)).items():
        utilities = points @ weights
        slack = RECOVERY_SHARE * float(utilities.max() - utilities.min())
        if float(np.max(played @ weights)) >= utilities[index] - slack:
            found.add(index)
    return frozenset(found)


def coverage_lines(records: Mapping[str, Mapping[int, ProtocolRecord]]) -> list[str]:
    """
    The page's block: per side the points recovered a seed and the seeds recovering all of them, then per
    hierarchy method and peer, among the seeds where the peer recovers some point, those where the method
    recovers every point the peer recovers (none where the env's true front is unknown).
    """
    known = next(r for by in records.values() for r in by.values()).known_front
    if known is None:
        return []
    coverage = convex_coverage_set(np.asarray(known, dtype=np.float64))
    found = {
        method: {seed: recovered_points(known, r.front, coverage) for seed, r in by.items()}
        for method, by in records.items()
    }
    size = len(coverage)
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
    for method, peer in hierarchy_peer_pairs(records):
        seeds = sorted(set(found[method]) & set(found[peer]))
        some = [s for s in seeds if found[peer][s]]
        covered = sum(found[peer][s] <= found[method][s] for s in some)
        lines.append(
            f"- {method} recovers every point {peer} recovers in {covered} of the {len(some)} seeds where "
            f"{peer} recovers one ({peer} recovers none in {len(seeds) - len(some)})."
        )
    return [*lines, ""]


def beyond_mixture_lines(records: Mapping[str, Mapping[int, ProtocolRecord]]) -> list[str]:
    """
    Per hierarchy method and peer, the peer's non-dominated points (those its indicators are computed on)
    beyond every mixture of the method's front points, per seed (``k of n``), and the largest margin (in the
    objectives' own units).
    """
    lines = []
    for method, peer in hierarchy_peer_pairs(records):
        counts, widest = [], 0.0
        for seed in sorted(set(records[method]) & set(records[peer])):
            theirs = records[peer][seed].non_dominated
            margins = points_beyond(theirs, records[method][seed].front, [True] * len(theirs[0]))
            counts.append(f"{sum(m > MIXTURE_TOLERANCE for m in margins)} of {len(margins)}")
            widest = max(widest, *margins)
        if counts:
            lines.append(
                f"- {peer}'s non-dominated points beyond every mixture of {method}'s (what switching between "
                f"its policies reaches, to first order), per seed: {', '.join(counts)}; the farthest by "
                f"{widest:.3g} on every objective at once."
            )
    return [*lines, ""] if lines else []


__all__ = [
    "RECOVERY_SHARE",
    "beyond_mixture_lines",
    "convex_coverage_set",
    "coverage_lines",
    "recovered_points",
]

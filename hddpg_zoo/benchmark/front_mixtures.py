"""
What switching between a front's policies can reach, and which points of another front lie beyond it.

A manager that runs one policy for a share of an episode and another for the rest earns, to first order,
that mixture of their returns: the convex combinations of a front's points bound what a switch between its
policies reaches. A learner that blends the objectives in one policy can reach points beyond them, and
:func:`mixture_shortfall` measures by how much: the additive epsilon indicator of one point with respect to
those mixtures.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.optimize import linprog


def mixture_shortfall(
    point: Sequence[float], front: Sequence[Sequence[float]], larger: Sequence[bool]
) -> float:
    """
    The least amount every objective of some mixture (convex combination) of ``front``'s points must be
    raised by to weakly dominate ``point``.

    :param point: one point's objectives.
    :param front: the points whose mixtures are considered (at least one), with ``point``'s objectives.
    :param larger: per objective, whether a larger value is better.
    :return: above 0 where ``point`` lies beyond every mixture (by that margin on each objective at once); 0
        or below where a mixture reaches it.
    """
    sign = np.where(np.asarray(larger, dtype=bool), 1.0, -1.0)
    target, points = np.asarray(point, dtype=float), np.asarray(front, dtype=float)
    if points.ndim != 2 or points.shape[0] == 0 or not points.shape[1] == target.shape[0] == sign.shape[0]:
        raise ValueError("mixture_shortfall needs at least one front point with the point's objectives")
    # Every objective to maximise.
    target, points = sign * target, sign * points
    count, objectives = points.shape
    # Variables: the mixture's weights, then the shortfall s. Minimise s subject to
    # sum_i w_i * points[i, k] + s >= target[k] for every objective k, the weights on the simplex.
    cost = np.zeros(count + 1)
    cost[-1] = 1.0
    upper = np.hstack([-points.T, -np.ones((objectives, 1))])
    simplex = np.hstack([np.ones((1, count)), np.zeros((1, 1))])
    solved = linprog(
        cost,
        A_ub=upper,
        b_ub=-target,
        A_eq=simplex,
        b_eq=[1.0],
        bounds=[(0.0, None)] * count + [(None, None)],
        method="highs",
    )
    if not solved.success:
        raise ValueError(f"mixture_shortfall: the linear programme failed ({solved.message})")
    return float(solved.x[-1])


def points_beyond(
    points: Sequence[Sequence[float]], front: Sequence[Sequence[float]], larger: Sequence[bool]
) -> list[float]:
    """The :func:`mixture_shortfall` of each of ``points`` with respect to ``front``'s mixtures, in order."""
    return [mixture_shortfall(point, front, larger) for point in points]

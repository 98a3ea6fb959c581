"""
Optimistic linear support (OLS; Roijers 2015, the weight choice of GPI-LS, Alegre et al. 2023; MORL-baselines'
``multi_policy/linear_support/linear_support.py``): where on the simplex of term weightings a convex coverage
set of policies gains most from one more policy.

The scalarised front ``max_i w . V_i`` of the policies' vector values is piecewise-linear and convex in the
weighting ``w``; at each of its corner weights the optimistic gain is OLS's bound on a new policy's value
minus the front there, and the support grows at the corner of largest gain.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from sb3_hddpg.extras import linprog

#: Tolerance of the vertex and feasibility checks.
EPSILON = 1e-9


@dataclass(frozen=True)
class Corner:
    """
    A corner weight of the current front with its optimistic gain.

    :param weights: the weighting, on the simplex.
    :param value: the front's scalarised value there, ``max_i w . V_i``.
    :param optimistic: the optimistic bound there.
    """

    weights: tuple[float, ...]
    value: float
    optimistic: float

    @property
    def gain(self) -> float:
        """How much one more policy may add at this weighting, at most."""
        return self.optimistic - self.value


def corner_weights(values: np.ndarray) -> list[np.ndarray]:
    """
    The corner weights of the scalarised front of ``values`` (one row per policy, one column per term): the
    vertices of ``{(w, u): w >= 0, sum w = 1, u >= w . V_i for all i}``, found by solving every system of
    ``d`` active constraints (fine for the few terms and policies of a support).

    :return: the corner weightings, distinct, each on the simplex (the simplex's own corners included).
    """
    values = np.atleast_2d(np.asarray(values, dtype=np.float64))
    n_policies, d = values.shape
    # Each constraint as a row over (w_1..w_d, u) = 0: u - w.V_i = 0, or w_k = 0.
    rows = [np.append(-values[i], 1.0) for i in range(n_policies)]
    rows += [np.append(np.eye(d)[k], 0.0) for k in range(d)]
    simplex = np.append(np.ones(d), 0.0)
    found: list[np.ndarray] = []
    for chosen in itertools.combinations(range(len(rows)), d):
        system = np.stack([simplex, *(rows[i] for i in chosen)])
        if abs(np.linalg.det(system)) < EPSILON:
            continue
        solution = np.linalg.solve(system, np.append(1.0, np.zeros(d)))
        w, u = solution[:d], solution[d]
        if np.any(w < -EPSILON) or u < np.max(values @ w) - 1e-7:
            continue
        w = np.clip(w, 0.0, None) / np.clip(w, 0.0, None).sum()
        if not any(np.allclose(w, other, atol=1e-7) for other in found):
            found.append(w)
    return found


def optimistic_value(weights: np.ndarray, visited: Sequence[np.ndarray], values: np.ndarray) -> float:
    """
    OLS's upper bound at ``weights``: ``max_v w . v`` subject to ``w_j . v <= max_i w_j . V_i`` for every
    visited weighting ``w_j``.

    :param visited: the weightings the policies were trained for (the simplex's corners among them, or the
        bound is infinite).
    :return: the bound (``inf`` when the visited weightings do not bound it).
    """
    values = np.atleast_2d(np.asarray(values, dtype=np.float64))
    bounds_at = np.stack([np.asarray(w, dtype=np.float64) for w in visited])
    limits = np.max(bounds_at @ values.T, axis=1)
    result = linprog(-np.asarray(weights, dtype=np.float64), A_ub=bounds_at, b_ub=limits, bounds=(None, None))
    return float(-result.fun) if result.status == 0 else float("inf")


def ranked_corners(values: np.ndarray, visited: Sequence[np.ndarray]) -> list[Corner]:
    """
    Every corner weight of the front of ``values`` with its optimistic gain, largest gain first (ties: the
    order found, which is deterministic).

    :param values: one row per policy of the support, one column per term.
    :param visited: the weightings the support's policies were trained for.
    """
    values = np.atleast_2d(np.asarray(values, dtype=np.float64))
    corners = [
        Corner(tuple(float(v) for v in w), float(np.max(values @ w)), optimistic_value(w, visited, values))
        for w in corner_weights(values)
    ]
    return sorted(corners, key=lambda corner: -corner.gain)

"""Linear complementarity problems of contact impulses, numpy only.

The impulses ``lam`` of contact rows that may only push solve ``w = M lam - r >= 0``,
``lam >= 0``, ``lam . w = 0`` with ``M`` symmetric positive definite (the rows' dual matrix plus a
small regularization): the rows end at or above their bounds and a row pushes only where it ends
exactly at its bound.
"""

from __future__ import annotations

import numpy as np


class ComplementarityError(RuntimeError):
    """The active-set method did not find the solution within its bound."""


def solve_lcp(matrix: np.ndarray, rhs: np.ndarray, tolerance: float = 1e-10) -> tuple[np.ndarray, int]:
    """``lam`` minimizing ``lam.M lam / 2 - r.lam`` over ``lam >= 0`` (the LCP's solution), by the
    Lawson-Hanson active-set method written for a positive definite quadratic.

    Each outer iteration frees the row whose bound is most violated; the inner loop moves towards
    the unconstrained minimum on the free rows and stops at the first impulse that would turn
    negative (which rejoins the fixed rows). Unlike pivoting methods it never trusts the sign of a
    tiny multiplier of a nearly dependent row, so rows that outnumber the DOFs (sixteen samples on
    a patch with a few normal DOFs) do not make it cycle.

    Args:
        matrix: ``(m, m)`` symmetric positive definite ``M``.
        rhs: ``(m,)`` ``r``.
        tolerance: a row is violated when ``r - M lam`` exceeds this times ``max |r|``.

    Returns:
        ``(lam (m,), outer iterations)``.

    Raises:
        ComplementarityError: after ``3 m + 10`` outer iterations (never seen; the bound is explicit).
    """
    count = len(rhs)
    lam = np.zeros(count)
    if count == 0:
        return lam, 0
    limit = tolerance * max(float(np.abs(rhs).max()), 1e-300)
    free = np.zeros(count, dtype=bool)
    for iteration in range(1, 3 * count + 11):
        gradient = rhs - matrix @ lam  # the descent direction of the fixed rows' impulses
        candidates = np.where(free, -np.inf, gradient)
        entering = int(np.argmax(candidates))
        if candidates[entering] <= limit:
            return lam, iteration - 1
        free[entering] = True
        for _ in range(count + 1):
            trial = np.zeros(count)
            trial[free] = np.linalg.solve(matrix[np.ix_(free, free)], rhs[free])
            blocked = free & (trial <= 0.0)
            if not blocked.any():
                lam = trial
                break
            # step from lam towards trial until the first free impulse reaches zero
            ratios = lam[blocked] / (lam[blocked] - trial[blocked])
            step = float(ratios.min())
            lam = lam + step * (trial - lam)
            free &= lam > 0.0
            free[np.flatnonzero(blocked)[np.argmin(ratios)]] = False
            lam[~free] = 0.0
    raise ComplementarityError(f"contact impulses: the active-set method did not settle ({count} rows)")

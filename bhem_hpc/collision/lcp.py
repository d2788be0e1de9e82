"""Linear complementarity problems of contact impulses, numpy only.

The impulses ``lam`` of contact rows that may only push solve ``w = M lam - r >= 0``,
``lam >= 0``, ``lam . w = 0`` with ``M`` symmetric positive definite (the rows' dual matrix plus a
small regularization): the rows end at or above their bounds and a row pushes only where it ends
exactly at its bound.
"""

from __future__ import annotations

import numpy as np

from bhem_hpc.errors import UserError

#: Block-pivoting exchanges of all wrong rows allowed without fewer wrong rows than the best so far.
PIVOTING_TRIES = 3


class ComplementarityError(UserError, RuntimeError):
    """The active-set method did not find the solution within its bound."""


def solve_lcp(
    matrix: np.ndarray, rhs: np.ndarray, tolerance: float = 1e-10, max_pivoting: int = 30
) -> tuple[np.ndarray, int]:
    """``lam`` minimizing ``lam.M lam / 2 - r.lam`` over ``lam >= 0`` (the LCP's solution).

    Block principal pivoting first (:func:`block_pivoting`): it settles most contact problems in
    about ten dense solves, however many rows push. Where it has not within ``max_pivoting``
    iterations (nearly dependent rows can make it slow), the Lawson-Hanson active-set method
    (:func:`lawson_hanson`) solves the problem from the start. Both end with the impulses of the
    rows that push solved together in one dense solve, so for the same rows they agree bit for bit.

    Args:
        matrix: ``(m, m)`` symmetric positive definite ``M``.
        rhs: ``(m,)`` ``r``.
        tolerance: a row is violated when ``r - M lam`` exceeds this times ``max |r|``.
        max_pivoting: block-pivoting iterations before the active-set method takes over.

    Returns:
        ``(lam (m,), iterations of both methods)``.

    Raises:
        ComplementarityError: the active-set method did not settle within its bound.
    """
    if len(rhs) == 0:
        return np.zeros(0), 0
    limit = tolerance * max(float(np.abs(rhs).max()), 1e-300)
    impulses, pivoting = block_pivoting(matrix, rhs, limit, max_pivoting)
    if impulses is not None:
        return impulses, pivoting
    impulses, active_set = lawson_hanson(matrix, rhs, limit)
    return impulses, pivoting + active_set


def block_pivoting(
    matrix: np.ndarray, rhs: np.ndarray, limit: float, max_iterations: int
) -> tuple[np.ndarray | None, int]:
    """The LCP by block principal pivoting (Judice and Pires), with Kim and Park's safeguard.

    Rows are split into pushing (``lam`` from the dense solve on them) and resting (``lam = 0``).
    Every row on the wrong side (a pushing row with ``lam < 0``, a resting row with
    ``r - M lam > limit``) changes side at once while that shrinks the number of wrong rows, or
    within :data:`PIVOTING_TRIES` tries of the best so far; otherwise only the last wrong row
    does (Murty's rule, which ends in finitely many steps for a positive definite ``M``).

    Args:
        matrix: ``(m, m)`` symmetric positive definite ``M``.
        rhs: ``(m,)`` ``r``.
        limit: the largest ``r - M lam`` a resting row may keep.
        max_iterations: dense solves before giving up.

    Returns:
        ``(lam (m,), iterations)``, or ``(None, max_iterations)`` when it did not settle.
    """
    count = len(rhs)
    pushing = np.zeros(count, dtype=bool)
    fewest, tries = count + 1, PIVOTING_TRIES
    for iteration in range(1, max_iterations + 1):
        impulses = np.zeros(count)
        if pushing.any():
            impulses[pushing] = np.linalg.solve(matrix[np.ix_(pushing, pushing)], rhs[pushing])
        wrong = np.where(pushing, impulses < 0.0, rhs - matrix @ impulses > limit)
        wrong_count = int(np.count_nonzero(wrong))
        if wrong_count == 0:
            return impulses, iteration
        if wrong_count < fewest:
            fewest, tries = wrong_count, PIVOTING_TRIES
            pushing ^= wrong
        elif tries > 0:
            tries -= 1
            pushing ^= wrong
        else:
            last = int(np.flatnonzero(wrong)[-1])
            pushing[last] = not pushing[last]
    return None, max_iterations


def lawson_hanson(matrix: np.ndarray, rhs: np.ndarray, limit: float) -> tuple[np.ndarray, int]:
    """The LCP by the Lawson-Hanson active-set method written for a positive definite quadratic.

    Each outer iteration frees the row whose bound is most violated; the inner loop moves towards
    the unconstrained minimum on the free rows and stops at the first impulse that would turn
    negative (which rejoins the fixed rows). Unlike pivoting methods it never trusts the sign of a
    tiny multiplier of a nearly dependent row, so rows that outnumber the DOFs (sixteen samples on
    a patch with a few normal DOFs) do not make it cycle; it takes one dense solve per pushing row.

    Args:
        matrix: ``(m, m)`` symmetric positive definite ``M``.
        rhs: ``(m,)`` ``r``.
        limit: a fixed row is violated when ``r - M lam`` exceeds this.

    Returns:
        ``(lam (m,), outer iterations)``.

    Raises:
        ComplementarityError: after ``3 m + 10`` outer iterations (never seen; the bound is explicit).
    """
    count = len(rhs)
    lam = np.zeros(count)
    if count == 0:
        return lam, 0
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

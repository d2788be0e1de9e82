"""Where a line meets a ruled rational Bezier patch, exactly, compiled.

A patch of degree 1 along ``t`` (a ruled patch: planes, cylinders, cones, extrusions, lofts
between two curves, the faces of most CAD solids) has on each ruling a homogeneous point linear
in ``t``: ``X(s, t) = (1 - t) X0(s) + t X1(s)``. A line is where two planes ``n_a . (x - o) = 0``
meet; on the patch, ``f(s, t) = n_0 . (X - o W)`` and ``g(s, t) = n_1 . (X - o W)`` are linear in
``t`` with Bernstein polynomials ``f0, f1, g0, g1`` of degree ``p`` in ``s`` as coefficients, and
vanish together exactly where ``f0 g1 - g0 f1 = 0`` (a polynomial of degree ``2 p`` in ``s``),
at ``t = f0 / (f0 - f1)`` (or from ``g``, whichever is better conditioned). The roots come from
:func:`~bhem_hpc.compiled.bernstein_roots.bernstein_roots`: no subdivision, no Newton start that
may miss.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from bhem_hpc.compiled.bernstein_roots import MAX_DEGREE, bernstein_roots, bernstein_value
from bhem_hpc.compiled.patch_kernels import EDGE_SLACK

#: Below this share of the product of the planes' sizes the determinant counts as zero: the patch
#: projects onto a curve across the line.
DEGENERATE = 1e-12


@njit(cache=True, error_model="numpy")
def ruled_degree(rows: int, columns: int) -> int:
    """The degree along ``s`` of nets ``(P, rows, columns, 4)`` that are ruled (``columns = 2``, or
    ``rows = 2``: then transposed) and whose determinant's degree is within the root finder's, else 0."""
    p = max(rows, columns) - 1
    return p if (rows == 2 or columns == 2) and 2 * p <= MAX_DEGREE else 0


@njit(cache=True, error_model="numpy")
def ruled_net(net: np.ndarray, transposed: bool, out: np.ndarray) -> None:
    """``net`` into ``out (p + 1, 2, 4)``, its parameters swapped when ``transposed`` (degree 1 along
    ``s``: the ruling along ``t`` then)."""
    for i in range(out.shape[0]):
        for j in range(2):
            for c in range(4):
                out[i, j, c] = net[j, i, c] if transposed else net[i, j, c]


@njit(cache=True, error_model="numpy")
def ruled_work(degree: int):
    """Scratch for :func:`ruled_solutions` on nets of ``degree`` along ``s``: the plane rows ``(4, p
    + 1)`` (``f0, f1, g0, g1``), the product weights, the determinant's coefficients, the root
    finder's table, roots and counts, and the solutions ``(2 p + 2, 2)``."""
    n = 2 * degree
    products = np.empty((degree + 1, degree + 1))
    for r in range(degree + 1):
        for m in range(degree + 1):
            products[r, m] = _binomial(degree, r) * _binomial(degree, m) / _binomial(n, r + m)
    return (np.empty((4, degree + 1)), products, np.empty(n + 1), np.empty((2, n + 1, n + 1)), np.empty((n + 1, n + 1)),
            np.empty(n + 1, dtype=np.int64), np.empty((n + 2, 2)))  # fmt: skip


@njit(cache=True, error_model="numpy")
def _binomial(n: int, k: int) -> float:
    value = 1.0
    for m in range(1, k + 1):
        value = value * (n - k + m) / m
    return value


@njit(cache=True, error_model="numpy")
def _largest_magnitude(rows: np.ndarray, first: int, last: int, length: int) -> float:
    """``max |rows[first:last, :length]|`` (without the temporaries numpy's expression allocates)."""
    largest = 0.0
    for r in range(first, last):
        for k in range(length):
            largest = max(largest, abs(rows[r, k]))
    return largest


@njit(cache=True, error_model="numpy")
def ruled_solutions(degree: int, work) -> int:
    """The parameters ``(s, t)`` where the planes of rows ``work[0]`` (``f0, f1, g0, g1`` ``(4, p +
    1)``, set by the caller) meet the ruled patch of ``degree`` along ``s``, within EDGE_SLACK of
    its square, into ``work[6][:count]``; the count (at most ``2 p + 2``).

    Where the determinant vanishes everywhere, the patch projects onto a curve across the line
    (its rulings run along it: no crossing of measure), or it is a cone whose apex, a collapsed
    edge, is on the line: the line crosses there (a surface of revolution on its axis), at ``(1/2,
    edge)``."""
    rows, products, coefficients, table, roots, counts, solutions = work
    p = degree
    size_f, size_g = _largest_magnitude(rows, 0, 2, p + 1), _largest_magnitude(rows, 2, 4, p + 1)
    coefficients[:] = 0.0
    for r in range(p + 1):  # the product of Bernstein polynomials of degree p, in degree 2 p
        for m in range(p + 1):
            coefficients[r + m] += products[r, m] * (rows[0, r] * rows[3, m] - rows[2, r] * rows[1, m])
    count = 0
    if _largest_magnitude(coefficients.reshape(1, -1), 0, 1, 2 * p + 1) <= DEGENERATE * size_f * size_g:
        for edge in range(2):
            if (_largest_magnitude(rows, edge, edge + 1, p + 1) <= DEGENERATE * size_f
                    and _largest_magnitude(rows, 2 + edge, 3 + edge, p + 1) <= DEGENERATE * size_g):  # fmt: skip
                solutions[count, 0], solutions[count, 1] = 0.5, float(edge)
                count += 1
        return count
    for k in range(bernstein_roots(coefficients, -EDGE_SLACK, 1.0 + EDGE_SLACK, table, roots, counts)):
        s = roots[2 * p, k]
        f0, f1 = bernstein_value(rows[0], p, s), bernstein_value(rows[1], p, s)
        g0, g1 = bernstein_value(rows[2], p, s), bernstein_value(rows[3], p, s)
        if max(abs(f0 - f1), abs(g0 - g1)) == 0.0:
            continue  # the ruling through s runs along the line (a degenerate point of the determinant)
        t = f0 / (f0 - f1) if abs(f0 - f1) >= abs(g0 - g1) else g0 / (g0 - g1)
        if -EDGE_SLACK <= t <= 1.0 + EDGE_SLACK:
            solutions[count, 0], solutions[count, 1] = s, t
            count += 1
    return count

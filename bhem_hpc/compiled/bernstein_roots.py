"""Real roots of a univariate polynomial in Bernstein form, compiled: the roots of each derivative
split the interval into pieces on which the one above is monotone, and a sign change on a piece is
one root, found by Newton's method kept inside its bracket (Yuksel 2022, "High-performance
polynomial root finding for graphics"), from the highest derivative (a line) up to the polynomial.
A root of even multiplicity is found where it is an extremum of the polynomial (a critical point at
which the value is exactly zero); otherwise, as any root finder in floating point, it may be lost or
split into two."""

from __future__ import annotations

import numpy as np
from numba import njit

#: Newton or bisection steps for one bracketed root (bisection alone halves to round-off in 64).
ROOT_ITERATIONS = 64
#: Highest degree of the polynomials (Pascal's triangle is tabulated up to it: divisions cost more
#: than the rest of an evaluation).
MAX_DEGREE = 32
BINOMIALS = np.zeros((MAX_DEGREE + 1, MAX_DEGREE + 1))
for _n in range(MAX_DEGREE + 1):
    BINOMIALS[_n, 0] = 1.0
    for _k in range(1, _n + 1):
        BINOMIALS[_n, _k] = BINOMIALS[_n - 1, _k - 1] + BINOMIALS[_n - 1, _k]


@njit(cache=True, error_model="numpy")
def bernstein_value(coefficients: np.ndarray, degree: int, x: float) -> float:
    """``sum_k coefficients[k] B_k^degree(x)`` at any real ``x`` near ``[0, 1]`` (``degree`` at most
    :data:`MAX_DEGREE`): ``sum_k C(n, k) c_k x^k (1 - x)^(n - k)`` by Horner's scheme."""
    s = 1.0 - x
    power, value = 1.0, coefficients[0]
    for k in range(1, degree + 1):
        power *= x
        value = value * s + BINOMIALS[degree, k] * coefficients[k] * power
    return value


@njit(cache=True, error_model="numpy")
def _value_and_slope(table: np.ndarray, degree: int, x: float) -> tuple[float, float]:
    """The polynomial ``table[degree]`` and its derivative ``table[degree - 1]`` at ``x``, from their
    coefficients times the binomials (``table[1]``): ``sum_k b_k x^k (1 - x)^(m - k)`` by Horner's
    scheme, both in one loop."""
    s = 1.0 - x
    scaled, derivative = table[1, degree], table[1, degree - 1]
    power, value, slope = 1.0, scaled[0], derivative[0]
    for k in range(1, degree):
        power *= x
        value = value * s + scaled[k] * power
        slope = slope * s + derivative[k] * power
    return value * s + scaled[degree] * power * x, slope


@njit(cache=True, error_model="numpy")
def _bracketed_root(table: np.ndarray, degree: int, a: float, b: float, fa: float, fb: float) -> float:
    """The root in ``[a, b]`` of the polynomial of row ``degree`` of ``table`` (its only root there,
    ``fa fb < 0``); row ``degree - 1`` is its derivative."""
    x = a - fa * (b - a) / (fb - fa)  # the chord's root: a start inside the bracket
    for _ in range(ROOT_ITERATIONS):
        f, slope = _value_and_slope(table, degree, x)
        if f == 0.0:
            return x
        if (f < 0.0) == (fa < 0.0):
            a, fa = x, f
        else:
            b = x
        step = x - f / slope if slope != 0.0 else 0.5 * (a + b)
        if abs(step - x) <= 1e-14 * max(1.0, abs(x)):
            # converged (a last step that rounding puts beyond the bracket is not taken)
            return step if a <= step <= b else x
        if not a < step < b:  # Newton left the bracket: bisect
            step = 0.5 * (a + b)
        if b - a <= 1e-16 * max(1.0, abs(a)):
            return step
        x = step
    return x


@njit(cache=True, error_model="numpy")
def _derivative_row(table: np.ndarray, degree: int) -> None:
    """Row ``degree - 1`` of ``table`` (both layers) from row ``degree``: the derivative's Bernstein
    coefficients ``degree (c_(k+1) - c_k)``, and those times ``C(degree - 1, k)``."""
    for k in range(degree):
        table[0, degree - 1, k] = degree * (table[0, degree, k + 1] - table[0, degree, k])
        table[1, degree - 1, k] = BINOMIALS[degree - 1, k] * table[0, degree - 1, k]


@njit(cache=True, error_model="numpy")
def _sign_changes(coefficients: np.ndarray) -> int:
    """The sign changes along ``coefficients``, or 2 when one is zero (the caller's general case)."""
    changes = 0
    for k in range(len(coefficients)):
        if coefficients[k] == 0.0:
            return 2
        if k > 0 and (coefficients[k] > 0.0) != (coefficients[k - 1] > 0.0):
            changes += 1
    return changes


@njit(cache=True, error_model="numpy")
def bernstein_roots(coefficients: np.ndarray, low: float, high: float, table: np.ndarray, roots: np.ndarray,
                    counts: np.ndarray) -> int:  # fmt: skip
    """The real roots in ``[low, high]`` (near ``[0, 1]``) of ``sum_k coefficients[k] B_k^n(x)``
    (``coefficients (n + 1,)``, ``n >= 1``), sorted, into ``roots[n, :count]``; the count.

    Scratch: ``table (2, n + 1, n + 1)`` (row ``m``: the Bernstein coefficients of the ``(n -
    m)``-th derivative, then the same times ``C(m, k)``),
    ``roots (n + 1, n + 1)`` (row ``m``: the roots of row ``m`` of the table), ``counts (n + 1,)``."""
    n = len(coefficients) - 1
    for k in range(n + 1):
        table[0, n, k] = coefficients[k]
        table[1, n, k] = BINOMIALS[n, k] * coefficients[k]
    _derivative_row(table, n)
    # Descartes' rule for the Bernstein form: the roots in [0, 1] are as many as the sign changes of
    # the coefficients, or fewer by an even number; none or one is the common case, and needs no
    # derivatives of higher order
    changes = _sign_changes(coefficients)
    if changes <= 1:
        # and no sign change between an end and the interval's bound beyond it
        fa, fb = bernstein_value(coefficients, n, low), bernstein_value(coefficients, n, high)
        if fa * coefficients[0] > 0.0 and fb * coefficients[n] > 0.0:
            counts[n] = changes
            if changes == 1:
                roots[n, 0] = _bracketed_root(table, n, low, high, fa, fb)
            return changes
    for m in range(n - 1, 0, -1):
        _derivative_row(table, m)
    counts[0] = 0  # a constant: no roots (or all roots, which no caller can use)
    for m in range(1, n + 1):
        count = 0
        a = low
        fa = bernstein_value(table[0, m], m, a)
        # the pieces between the derivative's roots, on each of which row m is monotone
        for k in range(counts[m - 1] + 1):
            b = roots[m - 1, k] if k < counts[m - 1] else high
            fb = bernstein_value(table[0, m], m, b)
            if fa == 0.0:
                if count == 0 or roots[m, count - 1] != a:
                    roots[m, count] = a
                    count += 1
            elif fa * fb < 0.0:
                roots[m, count] = _bracketed_root(table, m, a, b, fa, fb)
                count += 1
            a, fa = b, fb
        if fa == 0.0 and (count == 0 or roots[m, count - 1] != a):
            roots[m, count] = a
            count += 1
        counts[m] = count
    return counts[n]

"""The compiled Bernstein root finder against polynomials built from their roots."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import comb

from bhem_hpc.compiled.bernstein_roots import bernstein_roots, bernstein_value


def _bernstein_coefficients(roots: np.ndarray, scale: float) -> np.ndarray:
    """Bernstein coefficients ``(n + 1,)`` on [0, 1] of ``scale prod (x - roots)``, by interpolation."""
    n = len(roots)
    x = (np.arange(n + 1) + 0.5) / (n + 1)
    basis = comb(n, np.arange(n + 1)) * x[:, None] ** np.arange(n + 1) * (1 - x[:, None]) ** (n - np.arange(n + 1))
    return np.linalg.solve(basis, scale * np.prod(x[:, None] - roots[None, :], axis=1))


def _roots(coefficients: np.ndarray, low: float = 0.0, high: float = 1.0) -> np.ndarray:
    n = len(coefficients) - 1
    table, roots, counts = np.empty((2, n + 1, n + 1)), np.empty((n + 1, n + 1)), np.empty(n + 1, dtype=np.int64)
    return roots[n, : bernstein_roots(coefficients, low, high, table, roots, counts)].copy()


@pytest.mark.parametrize("degree", range(1, 9))
def test_roots_of_seeded_random_polynomials_are_found_to_round_off(rng, degree):
    for _ in range(200):
        expected = np.sort(rng.uniform(-0.5, 1.5, degree))
        if degree > 1 and np.diff(expected).min() < 1e-3:  # clustered roots are ill-conditioned: not this test
            continue
        coefficients = _bernstein_coefficients(expected, rng.choice([-1.0, 1.0]) * 10.0 ** rng.uniform(-6, 6))
        inside = expected[(expected >= 0.0) & (expected <= 1.0)]
        found = _roots(coefficients)
        assert len(found) == len(inside), (expected, found)
        np.testing.assert_allclose(found, inside, atol=1e-9)
        np.testing.assert_array_equal(found, np.sort(found))


def test_a_double_root_at_an_extremum_is_found_once_and_roots_just_beyond_the_ends_within_the_slack():
    """A root 1e-11 beyond an end is a seam's crossing that rounding put on the neighbour's side:
    within a slack it must be found although the coefficients change sign only once."""
    found = _roots(np.array([0.09, -0.21, 0.49]))  # (x - 0.3)^2 in Bernstein form: 0.09, 0.09 - 0.3, 0.49
    np.testing.assert_allclose(found, [0.3], atol=1e-7)
    beyond = _bernstein_coefficients(np.array([-1e-11, 0.5, 1.0 + 1e-11]), 1.0)
    np.testing.assert_allclose(_roots(beyond, -1e-9, 1.0 + 1e-9), [-1e-11, 0.5, 1.0 + 1e-11], atol=1e-13)
    assert len(_roots(beyond)) == 1


def test_bernstein_value_is_the_sum_of_the_basis(rng):
    for degree in range(1, 12):
        coefficients, x = rng.standard_normal(degree + 1), rng.uniform(-0.1, 1.1)
        k = np.arange(degree + 1)
        basis = comb(degree, k) * x**k * (1 - x) ** (degree - k)
        assert bernstein_value(coefficients, degree, x) == pytest.approx(basis @ coefficients, rel=1e-12, abs=1e-12)

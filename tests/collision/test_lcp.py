"""The contact impulses' complementarity problem: block pivoting, the active-set fallback, and the
conditions every solution meets (seeded problems shaped like contact rows on shell patches)."""

from __future__ import annotations

import numpy as np
import pytest

from bhem_hpc.collision.lcp import block_pivoting, lawson_hanson, solve_lcp

pytestmark = pytest.mark.rank_free  # no communicator: the same computation on every rank


def contact_like(seed: int, rows: int, dofs: int) -> tuple[np.ndarray, np.ndarray]:
    """A dual matrix ``G G^T + eps I`` of ``rows`` rows on ``dofs`` DOFs (more rows than DOFs: nearly
    dependent rows, as sixteen samples on a patch) and bounds of both signs."""
    rng = np.random.default_rng(seed)
    rows_matrix = rng.standard_normal((rows, dofs)) * (rng.random((rows, dofs)) < 0.2)
    matrix = rows_matrix @ rows_matrix.T
    matrix += 1e-8 * np.abs(np.diag(matrix)).max() * np.eye(rows)
    return matrix, rng.standard_normal(rows)


def assert_complementary(matrix: np.ndarray, rhs: np.ndarray, impulses: np.ndarray, tolerance: float = 1e-10):
    limit = tolerance * np.abs(rhs).max()
    slack = matrix @ impulses - rhs
    assert impulses.min() >= 0.0
    pushing = impulses > 0
    assert slack[~pushing].min(initial=0.0) >= -limit  # a row that does not push ends above its bound
    # a row pushes only where it ends at its bound (round-off of the dense solve allowed)
    assert np.abs(slack[pushing]).max(initial=0.0) <= 1e-6 * np.abs(rhs).max()


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize(("rows", "dofs"), [(40, 120), (120, 40), (300, 100)])
def test_block_pivoting_and_the_active_set_method_find_the_same_impulses(seed, rows, dofs):
    matrix, rhs = contact_like(seed, rows, dofs)
    impulses, _ = solve_lcp(matrix, rhs)
    assert_complementary(matrix, rhs, impulses)
    reference, _ = lawson_hanson(matrix, rhs, 1e-10 * np.abs(rhs).max())
    assert np.array_equal(impulses > 0, reference > 0)
    # both end with one dense solve on the pushing rows: the same numbers
    assert np.array_equal(impulses, reference)


def test_pivoting_that_does_not_settle_hands_over_to_the_active_set_method():
    matrix, rhs = contact_like(3, 300, 100)
    limit = 1e-10 * np.abs(rhs).max()
    unsettled, iterations = block_pivoting(matrix, rhs, limit, max_iterations=1)
    assert unsettled is None and iterations == 1
    impulses, total = solve_lcp(matrix, rhs, max_pivoting=1)
    reference, active_set = lawson_hanson(matrix, rhs, limit)
    assert np.array_equal(impulses, reference) and total == 1 + active_set
    assert active_set > 10  # one dense solve per pushing row: what pivoting saves


def test_many_pushing_rows_take_a_few_pivoting_steps():
    matrix, rhs = contact_like(5, 300, 100)
    impulses, iterations = solve_lcp(matrix, rhs)
    assert np.count_nonzero(impulses) > 50 and iterations <= 30


def test_no_rows_and_rows_already_met():
    assert solve_lcp(np.zeros((0, 0)), np.zeros(0))[0].shape == (0,)
    impulses, iterations = lawson_hanson(np.zeros((0, 0)), np.zeros(0), 1e-10)  # also on its own
    assert impulses.shape == (0,) and iterations == 0
    matrix, rhs = contact_like(1, 20, 60)
    impulses, iterations = solve_lcp(matrix, -np.abs(rhs))
    assert not impulses.any() and iterations == 1

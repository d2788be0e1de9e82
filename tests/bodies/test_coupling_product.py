"""The coupling product P^T H P from Hessian blocks (numpy and scipy only), against dense algebra on
seeded random prolongations and blocks; its pattern and the pattern test."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse

from bhem_hpc.bodies.coupling_product import CouplingProduct, PatternKeys

pytestmark = pytest.mark.rank_free  # no communicator: the same computation on every rank


def _case(rng, open_blocks: int = 7, closed: int = 12, count: int = 15):
    prolongation = scipy.sparse.random(3 * open_blocks, closed, density=0.2, random_state=rng, format="csr")
    rows, columns = rng.integers(0, open_blocks, count), rng.integers(0, open_blocks, count)
    rows[1], columns[1] = rows[0], columns[0]  # a block given twice is summed
    return prolongation, (rows, columns, rng.standard_normal((count, 3, 3)))


def _dense_hessian(blocks, open_blocks: int) -> np.ndarray:
    hessian = np.zeros((3 * open_blocks, 3 * open_blocks))
    for r, c, value in zip(*blocks, strict=True):
        hessian[3 * r:3 * r + 3, 3 * c:3 * c + 3] += value
    return hessian


@pytest.mark.parametrize("rows", [slice(0, 12), slice(5, 9)], ids=["all rows", "a rank's rows"])
def test_the_product_is_pt_h_p_on_the_ranks_rows(rng, rows):
    prolongation, blocks = _case(rng)
    product = CouplingProduct(prolongation, rows).product(blocks)
    dense = prolongation.toarray()
    expected = (dense.T @ _dense_hessian(blocks, 7) @ dense)[rows]
    assert product.shape == expected.shape
    np.testing.assert_allclose(product.toarray(), expected, atol=1e-12)


def test_the_pattern_holds_every_product_of_its_blocks_and_the_test_tells_entries_outside_it(rng):
    prolongation, blocks = _case(rng, count=3)  # few blocks: a pattern with room outside it
    coupling = CouplingProduct(prolongation, slice(0, 12))
    pattern = coupling.pattern(blocks[0], blocks[1])
    keys = PatternKeys(pattern.indptr, pattern.indices, 12)
    assert keys.holds(coupling.product(blocks))
    subset = tuple(part[:2] for part in blocks)
    assert keys.holds(coupling.product(subset))
    outside = np.ones((12, 12)) - (pattern.toarray() > 0)
    assert outside.any()
    assert not keys.holds(scipy.sparse.csr_matrix(outside))
    assert keys.holds(scipy.sparse.csr_matrix((12, 12)))
    assert not PatternKeys(np.zeros(13, np.int64), np.zeros(0, np.int64), 12).holds(pattern)

"""The coupling Hessian on the stacked closed DOFs, ``P^T H P``, formed from the blocks that the
coupling contributions give at an iterate (numpy and scipy only).

``H`` lives on the stacked open blocks (3 x 3 blocks, global block indices) and ``P``, the bodies'
prolongations side by side, is the same at every iterate. Only the blocks a contribution gives as
nonzero enter ``H``: a barrier's active pairs, an interface's quadrature points. A contribution's
fixed pattern (for a barrier every pair of mesh blocks that share a triangle) is mostly zeros away
from contact; it sizes the stacked Jacobian once (:meth:`CouplingProduct.pattern`) and is not
multiplied again at every Newton iteration.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.sparse

from bhem_hpc.solver.contributions import Contribution, ContributionState, GrowingPattern

#: block rows, block columns ``(k,)`` and values ``(k, 3, 3)``
Blocks = tuple[np.ndarray, np.ndarray, np.ndarray]


def contribution_blocks(contributions: Sequence[Contribution], patterns: Sequence[tuple[np.ndarray, np.ndarray]],
                        state: ContributionState) -> Blocks:  # fmt: skip
    """Collective (every contribution is asked on every rank): this rank's nonzero Hessian blocks of
    ``contributions`` at ``state``, those on their fixed ``patterns`` (block rows and columns) and,
    of a :class:`GrowingPattern`, those beyond it."""
    rows, columns, values = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)], [np.zeros((0, 3, 3))]
    for contribution, (pattern_rows, pattern_columns) in zip(contributions, patterns, strict=True):
        given = contribution.hessian(state)
        if len(pattern_rows):
            given = np.asarray(given, dtype=float).reshape(-1, 3, 3)
            nonzero = np.any(given != 0.0, axis=(1, 2))
            rows.append(np.asarray(pattern_rows, np.int64).reshape(-1)[nonzero])
            columns.append(np.asarray(pattern_columns, np.int64).reshape(-1)[nonzero])
            values.append(given[nonzero])
        if isinstance(contribution, GrowingPattern):
            extra_rows, extra_columns, extra_values = contribution.hessian_beyond_pattern()
            rows.append(np.asarray(extra_rows, np.int64).reshape(-1))
            columns.append(np.asarray(extra_columns, np.int64).reshape(-1))
            values.append(np.asarray(extra_values, dtype=float).reshape(-1, 3, 3))
    return np.concatenate(rows), np.concatenate(columns), np.concatenate(values)


def _block_matrix(blocks: Blocks, open_blocks: int) -> scipy.sparse.csr_matrix:
    """``H`` ``(3 open_blocks, 3 open_blocks)`` of ``blocks`` (blocks given twice are summed)."""
    rows, columns, values = blocks
    component = np.arange(3)
    shape = (len(rows), 3, 3)
    scalar_rows = np.broadcast_to(3 * rows[:, None, None] + component[None, :, None], shape)
    scalar_columns = np.broadcast_to(3 * columns[:, None, None] + component[None, None, :], shape)
    size = 3 * open_blocks
    return scipy.sparse.coo_matrix((values.ravel(), (scalar_rows.ravel(), scalar_columns.ravel())),
                                   shape=(size, size)).tocsr()  # fmt: skip


class CouplingProduct:
    """``P^T H P`` on this rank's rows of the stacked closed DOFs.

    Args:
        prolongation: ``P``, every rank's rows: stacked open DOFs ``3 * block + component`` (rows)
            from stacked closed DOFs (columns), shape ``(3 open blocks, closed DOFs)``.
        rows: this rank's closed DOFs (global indices).
    """

    def __init__(self, prolongation: scipy.sparse.csr_matrix, rows: slice):
        self.prolongation = prolongation.tocsr()
        self._transposed_rows = self.prolongation.T.tocsr()[rows]
        self.rows = rows
        self.open_blocks = prolongation.shape[0] // 3

    def product(self, blocks: Blocks) -> scipy.sparse.csr_matrix:
        """``(P^T H P)`` of every rank's ``blocks`` on this rank's rows, ``(local rows, closed DOFs)``."""
        hessian = _block_matrix(blocks, self.open_blocks)
        return (self._transposed_rows @ hessian @ self.prolongation).tocsr()

    def pattern(self, rows: np.ndarray, columns: np.ndarray) -> scipy.sparse.csr_matrix:
        """The product's pattern (all entries 1) on this rank's rows for every block pair ``(rows,
        columns)`` ``(k,)`` (of every rank): no entry of it cancels."""
        ones = np.ones((len(rows), 3, 3))
        hessian = _block_matrix((np.asarray(rows, np.int64), np.asarray(columns, np.int64), ones), self.open_blocks)
        absolute = abs(self.prolongation)
        product = (abs(self._transposed_rows) @ hessian @ absolute).tocsr()
        product.data[:] = 1.0
        return product


class PatternKeys:
    """The entries a matrix's pattern holds on this rank's rows, as sorted keys ``row * columns + column``
    (rows local), to tell whether another matrix's entries all fall within it.

    Args:
        row_pointer, columns: the pattern in CSR (rows local, columns global).
        num_columns: the matrix's global column count.
    """

    def __init__(self, row_pointer: np.ndarray, columns: np.ndarray, num_columns: int):
        self.num_columns = int(num_columns)
        self.keys = np.sort(self._keys(np.asarray(row_pointer), np.asarray(columns)))

    def _keys(self, row_pointer: np.ndarray, columns: np.ndarray) -> np.ndarray:
        rows = np.repeat(np.arange(len(row_pointer) - 1, dtype=np.int64), np.diff(row_pointer))
        return rows * self.num_columns + columns.astype(np.int64)

    def holds(self, matrix: scipy.sparse.csr_matrix) -> bool:
        """Whether every stored entry of ``matrix`` (local rows) is in the pattern."""
        keys = self._keys(matrix.indptr, matrix.indices)
        if not len(keys):
            return True
        if not len(self.keys):
            return False
        where = np.minimum(np.searchsorted(self.keys, keys), len(self.keys) - 1)
        return bool(np.all(self.keys[where] == keys))

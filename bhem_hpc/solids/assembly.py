"""The SEM stiffness ``K = Pi^T (sum_k v_k G_k^T D_k G_k) Pi`` assembled in coefficient space, by
groups of quadrature points that see the same coefficients (numpy and scipy).

At a quadrature point ``k`` the deformation gradient is ``F[k, c, d] = sum_m G_d[k, m] C[m, c]`` with
the scalar maps ``G_d (Q, n_c)`` of :meth:`~bhem_hpc.solids.shape_matching.ShapeMatching.kinematic_maps`
and the coefficients ``C = Pi q (n_c, 3)``. A point sees only the coefficients of the parts blended
there (and their origins' translations); points that see the same ones (the same parts) form a
group whose rows of ``G_d`` are one dense block, so the stiffness of a group is two BLAS products
of its own size, ``O(points m^2)`` for ``m`` coefficients seen, where a product over the control
points costs ``O(points n_q^2)``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse

#: Up to this many interleaved coefficients the groups' blocks are added into a dense matrix (128 MB
#: at most): many groups that each see most coefficients (a small model blended everywhere) would
#: otherwise give a triplet list far longer than the matrix.
DENSE_LIMIT = 4000


@dataclass(frozen=True)
class PointGroup:
    """Quadrature points ``points (n,)`` that see the coefficients ``columns (m,)``; ``gradients
    (n, 3, m)``: ``G_d[points][:, columns]`` with ``d`` the middle index."""

    points: np.ndarray
    columns: np.ndarray
    gradients: np.ndarray


#: The cost model by which groups are merged (:func:`_merged`), measured on a 2-core x86 machine:
#: BLAS multiply-adds per second, seconds per block entry added into the stiffness (memory bound)
#: and per group. It only shapes the grouping; the stiffness is the same to round-off.
FLOP_RATE, ENTRY_SECONDS, GROUP_SECONDS = 14e9, 2e-9, 3e-5


def _group_seconds(points: int, columns: int) -> float:
    """Modelled seconds of one group's block: its two products and its addition into the stiffness."""
    pairs = len(UPPER_PAIRS)
    return 3 * pairs * points * columns**2 / FLOP_RATE + pairs * columns**2 * ENTRY_SECONDS + GROUP_SECONDS


def _merged(members: list[tuple[np.ndarray, np.ndarray]], count: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Groups ``(columns, points)`` merged greedily, the widest first, into the group whose modelled
    cost (:func:`_group_seconds`) grows least by taking them, where that is less than their own
    (a point's gradients are zero in the columns it does not see): a rocket's 101 groups, most seeing
    nearly all of its 236 coefficients, became 8 and its stiffness took 0.056 s against 0.136."""
    merged: list[tuple[np.ndarray, list[np.ndarray], int]] = []  # (column mask, points, point count)
    for columns, points in sorted(members, key=lambda member: -len(member[0])):
        mask = np.zeros(count, dtype=bool)
        mask[columns] = True
        best, target = _group_seconds(len(points), len(columns)), None
        for index, (seen, _, size) in enumerate(merged):
            growth = _group_seconds(size + len(points), int(np.count_nonzero(seen | mask)))
            growth -= _group_seconds(size, int(np.count_nonzero(seen)))
            if growth < best:
                best, target = growth, index
        if target is None:
            merged.append((mask, [points], len(points)))
        else:
            seen, together, size = merged[target]
            merged[target] = (seen | mask, [*together, points], size + len(points))
    return [(np.flatnonzero(seen), np.concatenate(together)) for seen, together, _ in merged]


def point_groups(gradients: Sequence[scipy.sparse.spmatrix]) -> list[PointGroup]:
    """The groups of the scalar maps ``G_0, G_1, G_2 (Q, n_c)``: points with the same columns,
    merged where one product over more columns costs less than two (:func:`_merged`)."""
    maps = [scipy.sparse.csr_matrix(g) for g in gradients]
    pattern = (abs(maps[0]) + abs(maps[1]) + abs(maps[2])).tocsr()
    pattern.sort_indices()
    members: dict[bytes, list[int]] = {}
    for k in range(pattern.shape[0]):
        members.setdefault(pattern.indices[pattern.indptr[k] : pattern.indptr[k + 1]].tobytes(), []).append(k)
    distinct = [(np.frombuffer(key, dtype=pattern.indices.dtype).astype(np.int64), np.asarray(points, dtype=np.int64))
                for key, points in members.items()]  # fmt: skip
    groups = []
    for columns, points in _merged(distinct, pattern.shape[1]):
        dense = np.stack([m[points][:, columns].toarray() for m in maps], axis=1)
        groups.append(PointGroup(points, columns, dense))
    return groups


def fits_dense(size: int) -> bool:
    """Whether a stiffness of ``size`` rows is assembled as a dense matrix (:data:`DENSE_LIMIT`)."""
    return size <= DENSE_LIMIT


def coefficient_pattern(groups: Sequence[PointGroup], count: int) -> np.ndarray:
    """``(count, count)`` booleans: the coefficient pairs some group's block reaches (each pair's
    three by three components alike; dense coefficients only)."""
    pattern = np.zeros((count, count), dtype=bool)
    for group in groups:
        pattern[np.ix_(group.columns, group.columns)] = True
    return pattern


#: The component pairs ``(c, c')`` with ``c <= c'``: the stiffness is symmetric, so its blocks of
#: ``c > c'`` are the transposes of these and are not computed.
UPPER_PAIRS = np.array([(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)])


def _add_by_runs(dense: np.ndarray, block: np.ndarray, columns: np.ndarray) -> None:
    """``dense[:, columns, columns] += block`` (``(6, n, n)`` and ``(6, m, m)``, the index pairs
    as ``np.ix_`` makes them) by slices over the runs of consecutive ``columns`` (a part's
    coefficients are consecutive), into the component-major array, so that no block is transposed
    to the interleaved order: a rocket's stiffness (86 blocks of about 500 x 500, element-wise
    scatter into the interleaved matrix) took 0.24 s, this way 0.17 s."""
    breaks = np.flatnonzero(np.diff(columns) != 1) + 1
    starts, stops = np.r_[0, breaks], np.r_[breaks, len(columns)]
    for a0, a1 in zip(starts, stops, strict=True):
        rows = slice(int(columns[a0]), int(columns[a1 - 1]) + 1)
        for b0, b1 in zip(starts, stops, strict=True):
            dense[:, rows, int(columns[b0]) : int(columns[b1 - 1]) + 1] += block[:, a0:a1, b0:b1]


def _component_blocks(upper: np.ndarray) -> np.ndarray:
    """``(3, 3, m, m)`` ``[c, c', m, m']`` from the ``(6, m, m)`` blocks of :data:`UPPER_PAIRS`."""
    full = np.empty((3, 3, *upper.shape[1:]))
    for (c, d), block in zip(UPPER_PAIRS, upper, strict=True):
        full[c, d] = block
        full[d, c] = block.T
    return full


def coefficient_stiffness(groups: Sequence[PointGroup], weighted: np.ndarray, count: int,
                          pairs: bool = False) -> scipy.sparse.csr_matrix | np.ndarray:  # fmt: skip
    """``sum_k G_k^T W_k G_k`` on the interleaved coefficients (row ``3 m + c``), ``(3 count, 3 count)``:
    a dense array where :func:`fits_dense`, else a sparse matrix.

    Args:
        groups: from :func:`point_groups`.
        weighted: ``(Q, 9, 9)`` quadrature weight times the tangent ``d^2 psi / dF[c, d] dF[c', d']``
            at row ``3 c + d``, column ``3 c' + d'``.
        count: the number of coefficients ``n_c``.
        pairs: the dense blocks ``(6, count, count)`` of the component pairs :data:`UPPER_PAIRS`
            instead (``[pair, m, m']``; the others are their transposes), for a caller that has
            decided on dense assembly.
    """
    size = 3 * count
    # dense: [(c, c') of UPPER_PAIRS, m, m'], interleaved at the end
    dense = np.zeros((len(UPPER_PAIRS), count, count)) if pairs or fits_dense(size) else None
    rows, columns, values = [], [], []
    first_component, second_component = UPPER_PAIRS.T
    for group in groups:
        n, m = len(group.points), len(group.columns)
        # W[k, c, d, c', d'] at the pairs c <= c' -> (k, (pair, d'), d) times G[k, d, m]: A[k, pair, d', m]
        tangent = weighted[group.points].reshape(n, 3, 3, 3, 3)[:, first_component, :, second_component, :]
        tangent = tangent.transpose(1, 0, 3, 2).reshape(n, 3 * len(UPPER_PAIRS), 3)  # [pair, k, d, d'] first
        first = np.matmul(tangent, group.gradients)  # (n, 18, m): [k, (pair, d'), m]
        # sum over k and d': ((k, d'), (pair, m)) against G[(k, d'), m']
        left = first.reshape(n, len(UPPER_PAIRS), 3, m).transpose(0, 2, 1, 3).reshape(3 * n, -1)
        block = (left.T @ group.gradients.reshape(3 * n, m)).reshape(len(UPPER_PAIRS), m, m)  # [pair, m, m']
        if dense is not None:
            _add_by_runs(dense, block, group.columns)
            continue
        block = _component_blocks(block).transpose(2, 0, 3, 1).reshape(3 * m, 3 * m)  # [(m, c), (m', c')]
        index = (3 * group.columns[:, None] + np.arange(3)[None, :]).reshape(-1)
        rows.append(np.repeat(index, 3 * m))
        columns.append(np.tile(index, 3 * m))
        values.append(block.reshape(-1))
    if pairs:
        return dense
    if dense is not None:
        return np.ascontiguousarray(_component_blocks(dense).transpose(2, 0, 3, 1)).reshape(size, size)
    stiffness = scipy.sparse.coo_matrix(
        (np.concatenate(values), (np.concatenate(rows), np.concatenate(columns))), shape=(size, size)
    )
    return stiffness.tocsr()


#: A weighted Gram matrix ``A^T W A`` (:func:`weighted_gram`) is a BLAS product over the columns
#: ``A`` uses where at least this fraction of that block holds nonzeros (the castle's error energy:
#: each part's misfit reaches every control point; scipy's sparse product took 14 s there) and
#: those columns :func:`fits_dense`.
GRAM_DENSE_FILL = 0.2


def weighted_gram(matrix: scipy.sparse.spmatrix, weights: np.ndarray) -> scipy.sparse.csr_matrix:
    """``matrix^T diag(weights) matrix`` for ``matrix (S, n)`` and ``weights (S,)``: ``(n, n)``,
    exact zeros left out (as scipy's sparse product leaves them)."""
    matrix = scipy.sparse.csr_matrix(matrix)
    columns = np.unique(matrix.indices)
    size = len(columns)
    if not size or not fits_dense(size) or matrix.nnz < GRAM_DENSE_FILL * matrix.shape[0] * size:
        return (matrix.T @ scipy.sparse.diags(weights) @ matrix).tocsr()
    block = matrix[:, columns].toarray()
    return _scattered(block.T @ (np.asarray(weights)[:, None] * block), columns, matrix.shape[1])


def congruence(projection: scipy.sparse.spmatrix, inner: scipy.sparse.spmatrix) -> scipy.sparse.csr_matrix:
    """``projection^T inner projection`` for ``projection (m, n)`` and ``inner (m, m)``: ``(n, n)``,
    a BLAS product where the columns it reaches :func:`fits_dense` (a kinematic map's mass or
    stiffness on the coefficients carried to the control points)."""
    projection = scipy.sparse.csr_matrix(projection)
    columns = np.unique(projection.indices)
    if not fits_dense(len(columns)):
        return (projection.T @ inner @ projection).tocsr()
    block = projection[:, columns].toarray()
    return _scattered(block.T @ (inner @ block), columns, projection.shape[1])


def _scattered(block: np.ndarray, columns: np.ndarray, size: int) -> scipy.sparse.csr_matrix:
    """The ``(size, size)`` sparse matrix with ``block (m, m)`` at rows and columns ``columns (m,)``
    (sorted), its exact zeros left out."""
    rows, cols = np.nonzero(block)
    return scipy.sparse.csr_matrix((block[rows, cols], (columns[rows], columns[cols])), shape=(size, size))

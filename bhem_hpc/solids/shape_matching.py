"""Shape matching (SEM paper §5-§6, eq. 7) and the blended kinematic map, numpy and scipy only.

Every part ``i`` has a deformation origin ``Xbar_j`` (``j = origin[i]``, shared by several parts)
and a polynomial deformation ``x(X) = sum_a p_a(X - Xbar_j) C_i[a] + t_j`` of the monomials
``p`` of degree 1 (``X Y Z``) or 2 (adding ``XY XZ YZ XX YY ZZ``), ``C_i[a]`` a row of 3. The
coefficients are one array ``(n_c, 3)``: each part's ``k`` rows in part order, then one
translation row per origin. They are a linear map of the stacked control points ``q (n_q, 3)``:
``C = Pi @ q`` with the sparse scalar projection ``Pi (n_c, n_q)`` (it acts on each coordinate
alike). The translation ``t_j`` is the constant of the polynomial fitted over the samples of the
origin's parts; each part's rows are the least-squares fit of what is left on its own samples,
all orders at once, completed from its neighbours where its samples cannot see a term (see
:func:`shape_matching`), so that every polynomial motion of the degree is reproduced exactly.

The blended map at volume points ``X (Q, 3)`` with blending weights ``W (Q, parts)`` is
``x(X) = Phi(X) @ C`` and its deformation gradient ``F[:, :, d] = G_d(X) @ C`` (weights held
constant near each point, as the paper does, §7.3).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse

from bhem_hpc.geometry.surface import SurfaceError
from bhem_hpc.solids.sampling import PartSamples, column_offsets, stacked_basis

#: Monomials per degree: degree 1 -> 3, degree 2 -> 9.
TERMS = {1: 3, 2: 9}
#: Relative singular-value cutoff of the per-part least-squares fits (a planar part cannot fix
#: the coefficients of monomials that vanish on it: they take the minimum-norm value 0).
FIT_RCOND = 1e-10
#: Up to this many entries (32 MB) the projection's rows are dense arrays over all control points:
#: a model of tens of parts then takes one array operation per fit where per-part blocks took one
#: per part reached (a rocket of 25 parts: 637 blocks, 13 ms for the projection against 5).
DENSE_PROJECTION_ENTRIES = 4_000_000


def monomials(offset: np.ndarray, degree: int) -> np.ndarray:
    """``(Q, k)`` monomials of ``offset (Q, 3)``: ``Y0 Y1 Y2`` then ``Y0Y1 Y0Y2 Y1Y2 Y0^2 Y1^2 Y2^2``."""
    y0, y1, y2 = offset[:, 0], offset[:, 1], offset[:, 2]
    columns = [y0, y1, y2]
    if degree == 2:
        columns += [y0 * y1, y0 * y2, y1 * y2, y0**2, y1**2, y2**2]
    return np.stack(columns, axis=1)


def monomial_gradients(offset: np.ndarray, degree: int) -> np.ndarray:
    """``(Q, k, 3)``: ``d p_a / d X_d`` at ``offset (Q, 3)``."""
    count = len(offset)
    out = np.zeros((count, TERMS[degree], 3))
    out[:, 0, 0] = out[:, 1, 1] = out[:, 2, 2] = 1.0
    if degree == 2:
        y0, y1, y2 = offset[:, 0], offset[:, 1], offset[:, 2]
        out[:, 3, 0], out[:, 3, 1] = y1, y0
        out[:, 4, 0], out[:, 4, 2] = y2, y0
        out[:, 5, 1], out[:, 5, 2] = y2, y1
        out[:, 6, 0], out[:, 7, 1], out[:, 8, 2] = 2 * y0, 2 * y1, 2 * y2
    return out


@dataclass(frozen=True)
class ShapeMatching:
    """The projection and what the kinematic map needs of it.

    Attributes:
        projection: ``Pi (n_c, n_q)`` sparse.
        degree: 1 or 2.
        origin_of_part: ``(parts,)`` origin index of each part.
        origins: ``(origins, 3)`` reference positions ``Xbar``.
        part_rows: ``(parts,)`` first coefficient row of each part (``TERMS[degree]`` rows each);
            origin ``j``'s translation is row ``parts * k + j``.
    """

    projection: scipy.sparse.csr_matrix
    degree: int
    origin_of_part: np.ndarray
    origins: np.ndarray
    part_rows: np.ndarray

    @property
    def terms(self) -> int:
        return TERMS[self.degree]

    @property
    def coefficient_count(self) -> int:
        return self.projection.shape[0]

    def translation_row(self, origin: int) -> int:
        return len(self.part_rows) * self.terms + origin

    def kinematic_maps(
        self, points: np.ndarray, weights: scipy.sparse.spmatrix, weight_gradients: np.ndarray | None = None
    ):
        """``Phi (Q, n_c)`` and ``G (3, Q, n_c)`` at reference ``points (Q, 3)`` with blending
        ``weights (Q, parts)`` (sparse; rows sum to 1): ``x = Phi @ C``, ``F[:, :, d] = G[d] @ C``.

        With ``weight_gradients (Q, parts, 3)`` (zero wherever the weight is), ``F`` keeps the
        second term of eq. (15), ``sum_i grad w_i P_i C_i``, which the paper drops; without it parts
        may turn rigidly against each other at no strain (a blend of rotations is a rotation).
        """
        weights = scipy.sparse.coo_matrix(weights)
        point, part, w = weights.row, weights.col, weights.data
        offset = points[point] - self.origins[self.origin_of_part[part]]
        k = self.terms
        columns = self.part_rows[part][:, None] + np.arange(k)[None, :]
        shape = (len(points), self.coefficient_count)
        rows = np.repeat(point, k)
        basis = monomials(offset, self.degree)
        values = (w[:, None] * basis).ravel()
        translation = self.translation_row(0) + self.origin_of_part[part]
        all_rows, all_columns = np.r_[rows, point], np.r_[columns.ravel(), translation]
        phi = scipy.sparse.csr_matrix((np.r_[values, w], (all_rows, all_columns)), shape=shape)
        gradients = w[:, None, None] * monomial_gradients(offset, self.degree)
        grad = []
        for d in range(3):
            entries = np.r_[gradients[:, :, d].ravel(), np.zeros(len(point))]
            if weight_gradients is not None:
                slope = weight_gradients[point, part, d]
                entries = entries + np.r_[(slope[:, None] * basis).ravel(), slope]
            grad.append(scipy.sparse.csr_matrix((entries, (all_rows, all_columns)), shape=shape))
        return phi, grad


def shifts(deltas: np.ndarray, degree: int) -> np.ndarray:
    """``T (n, 1 + k, 1 + k)`` with ``Q(Y + deltas[i]) = T[i] @ Q(Y)`` for ``Q(Y) = (1, monomials(Y))``
    and ``deltas (n, 3)``: the monomials about one centre as a linear map of those about another."""
    size = 1 + TERMS[degree]
    shift = np.zeros((len(deltas), size, size))
    shift[:, np.arange(size), np.arange(size)] = 1.0
    shift[:, 1:4, 0] = deltas
    if degree == 2:
        for row, (i, j) in zip((4, 5, 6), ((0, 1), (0, 2), (1, 2)), strict=True):
            shift[:, row, 0] = deltas[:, i] * deltas[:, j]
            shift[:, row, 1 + i], shift[:, row, 1 + j] = deltas[:, j], deltas[:, i]
        for i in range(3):
            shift[:, 7 + i, 0], shift[:, 7 + i, 1 + i] = deltas[:, i] ** 2, 2.0 * deltas[:, i]
    return shift


def _pseudo_inverses(normals: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """The minimum-norm inverses ``(n, k, k)`` of weighted least-squares fits' normal matrices
    ``(n, k, k)`` and, per fit, the orthonormal coefficient directions ``(k, r)`` its samples
    cannot determine (eigenvalues below :data:`FIT_RCOND` of the largest)."""
    values, vectors = np.linalg.eigh(normals)
    seen = values > FIT_RCOND * np.maximum(values.max(axis=1, keepdims=True), 1e-300)
    scale = np.where(seen, 1.0 / np.where(seen, values, 1.0), 0.0)
    inverses = (vectors * scale[:, None, :]) @ vectors.transpose(0, 2, 1)
    return inverses, [v[:, ~s] for v, s in zip(vectors, seen, strict=True)]


class _PartRows:
    """Rows over the stacked control points, kept as one dense block per part whose control points
    they reach: ``blocks[g]`` is ``(rows, n_g)`` over part ``g``'s control points (a fit on a few
    parts' samples reaches only those parts' columns and their origin's translation's)."""

    def __init__(self, blocks: dict[int, np.ndarray]):
        self.blocks = blocks

    def left(self, matrix: np.ndarray) -> _PartRows:
        """``matrix @ self``."""
        return _PartRows({g: matrix @ block for g, block in self.blocks.items()})

    def fitted(self, inverse: np.ndarray) -> _PartRows:
        """``inverse (k, k) @ self[1:]``: a fit of the monomials from moments whose first row is the constant's."""
        return _PartRows({g: inverse @ block[1:] for g, block in self.blocks.items()})

    def minus_outer(self, column: np.ndarray, row: _PartRows) -> _PartRows:
        """``self - column (k,) ⊗ row`` (``row`` a single row)."""
        blocks = dict(self.blocks)
        for g, block in row.blocks.items():
            blocks[g] = blocks.get(g, 0.0) - column[:, None] * block
        return _PartRows(blocks)

    def plus(self, matrix: np.ndarray, other: _PartRows) -> _PartRows:
        """``self + matrix @ other``."""
        blocks = dict(self.blocks)
        for g, block in other.blocks.items():
            blocks[g] = blocks.get(g, 0.0) + matrix @ block
        return _PartRows(blocks)

    def triplets(self, first_row: int, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rows, columns and values of the entries, the rows numbered from ``first_row``."""
        rows, columns, values = [], [], []
        for g, block in self.blocks.items():
            r, c = np.nonzero(block)
            rows.append(first_row + r)
            columns.append(offsets[g] + c)
            values.append(block[r, c])
        return np.concatenate(rows), np.concatenate(columns), np.concatenate(values)


class _DenseRows:
    """Rows ``(k, n_q)`` over all the stacked control points, for models whose projection is small
    (:data:`DENSE_PROJECTION_ENTRIES`): one array operation where :class:`_PartRows` takes one per
    part it reaches (a rocket's 25 parts: 637 blocks)."""

    def __init__(self, rows: np.ndarray):
        self.rows = rows

    def left(self, matrix: np.ndarray) -> _DenseRows:
        return _DenseRows(matrix @ self.rows)

    def fitted(self, inverse: np.ndarray) -> _DenseRows:
        return _DenseRows(inverse @ self.rows[1:])

    def minus_outer(self, column: np.ndarray, row: _DenseRows) -> _DenseRows:
        return _DenseRows(self.rows - column[:, None] * row.rows)

    def plus(self, matrix: np.ndarray, other: _DenseRows) -> _DenseRows:
        return _DenseRows(self.rows + matrix @ other.rows)


class _Moments:
    """The weighted moments of each part's samples about its own centre ``centres (parts, 3)`` (the
    samples' weighted centroid): with ``Q = (1, monomials)`` of degree ``degree`` at the samples,
    ``normals[g] = Q^T S Q`` ``(1 + k, 1 + k)`` and ``Q^T S J`` ``(1 + k, n_g)`` over the part's
    control points. A fit about any origin over any group of parts is a sum of these moved by
    :func:`shifts`, so no fit goes back to the samples. The rows are dense over all control points
    (``dense``) for a projection of at most :data:`DENSE_PROJECTION_ENTRIES` entries, where each
    part's ``Q^T S J`` is kept as ``(1 + k, n_q)``; else per part. :meth:`place` sets the origins
    ``(origins, 3)`` the fits are made about."""

    def __init__(self, samples: Sequence[PartSamples], degree: int, coefficient_count: int):
        self.degree, self.coefficient_count = degree, coefficient_count
        self.offsets = column_offsets(samples)
        self.dense = coefficient_count * int(self.offsets[-1]) <= DENSE_PROJECTION_ENTRIES
        counts = np.array([len(s.weights) for s in samples])
        starts, part = np.r_[0, np.cumsum(counts)[:-1]], np.repeat(np.arange(len(samples)), counts)
        weights = np.concatenate([s.weights for s in samples])
        points = np.concatenate([s.points for s in samples])
        self.sums = np.add.reduceat(weights, starts)
        self.centres = np.add.reduceat(weights[:, None] * points, starts) / self.sums[:, None]
        basis = np.hstack([np.ones((len(points), 1)), monomials(points - self.centres[part], degree)])  # (s, 1 + k)
        weighted = weights[:, None] * basis
        self.normals = np.add.reduceat(weighted[:, :, None] * basis[:, None, :], starts)
        # each part's Q^T S J over its own control points (the other parts' columns are zero): one
        # product with the block-diagonal J of all parts, each control point's row from its own part
        self.stacked = np.ascontiguousarray((stacked_basis(samples).T @ weighted).T)  # (1 + k, n_q)
        self.projected = [self.stacked[:, a:b] for a, b in zip(self.offsets[:-1], self.offsets[1:], strict=True)]
        self.part_of_column = np.repeat(np.arange(len(samples)), np.diff(self.offsets))

    def place(self, origins: np.ndarray) -> None:
        """Each part's shift to each origin and its normal matrix moved there, ``(origins, parts, 1 + k, 1 + k)``."""
        moved = shifts((self.centres[None, :, :] - origins[:, None, :]).reshape(-1, 3), self.degree)
        self.moved = moved.reshape(len(origins), len(self.centres), *moved.shape[1:])
        self.moved_normals = self.moved @ self.normals[None] @ self.moved.transpose(0, 1, 3, 2)

    def about(self, group: Sequence[int], origin: int) -> tuple[np.ndarray, _PartRows | _DenseRows]:
        """``Q^T S Q`` ``(1 + k, 1 + k)`` and the rows ``Q^T S J`` ``(1 + k, n_q)`` of the samples of
        the parts ``group``, ``Q`` the monomials about origin number ``origin``."""
        group = np.asarray(group)
        moved, normal = self.moved[origin, group], self.moved_normals[origin, group].sum(axis=0)
        if self.dense:  # T_g (Q^T S J)_g column by column: each control point's own part's moved moments
            in_group = np.zeros(len(self.centres), dtype=bool)
            in_group[group] = True
            columns = np.flatnonzero(in_group[self.part_of_column])
            rows = np.zeros(self.stacked.shape)
            moved_of_column = self.moved[origin, self.part_of_column[columns]]  # (c, 1 + k, 1 + k)
            rows[:, columns] = np.matmul(moved_of_column, self.stacked.T[columns, :, None])[..., 0].T
            return normal, _DenseRows(rows)
        return normal, _PartRows({int(g): t @ self.projected[g] for g, t in zip(group, moved, strict=True)})


def _group_fit(moments: _Moments, group, origin, translation,
               solved: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[_PartRows | _DenseRows, np.ndarray]:
    """The least-squares rows ``(k, n_q)`` of the monomials about ``origin`` on the samples of the
    parts ``group``, fitted to ``J q - t`` (``translation``: the row of ``t``), and the coefficient
    directions ``(k, r)`` those samples cannot determine (they get 0); ``solved``: the normal
    matrix's inverse and those directions where :func:`_pseudo_inverses` made them for many fits."""
    normal, rows = moments.about(group, origin)
    if solved is None:
        (inverse,), (unseen,) = _pseudo_inverses(normal[None, 1:, 1:])
    else:
        inverse, unseen = solved
    # the fit (P^T S P)^+ P^T S applied to J and to the ones (the translation's column)
    return rows.fitted(inverse).minus_outer(inverse @ normal[1:, 0], translation), unseen


def _translations(moments: _Moments, origin_of_part: np.ndarray) -> list[_PartRows | _DenseRows]:
    """The row of each origin's translation: the constant of the polynomial fitted with it over its
    parts' samples, so that every polynomial motion of the parts' degree is reproduced exactly;
    where those samples cannot separate the constant from the other terms (a sphere's
    ``X^2 + Y^2 + Z^2``), the weighted centroid of the samples (the paper's)."""
    members = [np.flatnonzero(origin_of_part == j) for j in range(int(origin_of_part.max()) + 1)]
    normals = np.stack([moments.moved_normals[j, group].sum(axis=0) for j, group in enumerate(members)])
    inverses, unseens = _pseudo_inverses(normals)
    fits = zip(members, normals, inverses, unseens, strict=True)
    return [_translation_row(moments.about(group, j)[1], normal, inverse, unseen)
            for j, (group, normal, inverse, unseen) in enumerate(fits)]  # fmt: skip


def _translation_row(rows, normal, inverse, unseen) -> _PartRows | _DenseRows:
    """:func:`_translations`' row of one origin from its fit's moments, inverse and unseen directions."""
    if unseen.shape[1] and np.abs(unseen[0]).max() > 1e-8:
        return rows.left(np.eye(1, len(normal)) / normal[0, 0])
    return rows.left(inverse[:1])


def shape_matching(
    samples: Sequence[PartSamples],
    degree: int,
    origin_of_part: np.ndarray | None = None,
    names: Sequence[str] | None = None,
    neighbours: Sequence[np.ndarray] | None = None,
) -> ShapeMatching:
    """The projection ``Pi`` of parts with their boundary samples (eq. 7, fitted jointly).

    Each origin's translation is the constant of the polynomial fitted over its parts' samples; each
    part's coefficients (linear and quadratic together) are the least-squares fit of what is left on
    its own samples. Coefficients that a part's samples cannot determine (a planar part sees no
    variation along its normal: ``Z``, ``XZ``, ``YZ``, ``ZZ`` of a part in ``Z = 0``) come from the fit
    over the samples of the parts blended with it (all parts where those cannot determine them
    either). So every polynomial motion of the degree is reproduced exactly by every part, which the
    paper's hierarchical fit (lower orders first, each order on the part alone) does not do for
    planar parts: their quadratic terms along the normal vanish, and a bent beam locks in shear.

    Args:
        samples: per part, its samples over its own control points; the stacked control points
            take the parts in order.
        degree: 1 (linear) or 2 (quadratic) shape matching.
        origin_of_part: ``(parts,)`` origin indices ``0 .. origins - 1`` (default: one origin).
        names: the parts' names in errors.
        neighbours: per part, the parts blended with it somewhere (nonzero weights at one point).
    """
    if degree not in TERMS:
        raise SurfaceError(f"shape-matching degree must be 1 or 2, got {degree!r}")
    count = len(samples)
    names = list(names or [f"part {i}" for i in range(count)])
    origin_of_part = np.zeros(count, dtype=int) if origin_of_part is None else np.asarray(origin_of_part, dtype=int)
    origins_count = int(origin_of_part.max()) + 1
    terms = TERMS[degree]
    moments = _Moments(samples, degree, count * terms + origins_count)
    origins = np.zeros((origins_count, 3))
    for j in range(origins_count):
        members = np.flatnonzero(origin_of_part == j)
        if not len(members):
            raise SurfaceError(f"deformation origin {j} has no part")
        sums = moments.sums[members]
        origins[j] = sums @ moments.centres[members] / sums.sum()
    moments.place(origins)
    translation = _translations(moments, origin_of_part)
    every_part = np.arange(count)
    # each part's own fit, about its origin: all normal matrices inverted at once
    own_normals = moments.moved_normals[origin_of_part, every_part]
    inverses, unseens = _pseudo_inverses(own_normals[:, 1:, 1:])
    own = _own_fits(moments, origin_of_part, own_normals, inverses, translation) if moments.dense else None
    # the completion of a part depends on its group and origin alone: the planar faces of one fin
    # or box share both, and their fit over many parts' samples is made once
    keys: dict[int, _GroupKey] = {}
    for i, s in enumerate(samples):
        if len(s.points) < TERMS[degree]:
            raise SurfaceError(
                f"{names[i]}: {len(s.points)} boundary samples cannot fit the {TERMS[degree]} shape-matching "
                "terms; raise the sampling order"
            )
        if unseens[i].shape[1]:
            group = tuple(sorted({*neighbours[i].tolist(), i})) if neighbours is not None else ()
            keys[i] = (group, int(origin_of_part[i]))
    completions = _completions(moments, set(keys.values()), translation)
    blocks = []
    for i in range(count):
        origin, shift = origin_of_part[i], translation[origin_of_part[i]]
        if own is None:
            rows, unseen = _group_fit(moments, [i], origin, shift, (inverses[i], unseens[i]))
        else:
            rows, unseen = _DenseRows(own[i]), unseens[i]
        if unseen.shape[1]:
            rows = rows.plus(unseen @ unseen.T, completions[keys[i]])
        blocks.append(rows)
    part_rows = np.arange(count) * terms  # each part's first row; the origins' translations follow
    first_rows = [*part_rows, *(count * terms + np.arange(origins_count))]
    projection = _assembled(blocks + translation, first_rows, moments)
    return ShapeMatching(projection, degree, origin_of_part, origins, part_rows)


def _own_fits(moments: _Moments, origin_of_part: np.ndarray, normals: np.ndarray, inverses: np.ndarray,
              translation: Sequence[_DenseRows]) -> np.ndarray:  # fmt: skip
    """:func:`_group_fit` of every part on its own samples at once (dense rows): ``(parts, k, n_q)``."""
    parts = np.arange(len(origin_of_part))
    column = (inverses @ normals[:, 1:, :1])[..., 0]  # the fit applied to the ones: the translation's column
    shifts_row = np.stack([translation[j].rows[0] for j in origin_of_part])
    fits = -column[:, :, None] * shifts_row[:, None, :]  # (parts, k, n_q)
    offsets = moments.offsets
    for i, (moved, projected) in enumerate(zip(moments.moved[origin_of_part, parts], moments.projected, strict=True)):
        own = slice(offsets[i], offsets[i + 1])  # the part's own columns, where its samples' fit reaches
        fits[i, :, own] = inverses[i] @ (moved @ projected)[1:] - column[i][:, None] * shifts_row[i, own]
    return fits


_GroupKey = tuple[tuple[int, ...], int]  # the parts of a fit and its origin


def _completions(moments: _Moments, keys: set[_GroupKey],
                 translation: Sequence[_PartRows | _DenseRows]) -> dict[_GroupKey, _PartRows | _DenseRows]:  # fmt: skip
    """Per ``(group, origin)``: :func:`_group_fit` over the parts ``group`` where their samples
    determine every term, else over all parts' (an empty group: all parts'); the groups' normal
    matrices inverted at once."""
    keys = sorted(keys)
    fits = {}
    grouped = [(group, origin) for group, origin in keys if group]
    if grouped:
        normals = np.stack([moments.moved_normals[origin, list(group)].sum(axis=0) for group, origin in grouped])
        inverses, unseens = _pseudo_inverses(normals[:, 1:, 1:])
        for (group, origin), inverse, unseen in zip(grouped, inverses, unseens, strict=True):
            if not unseen.shape[1]:
                solved = (inverse, unseen)
                fits[group, origin] = _group_fit(moments, list(group), origin, translation[origin], solved)[0]
    every_part = np.arange(len(moments.centres))
    over_all: dict[int, _PartRows | _DenseRows] = {}  # per origin: the fit over all parts' samples
    for group, origin in keys:
        if (group, origin) not in fits:
            if origin not in over_all:
                fit, unseen = _group_fit(moments, every_part, origin, translation[origin])
                if unseen.shape[1]:
                    raise SurfaceError("the parts' samples lie on one quadric or plane: they bound no volume")
                over_all[origin] = fit
            fits[group, origin] = over_all[origin]
    return fits


def _assembled(row_groups: Sequence[_PartRows | _DenseRows], first_rows: Sequence[int],
               layout: _Moments) -> scipy.sparse.csr_matrix:  # fmt: skip
    """The projection from its consecutive row groups, each starting at its ``first_rows``."""
    if layout.dense:  # CSR straight from the nonzeros (scipy's conversion of a dense array goes through COO)
        dense = np.vstack([rows.rows for rows in row_groups])
        nonzero = dense != 0.0  # boolean masks select in row order, faster than np.nonzero's index pairs
        columns = np.broadcast_to(np.arange(dense.shape[1]), dense.shape)[nonzero]
        indptr = np.r_[0, np.cumsum(nonzero.sum(axis=1))]
        return scipy.sparse.csr_matrix((dense[nonzero], columns, indptr), shape=dense.shape)
    entries = [rows.triplets(first, layout.offsets) for rows, first in zip(row_groups, first_rows, strict=True)]
    rows, columns, values = (np.concatenate(e) for e in zip(*entries, strict=True))
    return scipy.sparse.csr_matrix((values, (rows, columns)), shape=(layout.coefficient_count, int(layout.offsets[-1])))

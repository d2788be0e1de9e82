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
from bhem_hpc.solids.sampling import PartSamples

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


def _fit(basis: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The weighted least-squares fit ``(P^T S P)^+ P^T S`` ``(k, s)`` on ``basis (s, k)`` (minimum
    norm along the directions the samples cannot determine) and those orthonormal coefficient
    directions ``(k, r)`` (eigenvalues of ``P^T S P`` below :data:`FIT_RCOND` of the largest)."""
    values, vectors = np.linalg.eigh(basis.T @ (weights[:, None] * basis))
    seen = values > FIT_RCOND * max(values.max(), 1e-300)
    inverse = (vectors[:, seen] / values[seen]) @ vectors[:, seen].T
    return inverse @ (basis.T * weights), vectors[:, ~seen]


class _PartRows:
    """Rows over the stacked control points, kept as one dense block per part whose control points
    they reach: ``blocks[g]`` is ``(rows, n_g)`` over part ``g``'s control points (a fit on a few
    parts' samples reaches only those parts' columns and their origin's translation's)."""

    def __init__(self, blocks: dict[int, np.ndarray]):
        self.blocks = blocks

    @staticmethod
    def fitted(fit: np.ndarray, group: Sequence[int], bases: Sequence[np.ndarray]) -> _PartRows:
        """``fit (k, s) @ J`` with ``J`` the rows of the samples of the parts ``group`` stacked in order
        (``bases[g] (s_g, n_g)`` over part ``g``'s control points)."""
        blocks, start = {}, 0
        for g in group:
            stop = start + len(bases[g])
            blocks[g] = fit[:, start:stop] @ bases[g]
            start = stop
        return _PartRows(blocks)

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

    def minus_outer(self, column: np.ndarray, row: _DenseRows) -> _DenseRows:
        return _DenseRows(self.rows - column[:, None] * row.rows)

    def plus(self, matrix: np.ndarray, other: _DenseRows) -> _DenseRows:
        return _DenseRows(self.rows + matrix @ other.rows)


class _Layout:
    """The parts' sample bases over their own control points, where each part's control points
    start in the stacked ones (``offsets (parts + 1,)``), and the kind of rows the fits give: dense
    for a projection up to :data:`DENSE_PROJECTION_ENTRIES` entries, the bases then stacked into one
    block-diagonal array ``(samples, n_q)`` whose rows ``sample_offsets`` are each part's."""

    def __init__(self, samples: Sequence[PartSamples], coefficient_count: int):
        self.coefficient_count = coefficient_count
        self.offsets = np.r_[0, np.cumsum([s.basis.shape[1] for s in samples])]
        self.sample_offsets = np.r_[0, np.cumsum([s.basis.shape[0] for s in samples])]
        self.dense = coefficient_count * int(self.offsets[-1]) <= DENSE_PROJECTION_ENTRIES
        if self.dense:
            self.stacked = np.zeros((int(self.sample_offsets[-1]), int(self.offsets[-1])))
            for g, s in enumerate(samples):
                rows, columns = self.sample_offsets[g : g + 2], self.offsets[g : g + 2]
                self.stacked[rows[0] : rows[1], columns[0] : columns[1]] = s.basis.toarray()
        else:
            self.bases = [s.basis.toarray() for s in samples]  # (s_g, n_g)

    def fitted(self, fit: np.ndarray, group: Sequence[int]) -> _PartRows | _DenseRows:
        """``fit (k, s) @ J`` with ``J`` the rows of the samples of the parts ``group`` stacked in order."""
        if not self.dense:
            return _PartRows.fitted(fit, group, self.bases)
        if len(group) == 1:
            return _DenseRows(fit @ self.stacked[self.sample_offsets[group[0]] : self.sample_offsets[group[0] + 1]])
        rows = np.concatenate([np.arange(self.sample_offsets[g], self.sample_offsets[g + 1]) for g in group])
        return _DenseRows(fit @ self.stacked[rows])


def _stacked_samples(samples: Sequence[PartSamples], group: Sequence[int], origin: np.ndarray):
    """The samples of the parts ``group``: offsets from ``origin`` ``(s, 3)`` and weights ``(s,)``."""
    points = np.concatenate([samples[g].points for g in group]) - origin
    return points, np.concatenate([samples[g].weights for g in group])


def _group_fit(samples, layout: _Layout, group, origin, translation,
               degree) -> tuple[_PartRows | _DenseRows, np.ndarray]:  # fmt: skip
    """The least-squares rows ``(k, n_q)`` of the monomials about ``origin`` on the samples of the
    parts ``group``, fitted to ``J q - t`` (``translation``: the row of ``t``), and the coefficient
    directions ``(k, r)`` those samples cannot determine (they get 0)."""
    points, weights = _stacked_samples(samples, group, origin)
    fit, unseen = _fit(monomials(points, degree), weights)
    return layout.fitted(fit, group).minus_outer(fit.sum(axis=1), translation), unseen


def _translation(samples, layout: _Layout, members, origin, degree) -> _PartRows | _DenseRows:
    """The row of an origin's translation: the constant of the polynomial fitted with it over its
    parts' samples, so that every polynomial motion of the parts' degree is reproduced exactly;
    where those samples cannot separate the constant from the other terms (a sphere's
    ``X^2 + Y^2 + Z^2``), the weighted centroid of the samples (the paper's)."""
    points, weights = _stacked_samples(samples, members, origin)
    fit, unseen = _fit(np.hstack([np.ones((len(points), 1)), monomials(points, degree)]), weights)
    if unseen.shape[1] and np.abs(unseen[0]).max() > 1e-8:
        return layout.fitted((weights / weights.sum())[None, :], members)
    return layout.fitted(fit[:1], members)


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
    layout = _Layout(samples, count * terms + origins_count)
    origins = np.zeros((origins_count, 3))
    translation = []
    for j in range(origins_count):
        members = np.flatnonzero(origin_of_part == j)
        if not len(members):
            raise SurfaceError(f"deformation origin {j} has no part")
        sigma = sum(samples[i].weights.sum() for i in members)
        origins[j] = sum(samples[i].weights @ samples[i].points for i in members) / sigma
        translation.append(_translation(samples, layout, members, origins[j], degree))
    every_part = np.arange(count)
    blocks = []
    # the completion of a part depends on its group and origin alone: the planar faces of one fin
    # or box share both, and their fit over many parts' samples is made once
    completions: dict[tuple[tuple[int, ...], int], _PartRows | _DenseRows] = {}
    for i, s in enumerate(samples):
        if len(s.points) < TERMS[degree]:
            raise SurfaceError(
                f"{names[i]}: {len(s.points)} boundary samples cannot fit the {TERMS[degree]} shape-matching "
                "terms; raise the sampling order"
            )
        origin, shift = origins[origin_of_part[i]], translation[origin_of_part[i]]
        rows, unseen = _group_fit(samples, layout, [i], origin, shift, degree)
        if unseen.shape[1]:
            groups = [np.union1d(neighbours[i], [i])] if neighbours is not None else []
            key = (tuple(int(g) for g in groups[0]) if groups else (), int(origin_of_part[i]))
            if key not in completions:
                completions[key] = _completion(samples, layout, [*groups, every_part], origin, shift, degree)
            rows = rows.plus(unseen @ unseen.T, completions[key])
        blocks.append(rows)
    part_rows = np.arange(count) * terms  # each part's first row; the origins' translations follow
    first_rows = [*part_rows, *(count * terms + np.arange(origins_count))]
    projection = _assembled(blocks + translation, first_rows, layout)
    return ShapeMatching(projection, degree, origin_of_part, origins, part_rows)


def _completion(samples, layout: _Layout, groups, origin, translation, degree) -> _PartRows | _DenseRows:
    """The fit over the first of ``groups`` whose samples determine every term (:func:`_group_fit`)."""
    for group in groups:
        completion, still_unseen = _group_fit(samples, layout, group, origin, translation, degree)
        if not still_unseen.shape[1]:
            return completion
    raise SurfaceError("the parts' samples lie on one quadric or plane: they bound no volume")


def _assembled(row_groups: Sequence[_PartRows | _DenseRows], first_rows: Sequence[int],
               layout: _Layout) -> scipy.sparse.csr_matrix:  # fmt: skip
    """The projection from its consecutive row groups, each starting at its ``first_rows``."""
    if layout.dense:
        return scipy.sparse.csr_matrix(np.vstack([rows.rows for rows in row_groups]))
    entries = [rows.triplets(first, layout.offsets) for rows, first in zip(row_groups, first_rows, strict=True)]
    rows, columns, values = (np.concatenate(e) for e in zip(*entries, strict=True))
    return scipy.sparse.csr_matrix((values, (rows, columns)), shape=(layout.coefficient_count, int(layout.offsets[-1])))

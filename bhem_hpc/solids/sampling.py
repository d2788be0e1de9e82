"""Boundary samples of NURBS parts (SEM paper §5), numpy only.

Every nonempty knot span pair of a part carries a tensor Gauss-Lobatto rule of ``order`` points
per direction (the paper's choice: the order of the NURBS, degree + 1, and at least 3: see
:func:`sample_part`), with weights in the parameter measure ``du dv`` of eq. (4). A sample ``s``
has a row ``J[s]`` of the rational basis: its reference point is ``X[s] = J[s] q0`` and its
deformed point ``J[s] q``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import scipy.sparse

from bhem_hpc.geometry.bspline import bernstein
from bhem_hpc.geometry.nurbs import KnotDirection, NurbsSurface


@lru_cache(maxsize=16)
def gauss_lobatto(count: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Lobatto points and weights ``(count,)`` on ``[0, 1]`` (``count >= 2``: both ends included;
    read-only arrays, computed once per count)."""
    if count < 2:
        raise ValueError(f"a Gauss-Lobatto rule needs at least 2 points, got {count}")
    n = count - 1
    # interior points: roots of P'_n; weights 2 / (n (n + 1) P_n(x)^2) on [-1, 1]
    legendre = np.polynomial.legendre.Legendre.basis(n)
    interior = np.sort(np.real(legendre.deriv().roots())) if n > 1 else np.zeros(0)
    x = np.concatenate([[-1.0], interior, [1.0]])
    w = 2.0 / (n * (n + 1) * legendre(x) ** 2)
    points, weights = 0.5 * (x + 1.0), 0.5 * w
    points.flags.writeable = weights.flags.writeable = False
    return points, weights


@dataclass(frozen=True)
class PartSamples:
    """Samples of one part: ``basis`` the sparse ``(s, n * m)`` rational basis ``J`` over the part's
    flattened control points, ``weights (s,)`` the diagonal of ``S``, ``points (s, 3)`` the
    reference points ``J q0``."""

    basis: scipy.sparse.csr_matrix
    weights: np.ndarray
    points: np.ndarray


@lru_cache(maxsize=64)
def _lobatto_bernstein(order: int, degree: int) -> np.ndarray:
    """The Bernstein polynomials of ``degree`` at the ``order`` Gauss-Lobatto nodes, ``(order, degree + 1)``
    (read-only, computed once per pair: every part of a model shares them)."""
    values = bernstein(gauss_lobatto(order)[0], degree)
    values.flags.writeable = False
    return values


def _span_bases(direction: KnotDirection, order: int) -> tuple[np.ndarray, np.ndarray]:
    """The first control index ``(S,)`` of each nonempty span of ``direction`` and its ``p + 1``
    basis functions at the ``order`` Gauss-Lobatto nodes of every span, ``(S, order, p + 1)`` (the
    spans' Bezier extraction applied to the Bernstein polynomials at the nodes)."""
    bernstein_at_nodes = _lobatto_bernstein(order, direction.degree)
    return direction.spans - direction.degree, np.einsum("sab,nb->sna", direction.extraction, bernstein_at_nodes)


def sample_part(part: NurbsSurface, order: int | None = None) -> PartSamples:
    """Gauss-Lobatto samples of ``order`` points per span and direction (default: the NURBS order,
    degree + 1, of the higher direction, and at least 3, so that a bilinear face has the 9 samples
    a quadratic fit needs); points on shared span edges appear once per span, as a
    composite Lobatto rule's do before its weights are summed (harmless for a least-squares fit).
    Samples are ordered ``[span_u, span_v, node_u, node_v]``."""
    order = order or max(max(part.degrees) + 1, 3)
    node_weights = gauss_lobatto(order)[1]
    (first_u, basis_u), (first_v, basis_v) = _span_bases(part.u, order), _span_bases(part.v, order)
    rows = first_u[:, None] + np.arange(part.u.degree + 1)  # (S_u, p + 1)
    cols = first_v[:, None] + np.arange(part.v.degree + 1)  # (S_v, q + 1)
    local_weights = part.weights[rows[:, None, :, None], cols[None, :, None, :]]  # (S_u, S_v, p + 1, q + 1)
    # rational basis [span_u, span_v, node_u, node_v, i, j], normalized over (i, j)
    weighted = np.einsum("aip,bjq,abpq->abijpq", basis_u, basis_v, local_weights)
    values = weighted / weighted.sum(axis=(4, 5), keepdims=True)
    index = rows[:, None, None, None, :, None] * part.control.shape[1] + cols[None, :, None, None, None, :]
    count, per_row = values[..., 0, 0].size, values.shape[4] * values.shape[5]
    indices = np.broadcast_to(index, values.shape).reshape(count, per_row)
    csr = (values.reshape(count, per_row).ravel(), indices.ravel(), np.arange(count + 1) * per_row)
    basis = scipy.sparse.csr_matrix(csr, shape=(count, part.control[..., 0].size))
    widths_u, widths_v = np.diff(part.u.knots)[part.u.spans], np.diff(part.v.knots)[part.v.spans]
    weights = np.einsum("a,i,b,j->abij", widths_u, node_weights, widths_v, node_weights).ravel()
    return PartSamples(basis, weights, basis @ part.control.reshape(-1, 3))


def sample_parts(parts: Sequence[NurbsSurface], order: int | None = None) -> list[PartSamples]:
    """:func:`sample_part` of each part; parts of the same degrees, knots and weights (a box's faces,
    a model's repeated pieces) share one basis and sample weights, computed once (the basis does
    not depend on the control points)."""
    shared: dict[tuple, PartSamples] = {}
    samples = []
    for part in parts:
        key = (part.degrees, part.u.knots.tobytes(), part.v.knots.tobytes(), part.weights.tobytes())
        if key not in shared:
            shared[key] = sample_part(part, order)
        basis, weights = shared[key].basis, shared[key].weights
        samples.append(PartSamples(basis, weights, basis @ part.control.reshape(-1, 3)))
    return samples


def column_offsets(samples: Sequence[PartSamples]) -> np.ndarray:
    """``(parts + 1,)``: where each part's control points start among all parts' stacked in order,
    then their count."""
    return np.r_[0, np.cumsum([s.basis.shape[1] for s in samples])]


def stacked_bases(samples: Sequence[PartSamples]) -> list[scipy.sparse.csr_matrix]:
    """Each part's ``J`` over the control points of all parts stacked in order: ``(s_i, n_q)``
    (its columns moved by where the part's control points start: scipy's ``hstack`` with empty
    blocks, or its ``block_diag``, goes through COO matrices, 1.4 ms for a rocket's 25 parts)."""
    offsets = column_offsets(samples)
    return [scipy.sparse.csr_matrix((s.basis.data, s.basis.indices + offset, s.basis.indptr),
                                    shape=(s.basis.shape[0], int(offsets[-1])))
            for s, offset in zip(samples, offsets[:-1], strict=True)]  # fmt: skip


def stacked_basis(samples: Sequence[PartSamples]) -> scipy.sparse.csr_matrix:
    """All parts' samples over all their control points, ``(sum s_i, n_q)``: the rows of
    :func:`stacked_bases` one under the other (block diagonal), assembled from the parts' CSR
    arrays (a matrix per part first costs scipy's checks 25 times for a rocket)."""
    bases = [s.basis for s in samples]
    columns = column_offsets(samples)
    nonzeros = np.r_[0, np.cumsum([b.nnz for b in bases])]
    indptr = np.concatenate([*(b.indptr[:-1] + start for b, start in zip(bases, nonzeros[:-1], strict=True)),
                             nonzeros[-1:]])  # fmt: skip
    indices = np.concatenate([b.indices + first for b, first in zip(bases, columns[:-1], strict=True)])
    data = np.concatenate([b.data for b in bases])
    return scipy.sparse.csr_matrix((data, indices, indptr), shape=(sum(b.shape[0] for b in bases), int(columns[-1])))

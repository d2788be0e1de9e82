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

import numpy as np
import scipy.sparse

from bhem_hpc.geometry.nurbs import NurbsSurface


def gauss_lobatto(count: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Lobatto points and weights ``(count,)`` on ``[0, 1]`` (``count >= 2``: both ends included)."""
    if count < 2:
        raise ValueError(f"a Gauss-Lobatto rule needs at least 2 points, got {count}")
    n = count - 1
    # interior points: roots of P'_n; weights 2 / (n (n + 1) P_n(x)^2) on [-1, 1]
    legendre = np.polynomial.legendre.Legendre.basis(n)
    interior = np.sort(np.real(legendre.deriv().roots())) if n > 1 else np.zeros(0)
    x = np.concatenate([[-1.0], interior, [1.0]])
    w = 2.0 / (n * (n + 1) * legendre(x) ** 2)
    return 0.5 * (x + 1.0), 0.5 * w


@dataclass(frozen=True)
class PartSamples:
    """Samples of one part: ``basis`` the sparse ``(s, n * m)`` rational basis ``J`` over the part's
    flattened control points, ``weights (s,)`` the diagonal of ``S``, ``points (s, 3)`` the
    reference points ``J q0``."""

    basis: scipy.sparse.csr_matrix
    weights: np.ndarray
    points: np.ndarray


def sample_part(part: NurbsSurface, order: int | None = None) -> PartSamples:
    """Gauss-Lobatto samples of ``order`` points per span and direction (default: the NURBS order,
    degree + 1, of the higher direction, and at least 3, so that a bilinear face has the 9 samples
    a quadratic fit needs); points on shared span edges appear once per span, as a
    composite Lobatto rule's do before its weights are summed (harmless for a least-squares fit)."""
    order = order or max(max(part.degrees) + 1, 3)
    nodes, node_weights = gauss_lobatto(order)
    u, v, w = [], [], []
    for ku in part.u.spans:
        a, b = part.u.knots[ku], part.u.knots[ku + 1]
        for kv in part.v.spans:
            c, d = part.v.knots[kv], part.v.knots[kv + 1]
            uu, vv = np.meshgrid(a + nodes * (b - a), c + nodes * (d - c), indexing="ij")
            u.append(uu.ravel())
            v.append(vv.ravel())
            w.append(np.outer(node_weights * (b - a), node_weights * (d - c)).ravel())
    u, v, w = np.concatenate(u), np.concatenate(v), np.concatenate(w)
    index, values = part.basis_matrix(u, v)
    rows = np.repeat(np.arange(len(u)), index.shape[1])
    basis = scipy.sparse.csr_matrix((values.ravel(), (rows, index.ravel())), shape=(len(u), part.control[..., 0].size))
    return PartSamples(basis, w, basis @ part.control.reshape(-1, 3))


def sample_parts(parts: Sequence[NurbsSurface], order: int | None = None) -> list[PartSamples]:
    return [sample_part(part, order) for part in parts]


def stacked_bases(samples: Sequence[PartSamples]) -> list[scipy.sparse.csr_matrix]:
    """Each part's ``J`` over the control points of all parts stacked in order: ``(s_i, n_q)``."""
    offsets = np.r_[0, np.cumsum([s.basis.shape[1] for s in samples])]
    total = int(offsets[-1])
    return [
        scipy.sparse.hstack(
            [scipy.sparse.csr_matrix((s.basis.shape[0], int(offsets[i]))), s.basis,
             scipy.sparse.csr_matrix((s.basis.shape[0], total - int(offsets[i + 1])))]
        ).tocsr()
        for i, s in enumerate(samples)
    ]  # fmt: skip

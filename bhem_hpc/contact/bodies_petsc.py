"""The contact projection of several bodies: rows that span bodies, each body's metric factored apart.

The bodies' metric is block diagonal, ``W = diag(W_b)``, so the dual system of rows ``G`` is the
sum of each body's part: ``G W^-1 G^T = sum_b G_b W_b^-1 G_b^T`` with ``G_b`` the rows' columns on
body ``b``. Each body's :class:`~bhem_hpc.contact.petsc.ContactProjector` caches its part of the
rows and their ``W_b^-1 G_b^T`` as it does alone; this projector sums the parts, solves the dual
system and hands each body its share of the correction ``W_b^-1 G_b^T lambda``. An impulse between
two bodies acts on both with opposite signs (the row holds ``a - b``), so it conserves their total
linear momentum.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from petsc4py import PETSc

from bhem_hpc.contact.petsc import ContactProjector, dual_residual, dual_solve, dual_solve_pushing


class StackedProjector:
    """Least-squares projection onto contact rows of several bodies' stacked entries.

    The interface of :class:`~bhem_hpc.contact.petsc.ContactProjector` (the contact handler uses
    either): rows name stacked entries (every body's flat entries, body after body).

    Args:
        projectors: each body's projector (None: a body no row touches).
        entry_offsets: where each body's entries start in the stacked entries, ``(bodies + 1,)``.
        regularization: ``eps`` relative to ``max diag(G^T G) / max diag(W)`` over all bodies.
    """

    def __init__(self, projectors: Sequence[ContactProjector | None], entry_offsets: np.ndarray,
                 regularization: float = 1e-8):  # fmt: skip
        self.projectors = tuple(projectors)
        self.entry_offsets = np.asarray(entry_offsets)
        self.regularization = regularization
        self.projections = 0
        # set_rows: (index (r, K), coefficients (r, K, 3), [(body, rows of the body, their cached ids)])
        self._selected: tuple[np.ndarray, np.ndarray, list[tuple[int, np.ndarray, np.ndarray]]] | None = None

    @property
    def factorizations(self) -> int:
        return sum(p.factorizations for p in self.projectors if p is not None)

    def set_metric(self, jacobians: Sequence[PETSc.Mat | None] | None = None, time_step: float = 1.0) -> None:
        """Collective: every body's metric (:meth:`ContactProjector.set_metric`); ``jacobians``: each
        body's Jacobian for the ``"jacobian"`` metric (None: ``M + S`` for all)."""
        for b, projector in enumerate(self.projectors):
            if projector is not None:
                projector.set_metric(None if jacobians is None else jacobians[b], time_step)

    def set_rows(self, index: np.ndarray, weights: np.ndarray, directions: np.ndarray) -> None:
        """Collective: select the rows of the following solves; row ``r`` is ``directions[r] . sum_k
        weights[r, k] x[index[r, k]]`` of stacked entries ``x`` (``index``, ``weights`` ``(r, K)``,
        ``directions`` ``(r, 3)``, identical on every rank). Each body gets the rows that touch it."""
        index, weights, directions = np.asarray(index), np.asarray(weights, float), np.asarray(directions, float)
        parts = []
        for b, projector in enumerate(self.projectors):
            low, high = self.entry_offsets[b], self.entry_offsets[b + 1]
            on = (index >= low) & (index < high) & (weights != 0.0)
            rows = np.flatnonzero(on.any(axis=1))
            if projector is None:
                if len(rows):
                    raise ValueError(f"contact rows touch body {b}, which has no contact projector")
                continue
            if not len(rows):
                continue
            projector.set_rows(np.where(on, index - low, 0)[rows], np.where(on, weights, 0.0)[rows], directions[rows])
            parts.append((b, rows, projector.selected_ids()))
        self._selected = (index, weights[:, :, None] * directions[:, None, :], parts)

    def _dual(self, current: np.ndarray | None, targets: np.ndarray, combine
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
        """The selected rows' dual system over distinct rows (a row is another's duplicate when every
        body caches them as one): ``(signature of each distinct row (u, parts), each selected row's
        position among them, G W^-1 G^T + eps I, the residual targets - G current combined by
        combine, G W^-1 G^T)``."""
        if self._selected is None:
            raise RuntimeError("StackedProjector.solve called before set_rows")
        index, coefficients, parts = self._selected
        signature = np.full((len(index), len(parts)), -1, dtype=np.int64)
        for k, (_, rows, ids) in enumerate(parts):
            signature[rows, k] = ids
        distinct, position = np.unique(signature, axis=0, return_inverse=True)
        position = position.reshape(-1)
        schur = np.zeros((len(distinct), len(distinct)))
        gtg_max, weighted_max = 0.0, 0.0
        for k, (b, _, _) in enumerate(parts):
            on = np.flatnonzero(distinct[:, k] >= 0)
            projector = self.projectors[b]
            schur[np.ix_(on, on)] += projector.schur_block(distinct[on, k])
            gtg_max = max(gtg_max, projector.largest_gtg(np.unique(distinct[on, k])))
            weighted_max = max(weighted_max, projector.weighted_max)
        eps = self.regularization * gtg_max / weighted_max if gtg_max > 0 else 1.0
        reduced = dual_residual(targets, current, (index, coefficients), position, len(distinct), combine)
        return distinct, position, schur + eps * np.eye(len(distinct)), reduced, schur

    def _correction(self, distinct: np.ndarray, multipliers: np.ndarray) -> np.ndarray:
        """Collective: ``W^-1 G^T lambda`` as stacked entries ``(N, 3)``, every body's share."""
        self.projections += 1
        index, _, parts = self._selected
        correction = np.zeros((int(self.entry_offsets[-1]), 3))
        for k, (b, _, _) in enumerate(parts):
            on = distinct[:, k] >= 0
            share = self.projectors[b].correction_of(distinct[on, k], multipliers[on])
            correction[self.entry_offsets[b] : self.entry_offsets[b + 1]] = share
        return correction

    def solve(self, current: np.ndarray | None, targets: np.ndarray) -> np.ndarray:
        """Collective: the correction (stacked entries ``(N, 3)``, on every rank) that brings the
        selected rows to ``targets`` in the least-squares sense (:meth:`ContactProjector.solve`)."""
        distinct, position, matrix, reduced, schur = self._dual(current, targets, np.add)
        counts = np.bincount(position, minlength=len(distinct))
        matrix = matrix + (counts[:, None] - 1) * schur  # a row selected c times: (c A + eps I)
        return self._correction(distinct, dual_solve(matrix, reduced, "contact projection between bodies"))

    def solve_pushing(self, current: np.ndarray | None, lower: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Collective: the correction with ``rows . (current + d) >= lower`` whose impulses only push
        (:meth:`ContactProjector.solve_pushing`); returns ``(d (N, 3), impulse (r,) of each row)``."""
        distinct, position, matrix, reduced, _ = self._dual(current, lower, np.maximum)
        multipliers = dual_solve_pushing(matrix, reduced, "contact projection between bodies")
        return self._correction(distinct, multipliers), multipliers[position]

    def release(self) -> None:
        """Forget the selected rows (every body's too)."""
        self._selected = None
        for projector in self.projectors:
            if projector is not None:
                projector.release()

    def close(self) -> None:
        """Destroy every body's PETSc objects (idempotent)."""
        self.release()
        for projector in self.projectors:
            if projector is not None:
                projector.close()

"""The impulse response's projection on a solid's control points (numpy + scipy: a solid is small and
every rank holds all of it).

The same least-squares projection as a shell's :class:`~bhem_hpc.contact.petsc.ContactProjector`:
contact rows ``G`` on the control points, the update ``d = W^-1 G^T lambda`` in the metric ``W``,
held DOFs fixed. The metric ``"mass"`` is ``W = M + dt^2 E``: the SEM mass ``M`` sees the control
points only through the shape-matched polynomial deformations (``Pi^T M_x Pi``), so it is singular;
the error energy's Hessian ``E`` (eq. 16) binds the control points to those deformations, as the
smoothing term ``S`` of a shell's ``M + S`` binds its nodal derivatives. ``E`` vanishes on rigid
translations, so ``W t = M t`` and impulses conserve linear momentum. The metric ``"jacobian"`` is
``W = dt^2 J`` with the step's Jacobian ``J = M / dt^2 + K + E``. ``W`` restricted to the free DOFs
is factored by SuperLU once per time step size (``"mass"``) or per step with contact
(``"jacobian"``); ``Z = W^-1 G^T`` of each new row is kept for the step. Every rank computes the
same numbers from the same rows, so nothing is communicated.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.sparse
import scipy.sparse.linalg


class SolidContactProjector:
    """The pieces of the dual system a :class:`~bhem_hpc.contact.bodies_petsc.StackedProjector`
    sums, for one solid.

    Args:
        mass: ``(3 n_q, 3 n_q)`` the consistent mass, interleaved (``3 i + c``).
        error: ``(3 n_q, 3 n_q)`` the error energy's Hessian, interleaved.
        held: the held DOFs (indices into ``3 n_q``): they never move.
        jacobian: gives the step's Jacobian ``(3 n_q, 3 n_q)`` on every rank (collective), for the
            ``"jacobian"`` metric.
        regularization: ``eps`` relative to ``max diag(G^T G) / max diag(W)`` (as a shell's).
    """

    def __init__(self, mass: scipy.sparse.spmatrix, error: scipy.sparse.spmatrix, held: np.ndarray,
                 jacobian: Callable[[], scipy.sparse.spmatrix] | None = None,
                 regularization: float = 1e-8):  # fmt: skip
        self.mass = scipy.sparse.csr_matrix(mass)
        self.error = scipy.sparse.csr_matrix(error)
        self.size = self.mass.shape[0]
        self.free = np.setdiff1d(np.arange(self.size), np.asarray(held, dtype=np.int64))
        self._jacobian = jacobian
        self.regularization = regularization
        self.factorizations = 0
        self.projections = 0
        self._factor = None
        self._factored_mass: float | None = None  # the time step of the factored "mass" metric
        self.weighted_max = 0.0
        self._selected: np.ndarray | None = None
        self._forget_rows()

    def _forget_rows(self) -> None:
        """Empty the step's cache of rows ``G`` (free DOFs) and ``Z = W^-1 G^T``."""
        self._row_ids: dict[bytes, int] = {}
        self._rows = np.zeros((0, len(self.free)))
        self._z = np.zeros((len(self.free), 0))

    def set_metric(self, jacobian: object | None = None, time_step: float = 1.0) -> None:
        """Collective (with the ``"jacobian"`` metric): ``W`` of the step's projections, factored.

        Args:
            jacobian: not None for ``W = dt^2 J`` (the step's Jacobian, fetched through the callable
                given at construction; the argument is the solver's own matrix); None:
                ``W = M + dt^2 E``, factored once per time step size.
            time_step: ``dt`` [s].
        """
        self._forget_rows()
        if jacobian is None and self._factored_mass == time_step:
            return
        if jacobian is not None and self._jacobian is None:
            raise ValueError("the 'jacobian' contact metric needs the solid's Jacobian")
        if jacobian is None:
            metric = self.mass + time_step**2 * self.error
        else:
            metric = time_step**2 * scipy.sparse.csr_matrix(self._jacobian())
        free = metric[self.free][:, self.free].tocsc()
        self.weighted_max = float(np.abs(free.diagonal()).max(initial=0.0))
        self._factor = scipy.sparse.linalg.splu(free)
        self._factored_mass = time_step if jacobian is None else None
        self.factorizations += 1

    def set_rows(self, index: np.ndarray, weights: np.ndarray, directions: np.ndarray) -> None:
        """Select the rows of the following sums: row ``r`` is ``directions[r] . sum_k weights[r, k]
        q[index[r, k]]`` of control points ``q (n_q, 3)``; new rows get their ``Z``."""
        if self._factor is None:
            self.set_metric()
        index, weights, directions = np.asarray(index), np.asarray(weights, float), np.asarray(directions, float)
        ids = np.empty(len(index), dtype=np.int64)
        new = []
        for r in range(len(index)):
            dense = np.zeros(self.size)
            np.add.at(dense, (3 * index[r][:, None] + np.arange(3)).ravel(),
                      (weights[r][:, None] * directions[r]).ravel())  # fmt: skip
            row = dense[self.free]
            key = row.tobytes()
            if key not in self._row_ids:
                self._row_ids[key] = len(self._row_ids)
                new.append(row)
            ids[r] = self._row_ids[key]
        if new:
            rows = np.array(new)
            self._rows = np.vstack([self._rows, rows])
            self._z = np.hstack([self._z, self._factor.solve(np.ascontiguousarray(rows.T))])
        self._selected = ids

    def selected_ids(self) -> np.ndarray:
        """``(r,)`` the cached row of each row selected by :meth:`set_rows`."""
        if self._selected is None:
            raise RuntimeError("SolidContactProjector.selected_ids called before set_rows")
        return self._selected

    def schur_block(self, ids: np.ndarray) -> np.ndarray:
        """``G W^-1 G^T`` between the cached rows ``ids``, ``(len(ids), len(ids))`` (symmetrized)."""
        block = self._rows[ids] @ self._z[:, ids]
        return 0.5 * (block + block.T)

    def largest_gtg(self, ids: np.ndarray) -> float:
        """``max diag(G^T G)`` over the free DOFs of the cached rows ``ids`` (distinct)."""
        return float((self._rows[ids] ** 2).sum(axis=0).max(initial=0.0))

    def correction_of(self, ids: np.ndarray, multipliers: np.ndarray) -> np.ndarray:
        """``sum_r multipliers[r] Z[:, ids[r]]`` as control points ``(n_q, 3)`` (held DOFs 0)."""
        self.projections += 1
        correction = np.zeros(self.size)
        correction[self.free] = self._z[:, ids] @ np.asarray(multipliers, dtype=float)
        return correction.reshape(-1, 3)

    def release(self) -> None:
        """Forget the selected rows (the step's cache stays until the next :meth:`set_metric`)."""
        self._selected = None

    def close(self) -> None:
        """Nothing to destroy (no PETSc objects); for the projector interface."""
        self.release()

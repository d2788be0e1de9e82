"""An SEM solid's problem in PETSc form, for the Newton driver (as
:class:`~bhem_hpc.solver.problem.ShellProblem` is a shell's).

:class:`SolidProblem` owns the residual and the Jacobian of a :class:`~bhem_hpc.solids.model.SolidModel`
on its DOFs (the control points, each rank owning a contiguous range). Each rank adds its share of
the quadrature points and, on rank 0, the terms over all DOFs (:mod:`bhem_hpc.solids.model`); the
gradient is summed over the ranks (an allreduce of ``3 n_q`` values: a solid is small) and the
Hessian's rows are added into one MPI AIJ matrix (PETSc sends the rows another rank owns), its
pattern fixed at the start: every entry the stiffness of all points, the error energy and the mass
can have. Held DOFs are rows and columns of the identity, as a shell's.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import numpy as np
import scipy.sparse
from petsc4py import PETSc

from bhem_hpc.solids.model import SolidModel
from bhem_hpc.solver.contributions import (
    Contribution,
    ContributionState,
    ContributionSteps,
    begin_lagged_step,
)
from bhem_hpc.solver.petsc import PetscOwner
from bhem_hpc.solver.problem import (
    add_contribution_hessians,
    add_diagonal_regularization,
    pattern_arrays,
    stored_entries,
)
from bhem_hpc.solver.report import SolveReport


class SolidProblem(ContributionSteps, PetscOwner):
    """Residual, Jacobian, held rows and potential of a :class:`SolidModel`.

    Args:
        model: the solid.
        report: where assembly times are added up.
        kinds: the Hessian kinds the solve names (a stacked problem's shells' kinds; ``"exact"``
            assembles the exact Hessian, every other kind the projected one).
        contributions: energy contributions on the control points (rows of
            ``ContributionState.positions``: every control point, on every rank; each term added on
            one rank), e.g. IPC's barrier against colliders; their Hessian patterns (global blocks)
            join the Jacobian's.
    """

    matrix_format = "aij"
    prolongation = None

    def __init__(self, model: SolidModel, report: SolveReport, kinds: Sequence[str] = ("projected", "exact"),
                 contributions: Sequence[Contribution] = ()):  # fmt: skip
        self.model, self.report, self.comm = model, report, model.comm
        self._kinds = tuple(kinds)
        self.hessian = self._kinds[0]
        self._closed = False
        self.contributions: list[Contribution] = list(contributions)
        for contribution in self.contributions:
            if not isinstance(contribution, Contribution):
                raise TypeError(f"{contribution!r} is not an energy contribution (bhem_hpc.solver.contributions)")
        self._patterns = [pattern_arrays(*c.hessian_pattern()) for c in self.contributions]
        local, size = model.closed_dofs
        start = 3 * model.owned[0]
        self._rows = slice(start, start + local)
        pattern = (model.hessian_pattern() + self._contribution_pattern(size))[self._rows].tocsr()
        pattern.sort_indices()
        self.jacobian = PETSc.Mat().createAIJ(((local, size), (local, size)), bsize=3, comm=self.comm,
                                              csr=(pattern.indptr.astype(PETSc.IntType),
                                                   pattern.indices.astype(PETSc.IntType)))  # fmt: skip
        self.jacobian.assemble()
        self.jacobian.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
        self.jacobian.setOption(PETSc.Mat.Option.SYMMETRIC, True)
        self.bc_local = model.constrained_local.astype(np.int64)
        self.bc_rows = model.constrained_rows.astype(PETSc.IntType)
        self.bc_values = model.constrained_initial.copy()
        self.regularization = 0.0
        self.on_pattern_growth: Callable[[], None] | None = None

    def _contribution_pattern(self, size: int) -> scipy.sparse.csr_matrix:
        """The contributions' Hessian blocks as scalar entries, gathered on every rank (each rank's
        Jacobian rows are preallocated from the whole pattern)."""
        rows = np.concatenate([np.zeros(0, np.int64), *(r.ravel() for r, _ in self._patterns)])
        cols = np.concatenate([np.zeros(0, np.int64), *(c.ravel() for _, c in self._patterns)])
        rows, cols = (np.concatenate(parts) for parts in zip(*self.comm.allgather((rows, cols)), strict=True))
        component, shape = np.arange(3), (len(rows), 3, 3)
        scalar_rows = np.broadcast_to(3 * rows[:, None, None] + component[None, :, None], shape).ravel()
        scalar_cols = np.broadcast_to(3 * cols[:, None, None] + component[None, None, :], shape).ravel()
        return scipy.sparse.csr_matrix((np.ones(len(scalar_rows)), (scalar_rows, scalar_cols)), shape=(size, size))

    def hessian_kinds(self) -> tuple[str, ...]:
        return self._kinds

    # -- state ----------------------------------------------------------------------------------
    def update_state(self, x: PETSc.Vec) -> None:
        """Collective: every rank's owned DOFs of ``x`` into the whole position on every rank."""
        self.model.position[:] = np.concatenate(self.comm.allgather(x.array_r))

    def state_to_vector(self, x: PETSc.Vec) -> None:
        x.array[:] = self.model.position[self._rows]

    def contribution_state(self) -> ContributionState:
        return ContributionState(self.model.open_positions, float(self.model.load_factor.value), self.point_positions)

    def point_positions(self, bases) -> np.ndarray:
        return np.zeros((len(bases), 3))

    def begin_step(self, time: float, dt: float) -> None:
        """Collective, before a time step from ``time`` of ``dt`` [s]: lagged contributions take the
        start state."""
        begin_lagged_step(self.contributions, self.contribution_state(), time, dt)

    def set_point_targets(self, t: float, ramp: bool = False) -> None:
        """The time (or load factor) ``t`` of the next solve: the solid's time-dependent loads (its
        held control points are DOFs: no point constraint to move)."""
        self.model.set_time(t)

    @property
    def alm_multipliers(self) -> np.ndarray:
        return np.zeros((0, 3))

    def update_multipliers(self) -> bool:
        return True

    # -- assembly -------------------------------------------------------------------------------
    def _summed(self, local: np.ndarray) -> np.ndarray:
        """Collective: the sum over ranks of a whole gradient ``(3 n_q,)``."""
        return self.comm.allreduce(local)

    def assemble_residual(self, x: PETSc.Vec, f: PETSc.Vec,
                          extra_gradient: Callable[[np.ndarray], None] | None = None) -> None:  # fmt: skip
        """``f`` = the gradient of the incremental potential on the owned rows, held rows replaced by
        ``x - x_bc``; ``extra_gradient(gradient)`` adds to this rank's ``(n_q, 3)`` first."""
        t0 = time.perf_counter()
        local = sum(self.model.local_gradients().values())
        local = np.array(local, dtype=float)
        state = self.contribution_state()
        for contribution in self.contributions:  # collective: every rank asks each
            contribution.add_gradient(state, local.reshape(-1, 3))
        if extra_gradient is not None:
            extra_gradient(local.reshape(-1, 3))
        values = f.array
        values[:] = self._summed(local)[self._rows]
        if len(self.bc_local):
            values[self.bc_local] = x.array_r[self.bc_local] - self.bc_values
        self.report.assemble_residual_s += time.perf_counter() - t0

    def assemble_jacobian(self, jac: PETSc.Mat) -> None:
        """This rank's share of the Hessian added into ``jac`` (rows of any rank), held rows and
        columns the identity, then ``J + r |diag J|``."""
        t0 = time.perf_counter()
        hessian = self.model.local_hessian(self.hessian)
        hessian.sort_indices()
        jac.zeroEntries()
        every_row = np.arange(hessian.shape[0], dtype=PETSc.IntType)
        jac.setValuesIJV(hessian.indptr.astype(PETSc.IntType), hessian.indices.astype(PETSc.IntType), hessian.data,
                         addv=PETSc.InsertMode.ADD, rowmap=every_row)  # fmt: skip
        add_contribution_hessians(jac, self.contributions, self._patterns, self.contribution_state())
        jac.assemble()
        jac.zeroRowsColumns(self.bc_rows, diag=1.0)
        add_diagonal_regularization(jac, self.regularization)
        self.report.assemble_jacobian_s += time.perf_counter() - t0

    def potential_energy(self) -> float:
        """Collective: the incremental potential at the current position (with the contributions')."""
        state = self.contribution_state()
        local = sum(self.model.local_terms().values()) + sum(c.energy(state) for c in self.contributions)
        return float(self.comm.allreduce(local))

    def term_residual_norms(self) -> dict[str, float]:
        """Collective: the 2-norm of each term's gradient on the free DOFs."""

        def adder(gradient: np.ndarray) -> Callable[[np.ndarray], None]:
            return lambda local: np.add(local, gradient, out=local)

        gradients = self.model.local_gradients()
        norms = {name: self.open_gradient_norm(adder(gradient)) for name, gradient in gradients.items()}
        state = self.contribution_state()
        for contribution in self.contributions:
            norms[contribution.name] = self.open_gradient_norm(
                lambda local, c=contribution: c.add_gradient(state, local.reshape(-1, 3)))  # fmt: skip
        return norms

    def open_gradient_norm(self, fill: Callable[[np.ndarray], None]) -> float:
        """Collective: the 2-norm on the free DOFs of the gradient ``fill(local)`` adds into zeros
        ``(3 n_q,)`` on each rank (summed over ranks)."""
        local = np.zeros_like(self.model.position)
        fill(local)
        total = self._summed(local)
        total[self.model.constrained] = 0.0
        return float(np.linalg.norm(total))

    def max_step(self, direction: PETSc.Vec) -> float:
        """Collective: the largest fraction of the step every step-bounded contribution admits."""
        return self.max_open_step(self.open_direction_blocks(direction)) if self.has_step_bounds else 1.0

    def step_converged(self, direction: PETSc.Vec) -> bool:
        """Collective: whether the step-testing contributions let the solve end with the step ``direction``."""
        return self.has_step_tests and self.open_step_converged(self.open_direction_blocks(direction))

    def open_direction_blocks(self, direction: PETSc.Vec) -> np.ndarray:
        """Collective: a direction on the owned DOFs as every control point's ``(n_q, 3)``."""
        return np.concatenate(self.comm.allgather(direction.array_r)).reshape(-1, 3)

    def jacobian_csr(self) -> scipy.sparse.csr_matrix:
        """Collective: the last assembled Jacobian ``(3 n_q, 3 n_q)`` on every rank (each rank's owned
        rows gathered; the impulse response's ``"jacobian"`` metric)."""
        indptr, indices, values = self.jacobian.getValuesCSR()
        parts = self.comm.allgather((indptr, indices, values))
        size = self.jacobian.getSize()[1]
        return scipy.sparse.vstack([scipy.sparse.csr_matrix((v, i, p), shape=(len(p) - 1, size))
                                    for p, i, v in parts]).tocsr()  # fmt: skip

    def matrix_nonzeros(self) -> int:
        return stored_entries(self.jacobian)

    def acceleration_residual(self, prefix: str, direct: bool):
        """The :class:`~bhem_hpc.solids.acceleration.SolidAccelerationResidual` of this solid's
        residuals (its lumped mass, on every rank: ``prefix`` and ``direct`` are a shell's
        choices)."""
        from bhem_hpc.solids.acceleration import SolidAccelerationResidual

        return SolidAccelerationResidual(self.model)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self.jacobian.destroy()

"""Shared unknowns of several bodies: the stacked problem reduced to one unknown per group of
closed DOFs that conforming interfaces share (:mod:`.shared_dofs`).

:class:`SharedDofProblem` wraps a :class:`~bhem_hpc.bodies.petsc.StackedProblem`. Its vector holds
the stacked closed DOFs less every shared DOF that is not its group's representative, each rank
the ones it owns in the stacked layout (the representatives keep their owners, so the reduced
layout is the stacked one with rows left out). ``R`` (stacked rows, reduced columns, one entry per
row: 1 for a representative, the member's coefficient for the others) takes the reduced unknowns
to the stacked DOFs: ``x = R x_R``, ``F_R = R^T F``, ``J_R = R^T J R``
(PETSc ``PtAP``), so the shared DOFs move as one and the forces on them add up. A group whose
member is held by a constraint is represented by a held member; its row holds ``x - x_bc``.

Everything that sees positions (contributions, contact, output, step bounds) sees the stacked
problem's open blocks, which ``R`` keeps consistent.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np
from petsc4py import PETSc

from bhem_hpc.bodies.shared_dofs import SharedDofs, shared_groups
from bhem_hpc.solver.acceleration import AccelerationResidual
from bhem_hpc.solver.contributions import Contribution, ContributionState, PointBasis
from bhem_hpc.solver.petsc import PetscOwner
from bhem_hpc.solver.problem import add_diagonal_regularization, stored_entries

if TYPE_CHECKING:  # (the stacked problem's module makes this one's problems)
    from bhem_hpc.bodies.petsc import StackedProblem


class SharedDofProblem(PetscOwner):
    """A stacked problem on the reduced unknowns of its shared DOFs (see the module).

    Args:
        stacked: the bodies' stacked problem (owned and closed by this object).
        shared: the DOFs the bodies share (the same on every rank).

    Raises:
        ValueError: a pair naming a body or a DOF the stacked problem does not have.
    """

    def __init__(self, stacked: StackedProblem, shared: SharedDofs):
        self.stacked, self.comm = stacked, stacked.comm
        self._closed = False
        layout = stacked.closed
        first, second, coefficients = _stacked_pairs(stacked, shared)
        held = np.concatenate(self.comm.allgather(np.asarray(stacked.bc_rows, dtype=np.int64)))
        members, representatives, member_coefficients = shared_groups(first, second, coefficients, held)
        keep = np.ones(layout.size_global, dtype=bool)
        keep[members] = False
        #: each stacked DOF's reduced unknown and coefficient, ``(stacked DOFs,)`` each (every rank)
        reduced_of, coefficient = np.cumsum(keep) - 1, np.ones(layout.size_global)
        reduced_of[members] = reduced_of[representatives]
        coefficient[members] = member_coefficients
        begin, end = int(layout.rank_start[self.comm.rank]), int(layout.rank_start[self.comm.rank + 1])
        self.size_local, self.size_global = int(keep[begin:end].sum()), int(keep.sum())  # the kept rows
        rows = np.arange(end - begin + 1, dtype=PETSc.IntType)
        sizes = ((end - begin, layout.size_global), (self.size_local, self.size_global))
        self.reduction = PETSc.Mat().createAIJ(sizes, csr=(rows, reduced_of[begin:end].astype(PETSc.IntType),
                                                           coefficient[begin:end]), comm=self.comm)  # fmt: skip
        self.reduction.assemble()
        # diag(R^T R): what a group's least-squares value is divided by (state_to_vector)
        squares = PETSc.Mat().createAIJ(sizes, csr=(rows, reduced_of[begin:end].astype(PETSc.IntType),
                                                    coefficient[begin:end] ** 2), comm=self.comm)  # fmt: skip
        squares.assemble()
        self._normal = squares.createVecRight()
        ones = squares.createVecLeft()
        ones.set(1.0)
        squares.multTranspose(ones, self._normal)
        for obj in (squares, ones):
            obj.destroy()
        # the held rows that stay: each held group's representative (its members' rows go)
        kept_held = keep[np.asarray(stacked.bc_rows, dtype=np.int64)]
        self._bc_kept = np.flatnonzero(kept_held)
        self.bc_rows = reduced_of[np.asarray(stacked.bc_rows, dtype=np.int64)[kept_held]].astype(PETSc.IntType)
        reduced_start = int(self.comm.exscan(self.size_local) or 0)
        self.bc_local = (self.bc_rows - reduced_start).astype(np.int64)
        self._x, self._f = self.reduction.createVecLeft(), self.reduction.createVecLeft()
        self._grew = False
        self.on_pattern_growth: Callable[[], None] | None = None
        stacked.on_pattern_growth = self._inner_grew
        self.jacobian = self._create_jacobian()

    def _inner_grew(self) -> None:
        self._grew = True

    def _create_jacobian(self) -> PETSc.Mat:
        """``R^T J R`` of the stacked Jacobian's pattern (its values as they stand)."""
        self._product = self.stacked.jacobian.PtAP(self.reduction)
        jacobian = self._product.duplicate(copy=True)
        jacobian.setOption(PETSc.Mat.Option.SYMMETRIC, all(p.model.symmetric for p in self.stacked.problems))
        return jacobian

    # -- what the stacked problem answers as it is --------------------------------------------------
    @property
    def problems(self) -> list:
        return self.stacked.problems

    @property
    def names(self) -> list[str]:
        return self.stacked.names

    @property
    def contributions(self) -> list[Contribution]:
        return self.stacked.contributions

    @property
    def hessian(self) -> str:
        return self.stacked.hessian

    @hessian.setter
    def hessian(self, kind: str) -> None:
        self.stacked.hessian = kind

    def hessian_kinds(self) -> tuple[str, ...]:
        return self.stacked.hessian_kinds()

    @property
    def regularization(self) -> float:
        return self.stacked.regularization

    @regularization.setter
    def regularization(self, value: float) -> None:
        self.stacked.regularization = value

    @property
    def alm_multipliers(self) -> np.ndarray:
        return self.stacked.alm_multipliers

    def update_multipliers(self) -> bool:
        return self.stacked.update_multipliers()

    def begin_step(self, time: float, dt: float) -> None:
        self.stacked.begin_step(time, dt)

    def adapt_to_iterate(self) -> bool:
        return self.stacked.adapt_to_iterate()

    def adapted_parameters(self) -> dict[str, float]:
        return self.stacked.adapted_parameters()

    def restore_adapted(self, parameters: dict[str, float]) -> None:
        self.stacked.restore_adapted(parameters)

    def set_point_targets(self, t: float, ramp: bool = False) -> None:
        self.stacked.set_point_targets(t, ramp)

    def point_basis(self, body: int, xi1: float, xi2: float) -> PointBasis:
        return self.stacked.point_basis(body, xi1, xi2)

    def point_frame_basis(self, body: int, xi1: float, xi2: float) -> tuple[np.ndarray, np.ndarray]:
        return self.stacked.point_frame_basis(body, xi1, xi2)

    def contribution_state(self) -> ContributionState:
        return self.stacked.contribution_state()

    def point_positions(self, bases: Sequence[PointBasis]) -> np.ndarray:
        return self.stacked.point_positions(bases)

    def potential_energy(self) -> float:
        return self.stacked.potential_energy()

    def term_residual_norms(self) -> dict[str, float]:
        """The stacked problem's (each body's terms on its own DOFs, before the shared ones add up)."""
        return self.stacked.term_residual_norms()

    @property
    def has_step_bounds(self) -> bool:
        return self.stacked.has_step_bounds

    @property
    def has_step_tests(self) -> bool:
        return self.stacked.has_step_tests

    def max_open_step(self, direction: np.ndarray, swept_from: float | None = None) -> float:
        return self.stacked.max_open_step(direction, swept_from)

    @property
    def moves_obstacles(self) -> bool:
        return self.stacked.moves_obstacles

    def place_obstacles_within_step(self, fraction: float) -> None:
        self.stacked.place_obstacles_within_step(fraction)

    def carried_by_obstacles(self, since: float) -> tuple[np.ndarray, np.ndarray]:
        return self.stacked.carried_by_obstacles(since)

    # -- the reduced unknowns ---------------------------------------------------------------------
    def create_vector(self) -> PETSc.Vec:
        """A vector of the reduced unknowns (the caller destroys it)."""
        return self.reduction.createVecRight()

    @property
    def bc_values(self) -> np.ndarray:
        """Values of this rank's held unknowns (the order of :attr:`bc_local`)."""
        return self.stacked.bc_values[self._bc_kept]

    @bc_values.setter
    def bc_values(self, values: np.ndarray) -> None:
        """Set from the values of every held stacked DOF (the stacked problem's order, body after
        body: as :class:`~bhem_hpc.solver.model_group.ModelGroup` gives them)."""
        self.stacked.bc_values = values

    def _expand(self, reduced: PETSc.Vec) -> PETSc.Vec:
        """``R reduced`` in the stacked work vector."""
        self.reduction.mult(reduced, self._x)
        return self._x

    def update_state(self, x: PETSc.Vec) -> None:
        self.stacked.update_state(self._expand(x))

    def state_to_vector(self, x: PETSc.Vec) -> None:
        """The reduced unknowns of the bodies' positions: each group's least-squares value
        ``(R^T R)^-1 R^T x`` over its members (their common value where they agree; the mean of
        what each body holds where a body's state was changed alone, as an impulse response does)."""
        self.stacked.state_to_vector(self._x)
        self.reduction.multTranspose(self._x, x)
        x.pointwiseDivide(x, self._normal)

    def assemble_residual(self, x: PETSc.Vec, f: PETSc.Vec) -> None:
        """``R^T F(R x)``, the held rows ``x - x_bc``."""
        self.stacked.assemble_residual(self._expand(x), self._f)
        self.reduction.multTranspose(self._f, f)
        if len(self.bc_local):
            f.array[self.bc_local] = x.array_r[self.bc_local] - self.bc_values

    def assemble_jacobian(self, jac: PETSc.Mat) -> None:
        """``R^T J R`` of the stacked Jacobian (held rows and columns the identity). Where the
        stacked pattern grew (contact between bodies), the reduced one grows with it and
        :attr:`on_pattern_growth` is called."""
        regularization, self.stacked.regularization = self.stacked.regularization, 0.0
        try:  # the regularizer goes on the reduced matrix, once
            self.stacked.assemble_jacobian(self.stacked.jacobian)
        finally:
            self.stacked.regularization = regularization
        grew, self._grew = self._grew, False
        if grew:
            self._product.destroy()
            self._product = self.stacked.jacobian.PtAP(self.reduction)
            jac.zeroEntries()
            jac.axpy(1.0, self._product, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
            if self.on_pattern_growth is not None:
                self.on_pattern_growth()
        else:
            self.stacked.jacobian.PtAP(self.reduction, result=self._product)
            self._product.copy(jac, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
        jac.zeroRowsColumns(self.bc_rows, diag=1.0)
        add_diagonal_regularization(jac, regularization)

    def max_step(self, direction: PETSc.Vec) -> float:
        return self.stacked.max_step(self._expand(direction))

    def step_converged(self, direction: PETSc.Vec) -> bool:
        return self.stacked.step_converged(self._expand(direction))

    def matrix_nonzeros(self) -> int:
        return stored_entries(self.jacobian)

    def acceleration_residual(self, prefix: str, direct: bool) -> SharedAccelerationResidual:
        """``a_rms`` of reduced residuals (each body's mass assembled under ``<prefix><body>_``)."""
        return SharedAccelerationResidual(self, prefix, direct)

    def close(self) -> None:
        """Destroy the reduced objects and close the stacked problem (idempotent)."""
        if self._closed:
            return
        self._closed = True
        for obj in (self.reduction, self._normal, self._x, self._f, self.jacobian, self._product):
            if obj is not None:
                obj.destroy()
        self.stacked.close()


class SharedAccelerationResidual(AccelerationResidual):
    """``a_rms = sqrt(r_R^T M_R^-1 r_R / m)`` of a :class:`SharedDofProblem`'s residuals, with
    ``M_R = R^T M R`` of the bodies' block-diagonal mass ``M`` (a shared unknown carries the mass of
    every body it moves) and ``m`` the bodies' total mass.

    Args:
        problem: the reduced problem.
        prefix: PETSc options prefix of the mass solve (each body's mass matrix is assembled under
            ``<prefix><body>_``).
        direct: factor ``M_R`` (MUMPS) rather than iterate on it.
    """

    def __init__(self, problem: SharedDofProblem, prefix: str, direct: bool):
        self.prefix, self._closed = prefix, False
        stacked = problem.stacked
        bodies = [body.acceleration_residual(f"{prefix}{k}_", direct) for k, body in enumerate(stacked.problems)]
        try:
            self.mass = sum(b.mass for b in bodies)
            full = _block_diagonal(stacked, [b.matrix for b in bodies])
        finally:
            for body in bodies:
                body.close()
        try:
            self.matrix = full.PtAP(problem.reduction)
        finally:
            full.destroy()
        # each body's matrix holds identity rows where it is held: cleared, so that the bound on the
        # largest eigenvalue taken next sees the free DOFs' masses only, as one body's does
        self.matrix.zeroRowsColumns(problem.bc_rows, diag=0.0)
        self.constrained_local = problem.bc_local
        self._solve_with_matrix(problem.bc_rows, problem.comm, direct)


def _stacked_pairs(stacked: StackedProblem, shared: SharedDofs) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The shared entries as stacked closed DOFs ``x[second] = coefficient x[first]``, ``(3 k,)`` each:
    each entry's closed block and scale from its body's discretization (a closed DOF holds the
    entry's value times that scale)."""
    layout = stacked.closed
    for pairs in (shared.first, shared.second):
        bodies = pairs[:, 0]
        if len(pairs) and (bodies.min() < 0 or bodies.max() >= layout.bodies):
            raise ValueError(f"shared DOFs name bodies {sorted(set(bodies.tolist()))}; the solve has {layout.bodies}")
    dofs, scales = [], []
    for pairs in (shared.first, shared.second):
        side_dofs, side_scales = np.zeros((len(pairs), 3), np.int64), np.zeros(len(pairs))
        for body in np.unique(pairs[:, 0]):
            rows = np.flatnonzero(pairs[:, 0] == body)
            blocks, entry_scales = stacked.problems[body].model.discretization.entry_closed_blocks()
            entries = pairs[rows, 1]
            side_dofs[rows] = layout.to_stacked(int(body), 3 * blocks[entries][:, None] + np.arange(3))
            side_scales[rows] = entry_scales[entries]
        dofs.append(side_dofs.ravel())
        scales.append(np.repeat(side_scales, 3))
    return dofs[0], dofs[1], np.repeat(shared.scale, 3) * scales[1] / scales[0]


def _block_diagonal(stacked: StackedProblem, matrices: list[PETSc.Mat]) -> PETSc.Mat:
    """The bodies' closed matrices side by side on the stacked layout (AIJ)."""
    layout, comm = stacked.closed, stacked.comm
    pointers, columns, values = [np.zeros(1, np.int64)], [], []
    for body, matrix in enumerate(matrices):
        row_pointer, body_columns, body_values = matrix.getValuesCSR()
        pointers.append(np.asarray(row_pointer[1:], np.int64) + pointers[-1][-1])
        columns.append(layout.to_stacked(body, body_columns))
        values.append(body_values)
    size = (layout.size_local, layout.size_global)
    csr = (np.concatenate(pointers).astype(PETSc.IntType), np.concatenate(columns).astype(PETSc.IntType),
           np.concatenate(values))  # fmt: skip
    full = PETSc.Mat().createAIJ((size, size), csr=csr, comm=comm)
    full.assemble()
    return full

"""The shell problem in PETSc form, apart from any solver (as dolfinx separates ``NonlinearProblem``).

:class:`ShellProblem` owns the residual and Jacobian on the closed DOFs, the boundary-condition rows,
the seam prolongation and the total potential: the model's UFL terms (one contribution dolfinx
assembles, :mod:`.form_terms`) plus a list of energy contributions outside UFL
(:mod:`.contributions`: point loads, the augmented-Lagrangian point constraints, and any the caller
adds). On a surface with periodic directions it assembles on the
open grid and iterates on the closed DOFs ``x_c``: ``F_c = P^T F(P x_c)``, ``J_c = P^T J P``
(PETSc ``PtAP``, whose symbolic product is reused).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import numpy as np
from dolfinx import fem
from petsc4py import PETSc

from bhem_hpc.model.shell import ShellModel
from bhem_hpc.solver.contributions import (
    Contribution,
    ContributionState,
    ContributionSteps,
    GrowingPattern,
    PointConstraints,
    PointLoads,
    begin_lagged_step,
    diagonal_compensation,
)
from bhem_hpc.solver.form_terms import ShellFormTerms
from bhem_hpc.solver.petsc import PetscOwner
from bhem_hpc.solver.report import SolveReport


def pattern_arrays(rows: np.ndarray, columns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A contribution's Hessian pattern as PETSc's block row and column index arrays ``(k, 1)``."""
    rows, columns = np.asarray(rows).reshape(-1), np.asarray(columns).reshape(-1)
    if rows.shape != columns.shape:
        raise ValueError(f"a Hessian pattern needs as many rows as columns, got {rows.shape} and {columns.shape}")
    return rows.astype(PETSc.IntType)[:, None], columns.astype(PETSc.IntType)[:, None]


def _blocked_aij(
    csr: tuple[np.ndarray, np.ndarray, np.ndarray], open_size: int, closed_sizes: tuple[int, int], comm,
    ties: tuple[np.ndarray, np.ndarray] = (np.zeros(0, np.int64), np.zeros(0, np.int64)),
) -> PETSc.Mat:  # fmt: skip
    """The prolongation as an AIJ matrix on 3-component DOFs: block CSR ``(indptr, closed blocks,
    weights)`` over the owned open blocks, each entry repeated for the components x, y, z; the
    columns of tied scalar DOFs ``ties = (slaves, masters)`` moved to their masters (summed)."""
    indptr, blocks, weights = csr
    counts = np.diff(indptr)
    components = np.arange(3)
    row = (3 * np.repeat(np.arange(len(counts)), counts)[:, None] + components).ravel()
    columns = (3 * np.asarray(blocks)[:, None] + components).ravel()
    values = np.repeat(np.asarray(weights, float), 3)
    slaves, masters = ties
    if len(slaves):
        remap = np.arange(closed_sizes[1], dtype=np.int64)
        remap[slaves] = masters
        tied = remap[columns] != columns  # keep a stored zero in each slave column: P^T J P keeps its diagonal
        row = np.concatenate([row, row[tied]])
        columns = np.concatenate([remap[columns], columns[tied]])
        values = np.concatenate([values, np.zeros(int(tied.sum()))])
        keys, inverse = np.unique(row * closed_sizes[1] + columns, return_inverse=True)  # sums duplicates
        row, columns, values = keys // closed_sizes[1], keys % closed_sizes[1], np.bincount(inverse, weights=values)
    else:
        order = np.argsort(row, kind="stable")  # row 3b + c keeps block b's entries in their order
        row, columns, values = row[order], columns[order], values[order]
    row_pointer = np.concatenate([[0], np.cumsum(np.bincount(row, minlength=3 * len(counts)))])
    return PETSc.Mat().createAIJ(
        ((3 * len(counts), open_size), closed_sizes),
        csr=(row_pointer.astype(PETSc.IntType), columns.astype(PETSc.IntType), values),
        comm=comm,
    )


def add_contribution_hessians(
    matrix: PETSc.Mat, contributions: Sequence[Contribution], patterns: Sequence[tuple[np.ndarray, np.ndarray]],
    state: ContributionState, grow: bool = False,
) -> None:
    """Add each contribution's Hessian blocks at its pattern (block indices ``(k, 1)`` each) into the
    unassembled ``matrix``; every contribution is asked on every rank (it may be collective). The
    blocks a :class:`GrowingPattern` one has beyond its pattern are added where they are with
    ``grow`` (the matrix's pattern grows to take them and keeps them), or else as their
    :func:`diagonal_compensation` (a fixed pattern: the seams' product relies on it)."""
    for contribution, (rows, columns) in zip(contributions, patterns, strict=True):
        values = contribution.hessian(state)
        if len(rows):
            values = np.asarray(values, dtype=float).reshape(len(rows), 1, 9)
            matrix.setValuesBlockedRCV(rows, columns, values, addv=PETSc.InsertMode.ADD)
        if isinstance(contribution, GrowingPattern):
            extra = contribution.hessian_beyond_pattern()
            if len(extra[0]):
                rows, columns, values = extra if grow else diagonal_compensation(*extra)
                matrix.setValuesBlockedRCV(_column(rows), _column(columns), np.asarray(values).reshape(-1, 1, 9),
                                           addv=PETSc.InsertMode.ADD)  # fmt: skip


def _column(indices: np.ndarray) -> np.ndarray:
    return np.asarray(indices, dtype=PETSc.IntType).reshape(-1, 1)


def stored_entries(matrix: PETSc.Mat) -> int:
    """Collective: the entries ``matrix`` stores over all ranks (its pattern's size: it tells when
    the pattern grew)."""
    return int(matrix.getInfo(PETSc.Mat.InfoType.GLOBAL_SUM)["nz_used"])


def add_diagonal_regularization(jac: PETSc.Mat, regularization: float) -> None:
    """The paper's diagonal regularizer, scaled per row: ``J + r |diag J|`` (nothing for ``r = 0``)."""
    if regularization > 0:
        diagonal = jac.getDiagonal()
        diagonal.abs()
        diagonal.scale(regularization)
        jac.setDiagonal(diagonal, addv=PETSc.InsertMode.ADD)
        diagonal.destroy()


class ShellProblem(ContributionSteps, PetscOwner):
    """Residual, Jacobian, constraint rows and potential of a :class:`ShellModel` on the closed DOFs.

    Args:
        model: the shell model (forms, constraints, loads).
        matrix_format: PETSc type of the closed Jacobian (``"sbaij"``: one triangle, for a serial
            LDL^T without seams; ``"baij"``: 3 x 3 blocks as assembled, for Krylov solvers with block
            preconditioners without seams; otherwise ``"aij"``).
        report: where assembly times are added up.
        contributions: energy contributions besides the model's terms, point loads and point
            constraints (:class:`~bhem_hpc.solver.contributions.Contribution`).
    """

    def __init__(self, model: ShellModel, matrix_format: str, report: SolveReport,
                 contributions: Sequence[Contribution] = ()):  # fmt: skip
        self.model = model
        self.matrix_format = matrix_format
        self.report = report
        self._closed = False
        disc = model.discretization
        comm = model.comm
        n_local, n_global = 3 * disc.num_owned_closed, 3 * disc.num_closed
        #: the terms assembled into PETSc objects: the model's UFL forms
        self.form_terms = ShellFormTerms(model)
        self.f_open = self.form_terms.create_vector()
        self.point_constraints = self._point_constraints()
        self.contributions: list[Contribution] = [
            PointLoads(lambda: model.point_load_open, lambda: model.point_loads_version),
            self.point_constraints,
            *contributions,
        ]
        for contribution in self.contributions:
            if not isinstance(contribution, Contribution):
                raise TypeError(f"{contribution!r} is not an energy contribution (bhem_hpc.solver.contributions)")
        self._patterns = [pattern_arrays(*c.hessian_pattern()) for c in self.contributions]
        # Element matrices go into 3x3-block storage (insertion ~5x cheaper than AIJ). MUMPS' LDL^T
        # takes symmetric-block SBAIJ directly, but MPISBAIJ cannot zero constrained rows and
        # columns and PtAP needs AIJ: there the blocked matrix is converted to AIJ (output reused).
        self.jacobian_blocked: PETSc.Mat | None = self.form_terms.create_matrix("baij")
        self._add_contribution_pattern(self.jacobian_blocked)
        self.form_terms.add_hessian(self.jacobian_blocked, self.form_terms.hessian_kinds()[0])
        self.jacobian_blocked.assemble()
        self.jacobian_blocked.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
        if matrix_format == "baij":  # Krylov solvers and block preconditioners take it as assembled
            self.jacobian_open, self.jacobian_blocked = self.jacobian_blocked, None
        else:
            self.jacobian_open = PETSc.Mat()
            self.jacobian_blocked.convert(matrix_format, self.jacobian_open)
        if matrix_format == "sbaij":
            self.jacobian_open.setOption(PETSc.Mat.Option.IGNORE_LOWER_TRIANGULAR, True)
            self.jacobian_blocked.destroy()
            self.jacobian_blocked = None
        self.prolongation: PETSc.Mat | None = None
        prolongation = disc.prolongation()
        if prolongation is not None:
            open_size = 3 * disc.function_space.dofmap.index_map.size_global
            self.prolongation = _blocked_aij(prolongation, open_size, (n_local, n_global), comm,
                                             disc.component_ties())  # fmt: skip
            self.jacobian = self.jacobian_open.PtAP(self.prolongation)
        else:
            self.jacobian = self.jacobian_open
        self.jacobian.setOption(PETSc.Mat.Option.SYMMETRIC, model.symmetric)
        self.prolongation_offset: PETSc.Vec | None = None
        offset = disc.prolongation_offset()
        if offset is not None:  # tied control points keep their rest offsets from their masters
            self.prolongation_offset = model.x.vector.duplicate()
            with self.prolongation_offset.localForm() as local:
                local.array[:] = offset
        self.bc_local = model.constrained.local.astype(np.int64)
        self.bc_rows = model.constrained.rows.astype(PETSc.IntType)
        self.bc_values = model.constrained_initial.copy()
        self.regularization = 0.0  # the driver's diagonal regularizer r: J + r |diag J|
        # contributions' blocks beyond their patterns grow the Jacobian's (without seams, and not in
        # MPIBAIJ, where the grown matrix came out wrong); the count of its stored entries tells when
        growing = any(isinstance(c, GrowingPattern) for c in self.contributions)
        self._may_grow = growing and self.prolongation is None and not (matrix_format == "baij" and comm.size > 1)
        self._stored = 0
        if self._may_grow and self.jacobian_blocked is not None:
            # converting into a matrix whose pattern grew loses entries under MPI: assembled in place
            self.jacobian_blocked.destroy()
            self.jacobian_blocked = None
        if self._may_grow:
            self.jacobian_open.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, False)
        #: called when it grew: a factorization of the Jacobian must start again from its analysis
        self.on_pattern_growth: Callable[[], None] | None = None
        #: the Hessian kind the next Jacobian is assembled with (a key of ``model.jacobian_forms``)
        self.hessian = self.form_terms.hessian_kinds()[0]

    def _point_constraints(self) -> PointConstraints:
        """Augmented Lagrangian for the model's point constraints: penalty ``1e3 Y h``, tolerance
        ``1e-10`` of the rest surface's bounding-box diagonal."""
        model = self.model
        count = len(model.point_constraints)
        mask = np.zeros((count, 3))
        for k, pc in enumerate(model.point_constraints):
            mask[k, list(pc.components)] = 1.0
        penalty = 1e3 * model.material.young * model.material.thickness
        tolerance = 1e-10 * model.rest_diagonal
        constraints = PointConstraints(model.point_constraint_basis, model.global_open_blocks, mask, penalty,
                                       tolerance, model.comm.rank)  # fmt: skip
        constraints.targets[:] = np.array([pc.target_at(0.0) for pc in model.point_constraints]).reshape(count, 3)
        return constraints

    @property
    def alm_multipliers(self) -> np.ndarray:
        """The point constraints' multipliers ``(points, 3)`` (empty without point constraints)."""
        return self.point_constraints.multipliers

    def _add_contribution_pattern(self, matrix: PETSc.Mat) -> None:
        """Make room in the (unassembled) blocked matrix for the contributions' Hessian blocks, so
        that their assembly never allocates: zeros at their fixed pattern."""
        pairs = [(rows, columns) for rows, columns in self._patterns if len(rows)]
        if not self.model.comm.allreduce(len(pairs)):
            return
        # on every rank: a rank may receive new nonzeros in its rows from another rank's blocks
        matrix.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, False)
        for rows, columns in pairs:
            matrix.setValuesBlockedRCV(rows, columns, np.zeros((len(rows), 1, 9)), addv=PETSc.InsertMode.ADD)

    def contribution_state(self) -> ContributionState:
        """What the contributions see: the model's current position on this rank's open blocks."""
        model = self.model
        return ContributionState(model.x.x.array.reshape(-1, 3), float(model.load_factor.value), model.point_positions)

    def update_state(self, x: PETSc.Vec) -> None:
        """Write closed DOFs ``x`` into the model's position Function (with ghosts)."""
        self._to_open(x, self.model.x.vector, offset=True)

    def _to_open(self, closed: PETSc.Vec, target: PETSc.Vec, offset: bool) -> None:
        """``target = P closed`` (plus the tied slaves' rest offsets with ``offset``: a state, not a
        direction), ghosts updated."""
        if self.prolongation is not None:
            self.prolongation.mult(closed, target)
            if offset and self.prolongation_offset is not None:
                target.axpy(1.0, self.prolongation_offset)
        else:
            closed.copy(target)
        target.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)

    def open_direction(self, direction: PETSc.Vec, target: PETSc.Vec) -> None:
        """``target = P direction``: a direction on the closed DOFs onto the open ones (ghosts updated)."""
        self._to_open(direction, target, offset=False)

    def to_closed(self, open_vector: PETSc.Vec, closed: PETSc.Vec) -> None:
        """``closed = P^T open_vector``: a gradient on the open DOFs (its owned entries summed over
        the ranks already) onto the closed ones."""
        if self.prolongation is not None:
            self.prolongation.multTranspose(open_vector, closed)
        else:
            open_vector.copy(closed)

    def add_contribution_hessians(self, matrix: PETSc.Mat) -> None:
        """Add the contributions' Hessian blocks at the current state into the unassembled open-layout
        ``matrix`` as the Jacobian takes them (blocks beyond a pattern where they are, or on the
        diagonal where the Jacobian's pattern is fixed: :func:`add_contribution_hessians`)."""
        add_contribution_hessians(matrix, self.contributions, self._patterns, self.contribution_state(),
                                  self._may_grow)  # fmt: skip

    def state_to_vector(self, x: PETSc.Vec) -> None:
        """Copy the model's current position into closed DOFs ``x``."""
        x.array[:] = self.model.discretization.open_to_closed(self.model.x.x.array)

    def assemble_residual(self, x: PETSc.Vec, f: PETSc.Vec,
                          extra_gradient: Callable[[np.ndarray], None] | None = None) -> None:  # fmt: skip
        """``f = P^T (F_int - F_ext + sum of the contributions' gradients)`` with constrained rows
        replaced by ``x - x_bc``; ``extra_gradient(gradient)`` may add more to this rank's open
        blocks ``(blocks, 3)`` first (a problem of several bodies adds the terms that couple them)."""
        t0 = time.perf_counter()
        with self.f_open.localForm() as local:
            local.set(0.0)
        self.form_terms.add_gradient(self.f_open)
        state = self.contribution_state()
        with self.f_open.localForm() as local:
            gradient = local.array.reshape(-1, 3)
            for contribution in self.contributions:
                contribution.add_gradient(state, gradient)
            if extra_gradient is not None:
                extra_gradient(gradient)
        self.f_open.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        self.to_closed(self.f_open, f)
        if len(self.bc_local):
            values = f.array
            values[self.bc_local] = x.array_r[self.bc_local] - self.bc_values
        self.report.assemble_residual_s += time.perf_counter() - t0

    def hessian_kinds(self) -> tuple[str, ...]:
        """The Hessian kinds :attr:`hessian` may name, the first the default."""
        return self.form_terms.hessian_kinds()

    def term_residual_norms(self) -> dict[str, float]:
        """Collective: the 2-norm of each term's part of the residual at the current state, on the free
        DOFs (constrained rows left out), e.g. to tell which energy dominates a failed solve."""
        state = self.contribution_state()
        norms = {name: self.open_gradient_norm(lambda local, form=form: fem.assemble_vector(local, form))
                 for name, form in self.form_terms.term_gradient_forms().items()}  # fmt: skip
        for contribution in self.contributions:
            norms[contribution.name] = self.open_gradient_norm(
                lambda local, c=contribution: c.add_gradient(state, local.reshape(-1, 3)))  # fmt: skip
        return norms

    def open_gradient_norm(self, fill: Callable[[np.ndarray], None]) -> float:
        """Collective: the 2-norm on the free closed DOFs of the open gradient that ``fill(local)``
        adds into this rank's zeroed open entries ``local`` (owned and ghost blocks, flat)."""
        disc = self.model.discretization
        closed = PETSc.Vec().createMPI((3 * disc.num_owned_closed, 3 * disc.num_closed), comm=self.model.comm)
        try:
            with self.f_open.localForm() as local:
                local.set(0.0)
                fill(local.array)
            self.f_open.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            if self.prolongation is not None:
                self.prolongation.multTranspose(self.f_open, closed)
            else:
                self.f_open.copy(closed)
            closed.array[self.bc_local] = 0.0
            return closed.norm()
        finally:
            closed.destroy()

    def potential_energy(self) -> float:
        """Total potential at the model's current state (internal - external work, plus the
        contributions' energies), collective."""
        local = self.form_terms.local_energy()
        state = self.contribution_state()
        local += sum(contribution.energy(state) for contribution in self.contributions)
        return self.model.comm.allreduce(local)

    def max_step(self, direction: PETSc.Vec) -> float:
        """Collective: the largest fraction of the step ``x -> x + direction`` (closed DOFs) that every
        step-bounded contribution admits from the current state (1: none bounds it)."""
        if not self.has_step_bounds:
            return 1.0
        return self.max_open_step(self.open_direction_blocks(direction))

    def step_converged(self, direction: PETSc.Vec) -> bool:
        """Collective: whether the step-testing contributions let the solve end with the step
        ``x -> x + direction`` (closed DOFs) from the current state (False: none tests)."""
        return self.has_step_tests and self.open_step_converged(self.open_direction_blocks(direction))

    def open_direction_blocks(self, direction: PETSc.Vec) -> np.ndarray:
        """Collective: a closed-DOF direction on this rank's open blocks (owned and ghosts), ``(blocks, 3)``."""
        open_direction = self.model.x.vector.duplicate()
        try:
            self._to_open(direction, open_direction, offset=False)
            with open_direction.localForm() as local:
                return local.array.reshape(-1, 3).copy()
        finally:
            open_direction.destroy()

    def _assemble_open_jacobian(self) -> None:
        target = self.jacobian_open if self.jacobian_blocked is None else self.jacobian_blocked
        target.zeroEntries()
        self.form_terms.add_hessian(target, self.hessian)
        self.add_contribution_hessians(target)
        target.assemble()
        if self.jacobian_blocked is not None:
            self.jacobian_blocked.convert(self.matrix_format, self.jacobian_open)

    def assemble_jacobian(self, jac: PETSc.Mat) -> None:
        """``J = P^T J_open P`` with constrained rows and columns replaced by the identity. Hessian
        blocks of contributions beyond their patterns (:class:`GrowingPattern`) grow the pattern of
        ``J`` (without seams; :attr:`on_pattern_growth` is called when it grew), or go onto its
        diagonal (:func:`diagonal_compensation`: the seams' product needs a fixed pattern)."""
        t0 = time.perf_counter()
        self._assemble_open_jacobian()
        if self.prolongation is not None:
            self.jacobian_open.PtAP(self.prolongation, result=jac)
        elif self._may_grow:
            stored = stored_entries(jac)
            if stored > self._stored > 0 and self.on_pattern_growth is not None:
                self.on_pattern_growth()
            self._stored = stored
        jac.zeroRowsColumns(self.bc_rows, diag=1.0)
        add_diagonal_regularization(jac, self.regularization)
        self.report.assemble_jacobian_s += time.perf_counter() - t0

    def begin_step(self, time: float, dt: float) -> None:
        """Collective, before a time step from ``time`` [s] of ``dt`` [s] at the model's current
        position: the contributions that lag quantities from the step's start take them."""
        begin_lagged_step(self.contributions, self.contribution_state(), time, dt)
        if self.step_velocity_test is not None:
            self.step_velocity_test.dt = dt

    def set_point_targets(self, t: float, ramp: bool = False) -> None:
        """Targets of the point constraints at time (or load factor) ``t``.

        With ``ramp`` (static load stepping) a fixed target is approached linearly from the
        point's initial position, as prescribed nodal values are.
        """
        initial = self.model.initial_surface
        targets = self.point_constraints.targets
        for k, pc in enumerate(self.model.point_constraints):
            if ramp and not callable(pc.target):
                start = initial.evaluate(np.array(pc.xi1), np.array(pc.xi2)).x
                targets[k] = start + t * (pc.target_at(t) - start)
            else:
                targets[k] = pc.target_at(t)

    def matrix_nonzeros(self) -> int:
        """Nonzeros of the (closed) Jacobian as a full matrix (SBAIJ stores the upper triangle)."""
        stored = stored_entries(self.jacobian)
        if self.jacobian.getType().endswith("sbaij"):
            bs = self.jacobian.getBlockSize()
            diagonal_blocks = self.jacobian.getSize()[0] // bs
            return 2 * stored - bs * bs * diagonal_blocks
        return stored

    def update_multipliers(self) -> bool:
        """After a converged solve: whether every held point is within tolerance of its target; if
        not, the augmented-Lagrangian multipliers are updated for the next solve."""
        if self.point_constraints.update_multipliers(self.contribution_state()):
            return True
        self.report.multiplier_updates += 1
        return False

    def acceleration_residual(self, prefix: str, direct: bool):
        """The :class:`~bhem_hpc.solver.acceleration.AccelerationResidual` of this shell's residuals
        (its mass solve under ``prefix``; ``direct``: factored)."""
        from bhem_hpc.solver.acceleration import AccelerationResidual

        return AccelerationResidual(self.model, self.prolongation, self.bc_rows, self.bc_local, prefix, direct)

    def close(self) -> None:
        """Destroy the PETSc objects this problem owns (idempotent)."""
        if self._closed:
            return
        self._closed = True
        objects = [self.f_open, self.jacobian_open]
        if self.jacobian_blocked is not None:
            objects.append(self.jacobian_blocked)
        if self.prolongation is not None:
            objects += [self.prolongation, self.jacobian]
        if self.prolongation_offset is not None:
            objects.append(self.prolongation_offset)
        for obj in objects:
            obj.destroy()

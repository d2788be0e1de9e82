"""The shell problem in PETSc form, apart from any solver (as dolfinx separates ``NonlinearProblem``).

:class:`ShellProblem` owns the residual and Jacobian on the closed DOFs, the boundary-condition rows,
the seam prolongation, point loads and point constraints (augmented Lagrangian) and the total
potential. On a surface with periodic directions it assembles on the open grid and iterates on
the closed DOFs ``x_c``: ``F_c = P^T F(P x_c)``, ``J_c = P^T J P`` (PETSc ``PtAP``, whose symbolic
product is reused).
"""

from __future__ import annotations

import time

import dolfinx.fem as fem
import dolfinx.fem.petsc as fem_petsc
import numpy as np
from petsc4py import PETSc

from bhem_hpc.model.shell import ShellModel
from bhem_hpc.solver.petsc import PetscOwner
from bhem_hpc.solver.report import SolveReport


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


class ShellProblem(PetscOwner):
    """Residual, Jacobian, constraint rows and potential of a :class:`ShellModel` on the closed DOFs.

    Args:
        model: the shell model (forms, constraints, loads).
        matrix_format: PETSc type of the closed Jacobian (``"sbaij"``: one triangle, for a serial
            LDL^T without seams; ``"baij"``: 3 x 3 blocks as assembled, for Krylov solvers with block
            preconditioners without seams; otherwise ``"aij"``).
        report: where assembly times are added up.
    """

    def __init__(self, model: ShellModel, matrix_format: str, report: SolveReport):
        self.model = model
        self.matrix_format = matrix_format
        self.report = report
        self._closed = False
        disc = model.discretization
        comm = model.comm
        n_local, n_global = 3 * disc.num_owned_closed, 3 * disc.num_closed
        self.f_open = fem_petsc.create_vector(model.residual_form)
        self.point_loads = self.f_open.duplicate()
        self._point_loads_version = -1
        self._update_point_loads()
        # Element matrices go into 3x3-block storage (insertion ~5x cheaper than AIJ). MUMPS' LDL^T
        # takes symmetric-block SBAIJ directly, but MPISBAIJ cannot zero constrained rows and
        # columns and PtAP needs AIJ: there the blocked matrix is converted to AIJ (output reused).
        self.jacobian_blocked: PETSc.Mat | None = fem_petsc.create_matrix(model.jacobian_form, "baij")
        fem_petsc.assemble_matrix(self.jacobian_blocked, model.jacobian_form)
        self.jacobian_blocked.assemble()
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
        #: the Hessian kind the next Jacobian is assembled with (a key of ``model.jacobian_forms``)
        self.hessian = next(iter(model.jacobian_forms))
        self._init_point_constraints()

    def _init_point_constraints(self) -> None:
        """Augmented Lagrangian for point constraints: multipliers, penalty, targets, masks."""
        model = self.model
        count = len(model.point_constraints)
        self.alm_multipliers = np.zeros((count, 3))
        self.alm_mask = np.zeros((count, 3))
        for k, pc in enumerate(model.point_constraints):
            self.alm_mask[k, list(pc.components)] = 1.0
        self.alm_targets = np.array([pc.target_at(0.0) for pc in model.point_constraints]).reshape(count, 3)
        self.alm_penalty = 1e3 * model.material.young * model.material.thickness
        nodes = model.rest_surface.evaluate(*model.rest_surface.grid.node_parameters()).x
        lo, hi = nodes.min(axis=(0, 1)), nodes.max(axis=(0, 1))
        self.alm_tolerance = 1e-10 * float(np.linalg.norm(hi - lo))

    def _update_point_loads(self) -> None:
        """Copy the model's point loads (again when :meth:`ShellModel.set_load` changed one)."""
        if self._point_loads_version == self.model.point_loads_version:
            return
        with self.point_loads.localForm() as local:
            local.array[:] = self.model.point_load_open
        self.point_loads.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        self._point_loads_version = self.model.point_loads_version

    def update_state(self, x: PETSc.Vec) -> None:
        """Write closed DOFs ``x`` into the model's position Function (with ghosts)."""
        target = self.model.x.vector
        if self.prolongation is not None:
            self.prolongation.mult(x, target)
            if self.prolongation_offset is not None:
                target.axpy(1.0, self.prolongation_offset)
        else:
            x.copy(target)
        target.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)

    def state_to_vector(self, x: PETSc.Vec) -> None:
        """Copy the model's current position into closed DOFs ``x``."""
        x.array[:] = self.model.discretization.open_to_closed(self.model.x.x.array)

    def assemble_residual(self, x: PETSc.Vec, f: PETSc.Vec) -> None:
        """``f = P^T (F_int - F_ext)`` with constrained rows replaced by ``x - x_bc``."""
        t0 = time.perf_counter()
        self._update_point_loads()
        with self.f_open.localForm() as local:
            local.set(0.0)
        fem_petsc.assemble_vector(self.f_open, self.model.residual_form)
        if len(self.alm_multipliers):
            force = (self.alm_multipliers + self.alm_penalty * self.point_constraint_violation()) * self.alm_mask
            with self.f_open.localForm() as local:
                blocked = local.array.reshape(-1, 3)
                for k, (blocks, values) in enumerate(self.model.point_constraint_basis):
                    blocked[blocks] += values[:, None] * force[k]
        self.f_open.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        self.f_open.axpy(-float(self.model.load_factor.value), self.point_loads)
        if self.prolongation is not None:
            self.prolongation.multTranspose(self.f_open, f)
        else:
            self.f_open.copy(f)
        if len(self.bc_local):
            values = f.array
            values[self.bc_local] = x.array_r[self.bc_local] - self.bc_values
        self.report.assemble_residual_s += time.perf_counter() - t0

    def term_residual_norms(self) -> dict[str, float]:
        """Collective: the 2-norm of each term's part of the residual at the current state, on the free
        DOFs (constrained rows left out), e.g. to tell which energy dominates a failed solve."""
        norms = {}
        disc = self.model.discretization
        closed = PETSc.Vec().createMPI((3 * disc.num_owned_closed, 3 * disc.num_closed), comm=self.model.comm)
        try:
            for name, form in self.model.term_residual_forms().items():
                with self.f_open.localForm() as local:
                    local.set(0.0)
                fem_petsc.assemble_vector(self.f_open, form)
                self.f_open.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
                if self.prolongation is not None:
                    self.prolongation.multTranspose(self.f_open, closed)
                else:
                    self.f_open.copy(closed)
                closed.array[self.bc_local] = 0.0
                norms[name] = closed.norm()
        finally:
            closed.destroy()
        return norms

    def point_constraint_violation(self) -> np.ndarray:
        """``x(xi_p) - target`` of every point constraint (constrained components), collective.

        Returns:
            Array of shape ``(points, 3)``; unconstrained components are 0.
        """
        positions = self.model.point_positions(self.model.point_constraint_basis)
        return (positions - self.alm_targets) * self.alm_mask

    def potential_energy(self) -> float:
        """Total potential at the model's current state (internal - external work), collective."""
        self._update_point_loads()
        local = fem.assemble_scalar(self.model.potential_form)
        local -= float(self.model.load_factor.value) * float(
            np.dot(self.point_loads.array_r, self.model.x.vector.array_r)
        )
        if len(self.alm_multipliers):
            c = self.point_constraint_violation()
            alm = float(np.sum(self.alm_multipliers * c) + 0.5 * self.alm_penalty * np.sum(c * c))
            local += alm if self.model.comm.rank == 0 else 0.0
        return self.model.comm.allreduce(local)

    def _assemble_open_jacobian(self) -> None:
        target = self.jacobian_open if self.jacobian_blocked is None else self.jacobian_blocked
        target.zeroEntries()
        fem_petsc.assemble_matrix(target, self.model.jacobian_forms[self.hessian])
        for blocks, values in self.model.point_constraint_basis:  # rho Phi Phi^T per component
            block = self.alm_penalty * np.outer(values, values)
            for comp in range(3):
                rows = (3 * blocks + comp).astype(PETSc.IntType)
                target.setValuesLocal(rows, rows, block, addv=PETSc.InsertMode.ADD)
        target.assemble()
        if self.jacobian_blocked is not None:
            self.jacobian_blocked.convert(self.matrix_format, self.jacobian_open)

    def assemble_jacobian(self, jac: PETSc.Mat) -> None:
        """``J = P^T J_open P`` with constrained rows and columns replaced by the identity."""
        t0 = time.perf_counter()
        self._assemble_open_jacobian()
        if self.prolongation is not None:
            self.jacobian_open.PtAP(self.prolongation, result=jac)
        jac.zeroRowsColumns(self.bc_rows, diag=1.0)
        if self.regularization > 0:
            # The paper's diagonal regularizer, scaled per row: J + r |diag J|.
            diagonal = jac.getDiagonal()
            diagonal.abs()
            diagonal.scale(self.regularization)
            jac.setDiagonal(diagonal, addv=PETSc.InsertMode.ADD)
            diagonal.destroy()
        self.report.assemble_jacobian_s += time.perf_counter() - t0

    def set_point_targets(self, t: float, ramp: bool = False) -> None:
        """Targets of the point constraints at time (or load factor) ``t``.

        With ``ramp`` (static load stepping) a fixed target is approached linearly from the
        point's initial position, as prescribed nodal values are.
        """
        initial = self.model.initial_surface
        for k, pc in enumerate(self.model.point_constraints):
            if ramp and not callable(pc.target):
                start = initial.evaluate(np.array(pc.xi1), np.array(pc.xi2)).x
                self.alm_targets[k] = start + t * (pc.target_at(t) - start)
            else:
                self.alm_targets[k] = pc.target_at(t)

    def matrix_nonzeros(self) -> int:
        """Nonzeros of the (closed) Jacobian as a full matrix (SBAIJ stores the upper triangle)."""
        stored = int(self.jacobian.getInfo(PETSc.Mat.InfoType.GLOBAL_SUM)["nz_used"])
        if self.jacobian.getType().endswith("sbaij"):
            bs = self.jacobian.getBlockSize()
            diagonal_blocks = self.jacobian.getSize()[0] // bs
            return 2 * stored - bs * bs * diagonal_blocks
        return stored

    def update_multipliers(self) -> bool:
        """After a converged solve: whether every held point is within tolerance of its target; if
        not, the augmented-Lagrangian multipliers are updated for the next solve."""
        violation = self.point_constraint_violation()
        if np.abs(violation).max() <= self.alm_tolerance:
            return True
        self.alm_multipliers += self.alm_penalty * violation
        self.report.multiplier_updates += 1
        return False

    def close(self) -> None:
        """Destroy the PETSc objects this problem owns (idempotent)."""
        if self._closed:
            return
        self._closed = True
        objects = [self.f_open, self.point_loads, self.jacobian_open]
        if self.jacobian_blocked is not None:
            objects.append(self.jacobian_blocked)
        if self.prolongation is not None:
            objects += [self.prolongation, self.jacobian]
        if self.prolongation_offset is not None:
            objects.append(self.prolongation_offset)
        for obj in objects:
            obj.destroy()

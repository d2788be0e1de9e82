"""The contact projector's PETSc side: the impulse metric, its factorizations and the dual solves."""

from __future__ import annotations

import logging
from collections.abc import Mapping

import dolfinx.fem as fem
import dolfinx.fem.petsc as fem_petsc
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from bhem_hpc import forms
from bhem_hpc.model.jit import compilation_report, default_jit_params
from bhem_hpc.solver.petsc import PetscOwner, SolverError, mumps_infog, push_options
from bhem_hpc.solver.problem import ShellProblem

log = logging.getLogger(__name__)


def dual_residual(targets: np.ndarray, current: np.ndarray | None, rows: tuple[np.ndarray, np.ndarray],
                  position: np.ndarray, count: int, combine) -> np.ndarray:  # fmt: skip
    """``targets - G current`` of the selected rows ``rows = (index (r, K), coefficients (r, K, 3))``
    (``current`` None: the targets themselves), the rows at one ``position`` (of ``count`` distinct
    rows) combined by the ufunc ``combine`` (``np.add``: one multiplier for the sum of their residuals;
    ``np.maximum``: the tightest bound)."""
    residual = np.asarray(targets, dtype=float).copy()
    if current is not None:
        index, coefficients = rows
        residual -= np.einsum("rkc,rkc->r", coefficients, current[index])
    reduced = np.full(count, -np.inf) if combine is np.maximum else np.zeros(count)
    combine.at(reduced, position, residual)
    return reduced


def dual_solve(matrix: np.ndarray, residual: np.ndarray, what: str) -> np.ndarray:
    """Multipliers ``lambda`` of the dual system ``matrix lambda = residual`` (``(r, r)``, symmetric
    positive definite), with one step of iterative refinement: the system is as ill-conditioned as its
    regularization is small. ``what`` names the projection in the error."""
    try:
        multipliers = np.linalg.solve(matrix, residual)
        return multipliers + np.linalg.solve(matrix, residual - matrix @ multipliers)
    except np.linalg.LinAlgError as error:
        raise SolverError(f"{what} failed: singular dual system of {len(residual)} contact rows") from error


def dual_solve_pushing(matrix: np.ndarray, lower: np.ndarray, what: str) -> np.ndarray:
    """Multipliers ``lambda >= 0`` with ``matrix lambda >= lower`` and complementarity (impulses that
    only push; :func:`~bhem_hpc.collision.lcp.solve_lcp`). ``what`` names the projection in the error."""
    from bhem_hpc.collision.lcp import ComplementarityError, solve_lcp  # contact scenes only

    try:
        multipliers, _ = solve_lcp(matrix, lower)
    except (ComplementarityError, np.linalg.LinAlgError) as error:
        raise SolverError(f"{what} failed: {error}") from error
    return multipliers


class ContactProjector(PetscOwner):
    """Least-squares projection of velocities and positions onto linear contact constraints (§6.2).

    Each contact row ``g`` is a linear function of the nodal data (a point's normal or tangential
    velocity, or its separation). The update ``d`` of a nodal vector with rows ``G`` and targets
    ``b`` minimizes ``|G (u + d) - b|^2 + eps d^T W d``, i.e. ``(G^T G + eps W) d = G^T (b - G u)``.
    It is solved in its dual (Woodbury) form ``d = Z lambda``, ``(G Z + eps I) lambda = b - G u``
    with ``Z = W^-1 G^T``: W is factored once per time step (:meth:`set_metric`), ``Z`` is computed
    for each new row with one multi-right-hand-side MUMPS solve and kept for the step, and every
    projection after that (active-set iterations, friction, push-out, later rounds) is a small dense
    solve. ``eps`` is tiny relative to ``G^T G``, so rows are met in the least-squares sense (exactly
    where they are compatible) and the update is the W-metric minimum ``W d = G^T lambda``: an
    impulse response that conserves linear momentum whenever the impulses do (self-contact pairs).
    Constrained DOFs do not move.

    Every contact row is a direction times a scalar combination of nodal entries
    (``d . sum_k w_k x[index_k]``). The metric ``M + S`` acts on the three components alike, so
    when the constraints do too it is factored as its scalar ``(N, N)`` block ``W_s`` (a ninth of
    the factor) and ``Z`` of a row is ``d`` times one scalar solve ``W_s^-1 w``, which also serves
    the row's other directions (friction's tangents).

    Args:
        problem: the model's problem (its constrained rows and seam prolongation are reused): a
            solver's ``problem``, or one body's among several (``StackedProblem.problems``).
        prefix: PETSc options prefix of the metric's KSP.
        options: PETSc options (without prefix) overriding the defaults.
        regularization: ``eps`` relative to ``max diag(G^T G) / max diag(W)``.
        smoothing: weight of the gradient term of the impulse metric
            (:func:`forms.impulse_metric`; 0 = the bare mass matrix).
    """

    def __init__(
        self,
        problem: ShellProblem,
        prefix: str = "bhem_contact_",
        options: Mapping[str, object] | None = None,
        regularization: float = 1e-8,
        smoothing: float = 1.0,
    ):
        model = problem.model
        if model.dynamics is None:
            raise ValueError("contact response needs a dynamic ShellModel (its mass matrix)")
        self.model = model
        self.prefix = prefix
        self.regularization = regularization
        self._closed = False
        disc = model.discretization
        comm = model.comm
        grid = model.rest_surface.grid
        space = model.discretization.function_space

        def assemble(mass_weight: float, smoothing_weight: float) -> PETSc.Mat:
            jit = default_jit_params()
            with compilation_report("the contact metric", jit["cache_dir"]):
                form = fem.form(model.in_unknowns(
                    forms.impulse_metric(
                        ufl.TrialFunction(space), ufl.TestFunction(space), model.x_rest, model.density, model.thickness,
                        (grid.h1, grid.h2), (mass_weight, smoothing_weight), model.dx,
                    )),
                    jit_params=jit,
                )  # fmt: skip
            matrix = fem_petsc.assemble_matrix(form)
            matrix.assemble()
            if problem.prolongation is None:
                return matrix
            closed = matrix.PtAP(problem.prolongation)
            matrix.destroy()
            return closed

        self.mass = assemble(1.0, smoothing)  # M + S: the metric without a Jacobian
        self.smoothing = assemble(0.0, smoothing)  # S alone, added to dt^2 J
        self.bc_rows = problem.bc_rows
        self.bc_local = problem.bc_local
        # Contact rows name entries (the discretization's flat nodal data): their closed DOFs.
        self.entry_block, self.entry_scale = disc.entry_closed_blocks()
        self._constrained_global = np.zeros(3 * disc.num_closed, dtype=bool)
        for rows in comm.allgather(np.asarray(problem.bc_rows, dtype=np.int64)):
            self._constrained_global[rows] = True
        # Sparse right-hand sides serially only: PETSc 3.18's parallel path stops with MUMPS
        # INFOG(1) = -27 (the sparse RHS pointers do not match); in parallel G^T goes dense.
        self.sparse_rhs = comm.size == 1
        self.n_local, self.n_global = 3 * disc.num_owned_closed, 3 * disc.num_closed
        self.first_owned = 3 * disc.closed_offset  # first owned closed DOF
        self.options = {
            "ksp_type": "preonly",
            "pc_type": "cholesky",
            "pc_factor_mat_solver_type": "mumps",
            "mat_mumps_icntl_7": "2",
        }
        self.option_overrides = dict(options or {})
        self.weighted: PETSc.Mat | None = None
        self.ksp: PETSc.KSP | None = None
        # the scalar block of M + S (see the class docstring): usable where every constrained
        # nodal entry has all three components constrained
        self.scalar_ksp: PETSc.KSP | None = None
        self.scalar_weighted: PETSc.Mat | None = None
        self._scalar_active = False  # the current metric is M + S through its scalar block
        # W_s^-1 w of contact points (index, weights): M + S does not change, so the columns of
        # points used in the previous step are kept (a shell sample keeps its weights)
        self._scalar_ids: dict[bytes, int] = {}  # (index, weights) -> column of _scalar_z
        self._scalar_z = np.zeros((self.n_local // 3, 0))  # owned rows, one column per point
        self._scalar_used: set[int] = set()  # columns used since the last set_metric
        self._scalar_max = 1.0
        self.scalar_metric = bool(
            np.all(
                self._constrained_global.reshape(-1, 3).all(axis=1)
                == self._constrained_global.reshape(-1, 3).any(axis=1)
            )
        )
        self._metric_kind = ""  # what `weighted` holds: "mass" (M + S) or "jacobian" (dt^2 J + S)
        self.weighted_max = 1.0
        self.factorizations = 0
        self.projections = 0
        self._forget_rows()
        self._selected: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # (row ids, index, coefficients)

    def _forget_rows(self) -> None:
        """Empty the per-step cache of rows and their columns ``Z = W^-1 G^T``."""
        self._row_ids: dict[bytes, int] = {}
        self._row_closed: list[tuple[np.ndarray, ...]] = []  # see _closed_rows
        self._z = np.zeros((self.n_local, 0))  # owned rows of Z, one column per cached row (vector metric)
        # scalar metric: Z of cached row r is _row_direction[r] x _scalar_z[:, _row_column[r]]
        self._row_column: list[int] = []
        self._row_direction: list[np.ndarray] = []
        self._schur = np.zeros((0, 0))  # G Z over the cached rows (identical on every rank)

    def _to_closed(self, entries: np.ndarray) -> PETSc.Vec:
        """Owned closed vector of entries ``(N, 3)`` (known on every rank)."""
        vec = PETSc.Vec().createMPI((self.n_local, self.n_global), comm=self.model.comm)
        vec.array[:] = self.model.discretization.entries_to_closed(entries)
        return vec

    def set_metric(self, jacobian: PETSc.Mat | None = None, time_step: float = 1.0) -> None:
        """Collective: the metric ``W`` of the following projections, factored (once per time step).

        Args:
            jacobian: the time step's Jacobian ``J = M / dt^2 + K (+ damping)``: then
                ``W = dt^2 J + S`` - a stiff shell answers an impulse or a push as a whole, a soft
                one locally; without it ``W = M + S``. Both satisfy ``W t = M t`` for rigid
                translations ``t``, so impulses conserve linear momentum.
            time_step: the ``dt`` of ``jacobian``.
        """
        self.release()
        self._forget_rows()
        if jacobian is None and self.scalar_metric:
            self._scalar_active = True
            if self.scalar_ksp is None:  # M + S does not change: factored once
                self._factor_scalar_mass()
            keep = sorted(self._scalar_used)
            position = {column: k for k, column in enumerate(keep)}
            self._scalar_ids = {key: position[c] for key, c in self._scalar_ids.items() if c in position}
            self._scalar_z = self._scalar_z[:, keep]
            self._scalar_used = set()
            self.weighted_max = self._scalar_max
            return
        self._scalar_active = False
        kind = "mass" if jacobian is None else "jacobian"
        if self.ksp is not None and kind == self._metric_kind == "mass":
            return  # M + S does not change: its factorization stays
        # The same nonzero pattern every step: refill the values, and the KSP refactors numerically
        # keeping MUMPS' symbolic analysis.
        reuse = self.ksp is not None and kind == self._metric_kind
        if not reuse:
            for obj in (self.weighted, self.ksp):
                if obj is not None:
                    obj.destroy()
            self.weighted = self.ksp = None
        if jacobian is None:
            self.weighted = self.mass.copy()
        else:
            # W in the Jacobian's own format (SBAIJ for the serial LDL^T: one triangle), S too
            if self.smoothing.getType() != jacobian.getType():
                if jacobian.getType().endswith("sbaij"):
                    self.smoothing.setOption(PETSc.Mat.Option.SYMMETRIC, True)
                self.smoothing.convert(jacobian.getType())  # in place
            if reuse:
                jacobian.copy(self.weighted, PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
            else:
                self.weighted = jacobian.duplicate(copy=True)
            self.weighted.scale(time_step**2)
            self.weighted.axpy(1.0, self.smoothing, PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        diagonal = self.weighted.getDiagonal()
        self.weighted_max = self.model.comm.allreduce(float(np.abs(diagonal.array_r).max(initial=0.0)), op=MPI.MAX)
        diagonal.destroy()
        self.weighted.setOption(PETSc.Mat.Option.SYMMETRIC, True)
        self.weighted.setOption(PETSc.Mat.Option.SPD, True)
        self.weighted.zeroRowsColumns(self.bc_rows, diag=1.0)
        if not reuse:
            self.ksp = self._new_ksp(self.weighted)
            self._metric_kind = kind
        self.ksp.setOperators(self.weighted)
        self.ksp.setUp()
        self.factorizations += 1
        self._check_factored(self.ksp)

    def _new_ksp(self, matrix: PETSc.Mat) -> PETSc.KSP:
        """A KSP on ``matrix`` under the projector's prefix, its options pushed and overridable."""
        ksp = PETSc.KSP().create(self.model.comm)
        ksp.setOptionsPrefix(self.prefix)
        opts = PETSc.Options()
        pushed = push_options(self.prefix, self.options, self.option_overrides)
        try:
            ksp.setFromOptions()
        finally:
            for name in pushed:
                opts.delValue(name)
        ksp.setOperators(matrix)
        return ksp

    def _factor_scalar_mass(self) -> None:
        """Collective: factor the scalar block ``W_s`` of ``M + S`` (rows ``3 b`` of the closed DOFs)."""
        comm = self.model.comm
        weighted = self.mass.copy()
        diagonal = weighted.getDiagonal()  # before the constrained rows' unit diagonal, as set_metric
        self._scalar_max = comm.allreduce(float(np.abs(diagonal.array_r).max(initial=0.0)), op=MPI.MAX)
        diagonal.destroy()
        weighted.zeroRowsColumns(self.bc_rows, diag=1.0)  # all three components of a constrained entry
        rows = PETSc.IS().createStride(self.n_local // 3, first=self.first_owned, step=3, comm=comm)
        try:
            self.scalar_weighted = weighted.createSubMatrix(rows, rows)
        finally:
            rows.destroy()
            weighted.destroy()
        self.scalar_weighted.setOption(PETSc.Mat.Option.SYMMETRIC, True)
        self.scalar_weighted.setOption(PETSc.Mat.Option.SPD, True)
        self.scalar_ksp = self._new_ksp(self.scalar_weighted)
        self.scalar_ksp.setUp()
        self.factorizations += 1
        self._check_factored(self.scalar_ksp)

    def _check_factored(self, ksp: PETSc.KSP) -> None:
        status = mumps_infog(ksp)
        if status is not None and status < 0:  # not MUMPS (options overridden): errors surface in the solves
            raise SolverError(f"contact metric '{self.prefix}' could not be factored: {self._mumps_info(ksp)}")

    def _mumps_info(self, ksp: PETSc.KSP | None = None) -> str:
        status = mumps_infog(ksp or (self.scalar_ksp if self._scalar_active else self.ksp))
        return "no MUMPS information" if status is None else f"MUMPS INFOG(1) = {status}"

    def _closed_rows(self, index: np.ndarray, coefficients: np.ndarray) -> tuple[np.ndarray, ...]:
        """Row ``(K,)`` entries / ``(K, 3)`` coefficients -> global closed indices and values (the
        absent second point of a collider contact has zero weights and is dropped), then the
        positions among this rank's owned closed DOFs and values of the owned ones."""
        closed = 3 * self.entry_block[index][:, None] + np.arange(3)
        values = coefficients / self.entry_scale[index][:, None]
        nonzero = values != 0.0
        closed, values = closed[nonzero], values[nonzero]
        owned = (closed >= self.first_owned) & (closed < self.first_owned + self.n_local)
        return closed, values, closed[owned] - self.first_owned, values[owned]

    def _right_hand_sides(self, columns: list[tuple[np.ndarray, np.ndarray]], scalar: bool = False,
                          dense: bool = False) -> PETSc.Mat:  # fmt: skip
        """Right-hand sides ``(n, len(columns))`` from each column's global closed indices and values
        (duplicates add up) in the vector numbering (3 per closed nodal entry) or the scalar one (1
        per entry); constrained DOFs stay zero (they do not move). Serially the transpose of a
        sparse matrix: MUMPS then skips the zero parts of each column in the forward elimination
        (PETSc 3.18's parallel path stops with MUMPS INFOG(1) = -27: in parallel they are dense)."""
        step = 3 if scalar else 1
        n_local, n_global, first = self.n_local // step, self.n_global // step, self.first_owned // step
        constrained = self._constrained_global[::step]
        index = np.concatenate([c for c, _ in columns])
        values = np.concatenate([v for _, v in columns])
        column_of = np.repeat(np.arange(len(columns)), [len(c) for c, _ in columns])
        keep = ~constrained[index]
        index, values, column_of = index[keep], values[keep], column_of[keep]
        comm = self.model.comm
        if dense or not self.sparse_rhs:
            owned = (index >= first) & (index < first + n_local)
            rhs = np.zeros((n_local, len(columns)), order="F")
            np.add.at(rhs, (index[owned] - first, column_of[owned]), values[owned])
            sizes = ((n_local, n_global), (PETSc.DECIDE, len(columns)))
            return PETSc.Mat().createDense(sizes, array=rhs, comm=comm)
        key, total = np.unique(column_of * n_global + index, return_inverse=True)  # one entry per (column, DOF)
        summed = np.bincount(total, weights=values, minlength=len(key))
        indptr = np.concatenate([[0], np.cumsum(np.bincount(key // n_global, minlength=len(columns)))])
        g = PETSc.Mat().createAIJ(
            ((len(columns), len(columns)), (n_local, n_global)),
            csr=(indptr.astype(PETSc.IntType), (key % n_global).astype(PETSc.IntType), summed),
            comm=comm,
        )
        transposed = PETSc.Mat().createTranspose(g)
        g.destroy()  # the transpose keeps a reference
        return transposed

    def _solve_for(self, ksp: PETSc.KSP, columns: list[tuple[np.ndarray, np.ndarray]], scalar: bool,
                   what: str) -> np.ndarray:  # fmt: skip
        """Collective: this rank's rows of ``W^-1`` applied to the right-hand sides of ``columns``
        (:meth:`_right_hand_sides`). A sparse right-hand side that MUMPS refuses is solved again as a
        dense one (PETSc 3.18's sparse path stopped once with INFOG(1) = -22 in a test of two cotton
        bodies; it was not reproduced)."""
        try:
            return self._solve_columns(ksp, self._right_hand_sides(columns, scalar), what)
        except SolverError as error:
            if not self.sparse_rhs:
                raise
            log.warning("%s; solving again with dense right-hand sides", error)
            return self._solve_columns(ksp, self._right_hand_sides(columns, scalar, dense=True), what)

    def _solve_columns(self, ksp: PETSc.KSP, rhs: PETSc.Mat, what: str) -> np.ndarray:
        """Collective: this rank's rows of ``W^-1 rhs`` through the factorization of ``ksp``."""
        x = PETSc.Mat().createDense(rhs.getSizes(), comm=self.model.comm)
        x.setUp()
        try:
            ksp.getPC().getFactorMatrix().matSolve(rhs, x)
            solution = x.getDenseArray().copy()
        except PETSc.Error as error:
            raise SolverError(
                f"contact projection '{self.prefix}': solving for {what} failed ({self._mumps_info(ksp)})"
            ) from error
        finally:
            rhs.destroy()
            x.destroy()
        if not np.all(np.isfinite(solution)):
            raise SolverError(f"contact projection '{self.prefix}': non-finite response to {what}")
        return solution

    def _scalar_columns(self, index: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """Collective: the columns of ``_scalar_z`` holding ``W_s^-1 w`` of the contact points
        ``(index (r, K), weights (r, K))``, one scalar solve per point not yet there (points are kept
        for this step and the next)."""
        columns = np.empty(len(index), dtype=np.int64)
        fresh: list[int] = []
        for r in range(len(index)):
            key = index[r].tobytes() + weights[r].tobytes()
            if key not in self._scalar_ids:
                self._scalar_ids[key] = self._scalar_z.shape[1] + len(fresh)
                fresh.append(r)
            columns[r] = self._scalar_ids[key]
        if fresh:
            points = [(self.entry_block[index[r]], weights[r] / self.entry_scale[index[r]]) for r in fresh]
            solved = self._solve_for(self.scalar_ksp, points, True, f"{len(fresh)} new contact points")
            self._scalar_z = np.hstack([self._scalar_z, solved])
        self._scalar_used.update(columns.tolist())
        return columns

    def _scalar_gz(self, index: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """Collective: ``w_a . W_s^-1 w`` of the points ``(index (r, K), weights (r, K))`` against
        every column of ``_scalar_z``, ``(r, columns)``."""
        first, count = self.first_owned // 3, self.n_local // 3
        products = np.zeros((len(index), self._scalar_z.shape[1]))
        for r in range(len(index)):
            blocks, values = self.entry_block[index[r]] - first, weights[r] / self.entry_scale[index[r]]
            owned = (blocks >= 0) & (blocks < count)
            products[r] = values[owned] @ self._scalar_z[blocks[owned]]
        return self.model.comm.allreduce(products, op=MPI.SUM)

    def _add_rows(self, index: np.ndarray, weights: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Collective: cache ids of the rows, computing ``Z = W^-1 G^T`` for the new ones in one
        multi-right-hand-side solve and extending ``G Z``."""
        coefficients = weights[:, :, None] * directions[:, None, :]
        ids = np.empty(len(index), dtype=np.int64)
        new: list[int] = []
        new_rows: list[int] = []  # their positions among the given rows
        for r in range(len(index)):
            key = index[r].tobytes() + coefficients[r].tobytes()
            if key not in self._row_ids:
                self._row_ids[key] = len(self._row_closed)
                self._row_closed.append(self._closed_rows(index[r], coefficients[r]))
                new.append(len(self._row_closed) - 1)
                new_rows.append(r)
            ids[r] = self._row_ids[key]
        if not new:
            return ids
        comm = self.model.comm
        # G Z for the new rows against every cached row (and by symmetry the transposed block)
        if self._scalar_active:
            # row a against row b: (d_a . d_b) (w_a . W_s^-1 w_b)
            self._row_column += self._scalar_columns(index[new_rows], weights[new_rows]).tolist()
            self._row_direction += list(directions[new_rows])
            products = self._scalar_gz(index[new_rows], weights[new_rows])
            block = (directions[new_rows] @ np.array(self._row_direction).T) * products[:, self._row_column]
        else:
            rows = [self._row_closed[row][:2] for row in new]
            self._z = np.hstack([self._z, self._solve_for(self.ksp, rows, False, f"{len(new)} new contact rows")])
            block = np.zeros((len(new), self._z.shape[1]))
            for k, row in enumerate(new):
                _, _, local, local_values = self._row_closed[row]
                block[k] = local_values @ self._z[local]
            block = comm.allreduce(block, op=MPI.SUM)
        old = self._schur.shape[0]
        total = len(self._row_closed)
        schur = np.zeros((total, total))
        schur[:old, :old] = self._schur
        schur[old:, :] = block
        schur[:old, old:] = block[:, :old].T
        self._schur = 0.5 * (schur + schur.T)
        return ids

    def set_rows(self, index: np.ndarray, weights: np.ndarray, directions: np.ndarray) -> None:
        """Collective: select the contact rows of the following :meth:`solve` (replaces earlier rows).

        Row ``r`` is ``directions[r] . sum_k weights[r, k] x[index[r, k]]`` of nodal data ``x``.

        Args:
            index: ``(r, K)`` flat nodal entries of each row (identical on every rank).
            weights: ``(r, K)`` their weights.
            directions: ``(r, 3)`` the rows' directions.
        """
        if self.ksp is None and not self._scalar_active:
            self.set_metric()
        index, weights, directions = np.asarray(index), np.asarray(weights, float), np.asarray(directions, float)
        ids = self._add_rows(index, weights, directions)
        self._selected = (ids, index, weights[:, :, None] * directions[:, None, :])

    def _dual(
        self, current: np.ndarray | None, targets: np.ndarray, combine
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The selected rows' dual system: distinct cached rows, each selected row's position among
        them, ``G Z + eps I`` on them and the residual ``targets - G current`` (duplicates of a row
        combined by ``combine``, a ufunc)."""
        if self._selected is None:
            raise RuntimeError("ContactProjector.solve called before set_rows")
        ids, index, coefficients = self._selected
        used, position = np.unique(ids, return_inverse=True)
        gtg_max = float(self._diagonal_of(used).max(initial=0.0))
        eps = self.regularization * gtg_max / self.weighted_max if gtg_max > 0 else 1.0
        reduced = dual_residual(targets, current, (index, coefficients), position, len(used), combine)
        matrix = self._schur[np.ix_(used, used)] + eps * np.eye(len(used))
        return used, position, matrix, reduced

    def _correction(self, used: np.ndarray, multipliers: np.ndarray) -> np.ndarray:
        """Collective: ``Z lambda`` as flat parametric nodal data on every rank."""
        self.projections += 1
        correction = PETSc.Vec().createMPI((self.n_local, self.n_global), comm=self.model.comm)
        try:
            if self._scalar_active:  # sum_r lambda_r d_r x W_s^-1 w_r, per component
                combined = np.zeros((self._scalar_z.shape[1], 3))
                columns = np.asarray(self._row_column)[used]
                np.add.at(combined, columns, multipliers[:, None] * np.asarray(self._row_direction)[used])
                correction.array[:] = (self._scalar_z @ combined).ravel()
            else:
                every = np.zeros(self._z.shape[1])  # (gathering Z's used columns would copy them)
                every[used] = multipliers
                correction.array[:] = self._z @ every
            return self.model.discretization.closed_to_entries(correction.array_r)
        finally:
            correction.destroy()

    def solve(self, current: np.ndarray | None, targets: np.ndarray) -> np.ndarray:
        """Collective: the correction ``d`` (flat parametric nodal ``(N, 3)``, on every rank) that
        brings the selected rows to ``targets`` (in the least-squares sense).

        Args:
            current: flat nodal data the rows are evaluated on; None: the targets are increments.
            targets: ``(r,)`` target values of the rows set by :meth:`set_rows`.
        """
        # a row selected twice holds one multiplier for the sum of its residuals: (c A + eps I)
        used, position, matrix, reduced = self._dual(current, targets, np.add)
        counts = np.bincount(position, minlength=len(used))
        matrix = matrix + (counts[:, None] - 1) * self._schur[np.ix_(used, used)]
        return self._correction(used, dual_solve(matrix, reduced, f"contact projection '{self.prefix}'"))

    def solve_pushing(self, current: np.ndarray | None, lower: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Collective: the correction ``d`` with ``rows . (current + d) >= lower`` whose impulses
        only push (a linear complementarity problem on the dual system, :func:`solve_lcp`).

        Returns:
            ``(d (N, 3) flat nodal, impulse (r,) of each selected row)``.
        """
        used, position, matrix, reduced = self._dual(current, lower, np.maximum)
        multipliers = dual_solve_pushing(matrix, reduced, f"contact projection '{self.prefix}'")
        return self._correction(used, multipliers), multipliers[position]

    # The pieces of the dual system a projector over several bodies sums (StackedProjector).

    def selected_ids(self) -> np.ndarray:
        """``(r,)`` cached row of each row selected by :meth:`set_rows`."""
        if self._selected is None:
            raise RuntimeError("ContactProjector.selected_ids called before set_rows")
        return self._selected[0]

    def schur_block(self, ids: np.ndarray) -> np.ndarray:
        """``G W^-1 G^T`` between the cached rows ``ids``, ``(len(ids), len(ids))``."""
        return self._schur[np.ix_(ids, ids)]

    def largest_gtg(self, ids: np.ndarray) -> float:
        """``max diag(G^T G)`` over this body's DOFs of the cached rows ``ids`` (distinct)."""
        return float(self._diagonal_of(ids).max(initial=0.0))

    def correction_of(self, ids: np.ndarray, multipliers: np.ndarray) -> np.ndarray:
        """Collective: ``sum_r multipliers[r] Z[:, ids[r]]`` as flat parametric nodal data ``(N, 3)``."""
        used, position = np.unique(ids, return_inverse=True)
        return self._correction(used, np.bincount(position, weights=multipliers, minlength=len(used)))

    def _diagonal_of(self, rows: np.ndarray) -> np.ndarray:
        """diag(G^T G) over the closed DOFs of the selected cached rows."""
        diagonal = np.zeros(self.n_global)
        for row in rows:
            closed, values, _, _ = self._row_closed[row]
            np.add.at(diagonal, closed, values**2)
        return diagonal

    def release(self) -> None:
        """Forget the selected rows (the per-step cache stays until the next :meth:`set_metric`)."""
        self._selected = None

    def close(self) -> None:
        """Destroy the PETSc objects (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self.release()
        for obj in (self.mass, self.smoothing, self.weighted, self.ksp, self.scalar_weighted, self.scalar_ksp):
            if obj is not None:
                obj.destroy()

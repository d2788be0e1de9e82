"""The Newton driver of the shell problem (PETSc SNES).

:class:`ShellSolver` owns a SNES (Newton + line search) whose linear solves are MUMPS direct
factorizations (LDL^T by default, LU when the Jacobian is not symmetric). Options live under the
solver's own prefix; defaults are pushed only where nothing is set yet, so the command line
(``-bhem_static_snes_rtol 1e-12``, ...) and a scene's ``options`` table override them.

On a surface with periodic directions the solver iterates on the closed DOFs ``x_c`` and
assembles on the open grid: ``F_c = P^T F(P x_c)``, ``J_c = P^T J P`` (PETSc ``PtAP``, whose
symbolic product is reused).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping
from dataclasses import dataclass, field

import dolfinx.fem as fem
import dolfinx.fem.petsc as fem_petsc
import numpy as np
from petsc4py import PETSc

from bhem_hpc.model.shell import ShellModel
from bhem_hpc.solver.petsc import KSP_REASONS, SNES_REASONS, PetscOwner, SolverError, push_options

log = logging.getLogger(__name__)


def default_options(model: ShellModel) -> dict[str, str]:
    """Solver defaults for a model (all overridable under the prefix)."""
    m = model.material
    grid = model.rest_surface.grid
    # Absolute residual floor: round-off of the internal force is ~eps * Y h * patch size.
    force_scale = m.young * m.thickness * max(grid.h1, grid.h2)
    return {
        "snes_type": "newtonls",
        # Conservative problems: full step damped by the energy precheck (ShellSolver.damp_step);
        # follower loads have no potential: backtracking on the residual norm.
        "snes_linesearch_type": "basic" if model.potential_form is not None else "bt",
        "snes_rtol": "1e-9",
        "snes_atol": f"{1e-13 * force_scale:.3e}",
        "snes_stol": "1e-14",
        "snes_max_it": "30",
        "ksp_type": "preonly",
        "pc_type": "cholesky" if model.symmetric else "lu",
        "pc_factor_mat_solver_type": "mumps",
        # Debian's MUMPS has no METIS: AMF (2) was the fastest of the built-in orderings here.
        "mat_mumps_icntl_7": "2",
    }


def _residual_callback(snes: PETSc.SNES, x: PETSc.Vec, f: PETSc.Vec, solver: ShellSolver) -> None:
    solver.update_state(x)
    solver.assemble_residual(x, f)


def _energy_precheck(x: PETSc.Vec, y: PETSc.Vec, solver: ShellSolver) -> None:
    solver.damp_step(x, y)


def _jacobian_callback(snes: PETSc.SNES, x: PETSc.Vec, jac: PETSc.Mat, pmat: PETSc.Mat, solver: ShellSolver) -> None:
    solver.assemble_jacobian(pmat)


@dataclass


class SolveReport:
    """What a solve did: per load step Newton iterations and timings."""

    load_steps: int = 0
    newton_iterations: list[int] = field(default_factory=list)
    residual_norms: list[float] = field(default_factory=list)
    negative_pivots: list[int] = field(default_factory=list)
    backtracks: int = 0
    cuts: int = 0
    regularized_retries: int = 0
    regularized_iterations: int = 0
    multiplier_updates: int = 0
    assemble_residual_s: float = 0.0
    assemble_jacobian_s: float = 0.0
    wall_s: float = 0.0


class ShellSolver(PetscOwner):
    """Newton solver for a :class:`ShellModel`: static equilibria (:meth:`solve`, with load stepping)
    and single time steps (:meth:`solve_step`, driven by :class:`~bhem_hpc.solver.dynamics.TimeStepper`).

    Args:
        model: the shell problem (forms, constraints, loads).
        prefix: PETSc options prefix of this solver.
        options: PETSc options (without prefix) that override the defaults, e.g. from a scene.
    """

    def __init__(self, model: ShellModel, prefix: str = "bhem_static_", options: Mapping[str, object] | None = None):
        self.model = model
        self.prefix = prefix
        self._closed = False
        disc = model.discretization
        comm = model.comm
        n_local, n_global = 3 * disc.num_owned_closed, 3 * disc.num_closed
        self.x = PETSc.Vec().createMPI((n_local, n_global), comm=comm)
        self.f = self.x.duplicate()
        self.f_open = fem_petsc.create_vector(model.residual_form)
        self.point_loads = self.f_open.duplicate()
        with self.point_loads.localForm() as local:
            local.array[:] = model.point_load_open
        self.point_loads.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        opts = PETSc.Options()
        pushed = push_options(prefix, default_options(model), options or {})
        try:  # the pushed defaults are removed again whatever happens
            ldlt = opts.getString(prefix + "pc_type", "") == "cholesky"
            mumps = opts.getString(prefix + "pc_factor_mat_solver_type", "") == "mumps"
            # Element matrices go into 3x3-block storage (insertion ~5x cheaper than AIJ). MUMPS' LDL^T
            # takes symmetric-block SBAIJ directly, but MPISBAIJ cannot zero constrained rows and
            # columns and PtAP needs AIJ: there the blocked matrix is converted to AIJ (output reused).
            serial_sbaij = ldlt and mumps and model.symmetric and comm.size == 1 and not disc.is_periodic
            self.matrix_format = "sbaij" if serial_sbaij else "aij"
            self.jacobian_blocked: PETSc.Mat | None = fem_petsc.create_matrix(model.jacobian_form, "baij")
            fem_petsc.assemble_matrix(self.jacobian_blocked, model.jacobian_form)
            self.jacobian_blocked.assemble()
            self.jacobian_open = PETSc.Mat()
            self.jacobian_blocked.convert(self.matrix_format, self.jacobian_open)
            if serial_sbaij:
                self.jacobian_open.setOption(PETSc.Mat.Option.IGNORE_LOWER_TRIANGULAR, True)
                self.jacobian_blocked.destroy()
                self.jacobian_blocked = None
            self.prolongation: PETSc.Mat | None = None
            if disc.is_periodic:
                cols = disc.prolongation_columns().astype(PETSc.IntType)
                rows = cols.size
                indptr = np.arange(rows + 1, dtype=PETSc.IntType)
                self.prolongation = PETSc.Mat().createAIJ(
                    ((rows, 3 * disc.function_space.dofmap.index_map.size_global), (n_local, n_global)),
                    csr=(indptr, cols, np.ones(rows)),
                    comm=comm,
                )
                self.jacobian = self.jacobian_open.PtAP(self.prolongation)
            else:
                self.jacobian = self.jacobian_open
            self.jacobian.setOption(PETSc.Mat.Option.SYMMETRIC, model.symmetric)
            self.bc_local = model.constrained.local.astype(np.int64)
            self.bc_rows = model.constrained.rows.astype(PETSc.IntType)
            self.bc_values = model.constrained_initial.copy()
            self.report = SolveReport()
            self.regularization = 0.0
            self._init_point_constraints()

            PETSc.Log.begin()  # event timers for linear_solver_seconds (idempotent, cheap)
            self.snes = PETSc.SNES().create(comm)
            self.snes.setOptionsPrefix(prefix)
            self.snes.setFunction(_residual_callback, self.f, kargs={"solver": self})
            self.snes.setJacobian(_jacobian_callback, self.jacobian, self.jacobian, kargs={"solver": self})
            self._trial: PETSc.Vec | None = None  # the energy line search's trial state
            if model.potential_form is not None:
                self._trial = self.x.duplicate()
                self.snes.setLineSearchPreCheck(_energy_precheck, kargs={"solver": self})
            self.snes.setFromOptions()
        finally:
            for name in pushed:
                opts.delValue(name)

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
        lo, hi = (
            model.rest_surface.nodal[..., 0, :].min(axis=(0, 1)),
            model.rest_surface.nodal[..., 0, :].max(axis=(0, 1)),
        )
        self.alm_tolerance = 1e-10 * float(np.linalg.norm(hi - lo))

    # -- assembly --------------------------------------------------------------------------------
    def update_state(self, x: PETSc.Vec) -> None:
        """Write closed DOFs ``x`` into the model's position Function (with ghosts)."""
        target = self.model.x.vector
        if self.prolongation is not None:
            self.prolongation.mult(x, target)
        else:
            x.copy(target)
        target.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)

    def state_to_vector(self, x: PETSc.Vec) -> None:
        """Copy the model's current position into closed DOFs ``x``."""
        x.array[:] = self.model.discretization.open_to_closed(self.model.x.x.array)

    def assemble_residual(self, x: PETSc.Vec, f: PETSc.Vec) -> None:
        """``f = P^T (F_int - F_ext)`` with constrained rows replaced by ``x - x_bc``."""
        t0 = time.perf_counter()
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

    def point_constraint_violation(self) -> np.ndarray:
        """``x(xi_p) - target`` of every point constraint (constrained components), collective.

        Returns:
            Array of shape ``(points, 3)``; unconstrained components are 0.
        """
        local = np.zeros_like(self.alm_multipliers)
        positions = self.model.x.x.array.reshape(-1, 3)
        for k, (blocks, values) in enumerate(self.model.point_constraint_basis):
            if len(blocks):
                local[k] = values @ positions[blocks]
        return (self.model.comm.allreduce(local) - self.alm_targets) * self.alm_mask

    def _solve_constrained(self, max_updates: int = 30) -> bool:
        """SNES solve, wrapped in augmented-Lagrangian multiplier updates when points are held."""
        for _ in range(max_updates):
            self.snes.solve(None, self.x)
            if not self._converged() or not len(self.alm_multipliers):
                return self._converged()
            self.update_state(self.x)
            violation = self.point_constraint_violation()
            if np.abs(violation).max() <= self.alm_tolerance:
                return True
            self.alm_multipliers += self.alm_penalty * violation
            self.report.multiplier_updates += 1
        log.warning("%s: augmented Lagrangian not converged after %d multiplier updates", self.prefix, max_updates)
        return False

    def potential_energy(self) -> float:
        """Total potential at the model's current state (internal - external work), collective."""
        local = fem.assemble_scalar(self.model.potential_form)
        local -= float(self.model.load_factor.value) * float(
            np.dot(self.point_loads.array_r, self.model.x.vector.array_r)
        )
        if len(self.alm_multipliers):
            c = self.point_constraint_violation()
            alm = float(np.sum(self.alm_multipliers * c) + 0.5 * self.alm_penalty * np.sum(c * c))
            local += alm if self.model.comm.rank == 0 else 0.0
        return self.model.comm.allreduce(local)

    def damp_step(self, x: PETSc.Vec, y: PETSc.Vec, max_backtracks: int = 30) -> None:
        """Scale the Newton step ``x -> x - y`` so that the total potential decreases.

        Backtracking with safeguarded quadratic interpolation on the potential (Armijo constant
        1e-4). Once the predicted decrease ``F.y`` is below the round-off of the potential
        itself, the energy cannot judge a step and the full Newton step is taken (the local,
        quadratically convergent regime).
        """
        self.update_state(x)
        energy0 = self.potential_energy()
        slope = -self.f.dot(y)  # d/dlambda of the potential along x - lambda y, at lambda = 0
        resolution = 1e-12 * abs(energy0)
        if self.negative_pivots() > 0 or slope > 0:
            slope = self._regularized_direction(y)
        if abs(slope) <= 1e3 * resolution:
            return
        step = 1.0
        for _ in range(max_backtracks):
            self._trial.waxpy(-step, y, x)
            self.update_state(self._trial)
            energy = self.potential_energy()
            if np.isfinite(energy) and energy <= energy0 + 1e-4 * step * slope + resolution:
                break
            curvature = energy - energy0 - slope * step
            guess = -slope * step**2 / (2 * curvature) if np.isfinite(energy) and curvature > 0 else 0.1 * step
            step = min(0.5 * step, max(0.1 * step, guess))
        else:
            # No decrease found: take no step rather than accept an energy increase; Newton then
            # stalls and the caller's recovery (regularized retry, smaller increment) takes over.
            log.warning("%s: energy backtracking found no decrease in %d steps", self.prefix, max_backtracks)
            step = 0.0
        self.report.backtracks += int(step < 1.0)
        if step < 1.0:
            y.scale(step)

    def _regularized_direction(self, y: PETSc.Vec, factors: tuple[float, ...] = (1e-6, 1e-4, 1e-2, 1.0)) -> float:
        """Re-solve for ``y`` with ``J + r |diag J|``, raising ``r`` until LDL^T shows no negative
        pivots (the paper's diagonal regularizer, applied within the Newton iteration).

        Returns:
            The new slope ``-F.y`` (negative once the matrix is positive definite).
        """
        ksp = self.snes.getKSP()
        magnitude = self.jacobian.getDiagonal()
        magnitude.abs()
        applied = 0.0
        for factor in factors:
            increment = magnitude.copy()
            increment.scale(factor - applied)
            self.jacobian.setDiagonal(increment, addv=PETSc.InsertMode.ADD)
            increment.destroy()
            applied = factor
            ksp.setOperators(self.jacobian)
            ksp.solve(self.f, y)
            if self.negative_pivots() <= 0:
                break
        magnitude.destroy()
        self.report.regularized_iterations += 1
        log.info("%s: indefinite Jacobian regularized with r = %.0e", self.prefix, applied)
        return -self.f.dot(y)

    def _assemble_open_jacobian(self) -> None:
        target = self.jacobian_open if self.jacobian_blocked is None else self.jacobian_blocked
        target.zeroEntries()
        fem_petsc.assemble_matrix(target, self.model.jacobian_form)
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

    # -- solves ---------------------------------------------------------------------------------
    def solve(self, load_steps: int = 1, max_cuts: int = 10) -> SolveReport:
        """Solve for equilibrium, ramping loads and prescribed values from 0 to 1.

        The load factor advances in increments of at most ``1 / load_steps``; a load step whose
        Newton solve fails is retried from the last equilibrium with half the increment (at most
        ``max_cuts`` halvings in a row), and the increment grows back after successes. Each step
        starts from a secant prediction along the last two equilibria.

        Raises:
            SolverError: naming the solver, the load factor and the SNES/KSP reasons.
        """
        if isinstance(load_steps, bool) or not isinstance(load_steps, int) or load_steps < 1:
            raise SolverError(f"solver '{self.prefix}': load_steps must be an integer >= 1, got {load_steps!r}")
        model = self.model
        start = time.perf_counter()
        max_increment = 1.0 / load_steps
        increment = max_increment
        self.state_to_vector(self.x)
        accepted = self.x.copy()
        history: list[tuple[float, PETSc.Vec]] = []
        factor, cuts = 0.0, 0
        while factor < 1.0 - 1e-12:
            trial = min(1.0, factor + increment)
            accepted.copy(self.x)
            if history:
                # Secant predictor: continue the path of the last two equilibria (captures the
                # in-plane pull-in that a Newton step linearized at the last state misses).
                last_factor, last = history[-1]
                self.x.axpy((trial - factor) / (factor - last_factor), accepted - last)
            model.load_factor.value = trial
            self.bc_values = model.constrained_initial + trial * (model.constrained_target - model.constrained_initial)
            self.set_point_targets(trial, ramp=True)
            if len(self.bc_local):
                self.x.array[self.bc_local] = self.bc_values
            if not self._solve_constrained():
                cuts += 1
                self.report.cuts += 1
                if cuts > max_cuts:
                    self._raise(trial, f"{max_cuts} halvings of the load increment")
                log.warning(
                    "%s: Newton failed at load factor %.4g (%s); halving the increment to %.3g",
                    self.prefix,
                    trial,
                    SNES_REASONS.get(self.snes.getConvergedReason()),
                    increment / 2,
                )
                increment /= 2
                continue
            cuts = 0
            its = self.snes.getIterationNumber()
            self.report.newton_iterations.append(its)
            self.report.residual_norms.append(self.snes.getFunctionNorm())
            self.report.negative_pivots.append(self.negative_pivots())
            self.report.load_steps += 1
            log.info(
                "%s: load factor %.4g: %d Newton iterations, |F| = %.3e",
                self.prefix,
                trial,
                its,
                self.snes.getFunctionNorm(),
            )
            if history:
                history[0][1].destroy()
            history = [(factor, accepted)]
            accepted = self.x.copy()
            factor = trial
            increment = min(max_increment, 2 * increment)
        for _, vec in history:
            vec.destroy()
        accepted.destroy()
        self.update_state(self.x)
        self.report.wall_s += time.perf_counter() - start
        return self.report

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

    def solve_step(
        self, bc_values: np.ndarray | None = None, regularizations: tuple[float, ...] = (1e-6, 1e-4, 1e-2)
    ) -> int:
        """One nonlinear solve at load factor 1 from the model's current state (a time step).

        Args:
            bc_values: reference-DOF values of the constrained DOFs (``model.constrained``);
                default: the model's targets.
            regularizations: relative diagonal regularizers ``r`` (``J + r |diag J|``) tried in turn
                when Newton fails (the line search stalls or the iteration limit is hit).

        Returns:
            Newton iterations of the successful attempt.

        Raises:
            SolverError: when every attempt failed; the state is left at the last attempt.
        """
        model = self.model
        model.load_factor.value = 1.0
        self.bc_values = model.constrained_target.copy() if bc_values is None else np.asarray(bc_values, float)
        self.state_to_vector(self.x)
        start = self.x.copy()
        try:
            for attempt, regularization in enumerate((0.0, *regularizations)):
                self.regularization = regularization
                start.copy(self.x)
                if len(self.bc_local):
                    self.x.array[self.bc_local] = self.bc_values
                converged = self._solve_constrained()
                pivots = self.negative_pivots()
                if converged:
                    # A converged step whose last LDL^T showed negative pivots is a stationary point
                    # of an indefinite incremental potential: recorded, not retried (a regularized
                    # retry converges to the same point).
                    self.update_state(self.x)
                    its = self.snes.getIterationNumber()
                    self.report.newton_iterations.append(its)
                    self.report.negative_pivots.append(pivots)
                    return its
                if attempt == len(regularizations):
                    break
                self.report.regularized_retries += 1
                log.warning(
                    "%s: attempt %d failed (%s, %d negative pivots); retrying with diagonal regularizer %.0e",
                    self.prefix,
                    attempt,
                    SNES_REASONS.get(self.snes.getConvergedReason()),
                    pivots,
                    regularizations[attempt],
                )
            self._raise(1.0, f"{len(regularizations)} regularized retries")
        finally:
            self.regularization = 0.0
            start.destroy()
        return -1  # unreachable: _raise always raises

    def _converged(self) -> bool:
        return self.snes.getConvergedReason() > 0 and bool(np.isfinite(self.snes.getFunctionNorm()))

    def _raise(self, factor: float, after: str) -> None:
        reason = self.snes.getConvergedReason()
        ksp_reason = self.snes.getKSP().getConvergedReason()
        mumps = ""
        factor_matrix = self._factor_matrix()
        if factor_matrix is not None:
            mumps = f", MUMPS INFOG(1) = {factor_matrix.getMumpsInfog(1)}"
        raise SolverError(
            f"SNES solver '{self.prefix}' failed at load factor {factor:.4g} after {after}: "
            f"{SNES_REASONS.get(reason, reason)} after {self.snes.getIterationNumber()} Newton iterations, "
            f"|F| = {self.snes.getFunctionNorm():.3e}; last linear solve: KSP "
            f"{KSP_REASONS.get(ksp_reason, ksp_reason)}{mumps}"
        )

    def _factor_matrix(self) -> PETSc.Mat | None:
        pc = self.snes.getKSP().getPC()
        if pc.getType() not in ("cholesky", "lu") or pc.getFactorSolverType() != "mumps":
            return None
        try:
            return pc.getFactorMatrix()
        except PETSc.Error:
            return None

    def negative_pivots(self) -> int:
        """Negative pivots of the last LDL^T factorization (MUMPS INFOG(12)); -1 if unknown."""
        factor_matrix = self._factor_matrix()
        if factor_matrix is None or self.snes.getKSP().getPC().getType() != "cholesky":
            return -1
        return int(factor_matrix.getMumpsInfog(12))

    def time_newton_iteration(self) -> dict[str, float]:
        """One Newton iteration at the current state, phase by phase (for benchmarks).

        Assembles the residual and the Jacobian, factorizes (numeric factorization; the symbolic
        analysis is reused once done) and solves, without updating the state.

        Returns:
            Seconds per phase (``assemble_residual_s``, ``assemble_jacobian_s``, ``factor_s``,
            ``solve_s``, ``newton_iteration_s``) and ``factor_gflop`` (MUMPS RINFOG(3)).
        """
        comm = self.model.comm
        ksp = self.snes.getKSP()
        pc = ksp.getPC()
        step = self.x.duplicate()
        self.state_to_vector(self.x)

        def timed(action) -> float:
            comm.Barrier()
            t0 = time.perf_counter()
            action()
            comm.Barrier()
            return time.perf_counter() - t0

        def residual() -> None:
            self.update_state(self.x)
            self.assemble_residual(self.x, self.f)

        times = {
            "assemble_residual_s": timed(residual),
            "assemble_jacobian_s": timed(lambda: self.assemble_jacobian(self.jacobian)),
        }
        ksp.setOperators(self.jacobian)
        times["factor_s"] = timed(pc.setUp)
        times["solve_s"] = timed(lambda: ksp.solve(self.f, step))
        times["newton_iteration_s"] = sum(times.values())
        factor_matrix = self._factor_matrix()
        times["factor_gflop"] = factor_matrix.getMumpsRinfog(3) / 1e9 if factor_matrix is not None else float("nan")
        times["negative_pivots"] = self.negative_pivots()
        step.destroy()
        return times

    @staticmethod
    def linear_solver_seconds() -> tuple[float, float]:
        """Cumulative ``(factorization, triangular solves)`` seconds of this process (PETSc log)."""

        def seconds(*events: str) -> float:
            return sum(PETSc.Log.Event(name).getPerfInfo()["time"] for name in events)

        factor = seconds("MatCholFctrSym", "MatCholFctrNum", "MatLUFactorSym", "MatLUFactorNum")
        return factor, seconds("MatSolve")

    def matrix_nonzeros(self) -> int:
        """Nonzeros of the (closed) Jacobian as a full matrix (SBAIJ stores the upper triangle)."""
        stored = int(self.jacobian.getInfo(PETSc.Mat.InfoType.GLOBAL_SUM)["nz_used"])
        if self.jacobian.getType().endswith("sbaij"):
            bs = self.jacobian.getBlockSize()
            diagonal_blocks = self.jacobian.getSize()[0] // bs
            return 2 * stored - bs * bs * diagonal_blocks
        return stored

    # -- lifetime -------------------------------------------------------------------------------
    def close(self) -> None:
        """Destroy the PETSc objects this solver owns (idempotent)."""
        if self._closed:
            return
        self._closed = True
        objects = [
            self.snes,
            self.x,
            self.f,
            self.f_open,
            self.point_loads,
            self.jacobian_open,
        ]
        if self.jacobian_blocked is not None:
            objects.append(self.jacobian_blocked)
        if self._trial is not None:
            objects.append(self._trial)
        if self.prolongation is not None:
            objects += [self.prolongation, self.jacobian]
        for obj in objects:
            obj.destroy()

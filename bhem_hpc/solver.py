"""PETSc solvers for the shell problem. All petsc4py code of the project lives in this module.

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
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from bhem_hpc import forms
from bhem_hpc.shell import ShellModel, default_jit_params

log = logging.getLogger(__name__)

SNES_REASONS = {v: k for k, v in vars(PETSc.SNES.ConvergedReason).items() if k.isupper()}
KSP_REASONS = {v: k for k, v in vars(PETSc.KSP.ConvergedReason).items() if k.isupper()}


class SolverError(RuntimeError):
    """A nonlinear or linear solve failed; the message names the solver and the reasons."""


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


def _push_options(prefix: str, defaults: Mapping[str, str], overrides: Mapping[str, object]) -> list[str]:
    """Set ``overrides`` then ``defaults`` under ``prefix`` where the database has no value.

    Returns the names pushed, so the caller can remove them after ``setFromOptions`` and leave
    the database as the user made it.
    """
    opts = PETSc.Options()
    pushed = []
    for source in (overrides, defaults):
        for key, value in source.items():
            name = prefix + key.lstrip("-")
            if not opts.hasName(name):
                opts[name] = "" if value is None else str(value)
                pushed.append(name)
    return pushed


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


class _PetscOwner:
    """Owns PETSc objects: an explicit ``close()`` (idempotent), a context manager, a guarded ``__del__``."""

    def close(self) -> None:  # pragma: no cover - every subclass defines it
        raise NotImplementedError

    def __enter__(self):
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown may have torn PETSc down already
            pass


class ShellSolver(_PetscOwner):
    """Newton solver for a :class:`ShellModel`: static equilibria (:meth:`solve`, with load stepping)
    and single time steps (:meth:`solve_step`, driven by :class:`~bhem_hpc.dynamics.TimeStepper`).

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
        pushed = _push_options(prefix, default_options(model), options or {})
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
                blocks = disc.open_blocks
                rows = 3 * blocks.size
                cols = (3 * disc.closed_of_open[blocks][:, None] + np.arange(3)).ravel().astype(PETSc.IntType)
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
            # Augmented Lagrangian for point constraints: multipliers, penalty, targets, masks.
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

            PETSc.Log.begin()  # event timers for linear_solver_seconds (idempotent, cheap)
            self.snes = PETSc.SNES().create(comm)
            self.snes.setOptionsPrefix(prefix)
            self.snes.setFunction(_residual_callback, self.f, kargs={"solver": self})
            self.snes.setJacobian(_jacobian_callback, self.jacobian, self.jacobian, kargs={"solver": self})
            if model.potential_form is not None:
                self._trial = self.x.duplicate()
                self.snes.setLineSearchPreCheck(_energy_precheck, kargs={"solver": self})
            self.snes.setFromOptions()
        finally:
            for name in pushed:
                opts.delValue(name)

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
        disc = self.model.discretization
        x.array[:] = self.model.x.x.array.reshape(-1, 3)[disc.owned_closed_open_block].ravel()

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
        if hasattr(self, "_trial"):
            objects.append(self._trial)
        if self.prolongation is not None:
            objects += [self.prolongation, self.jacobian]
        for obj in objects:
            obj.destroy()


class ContactProjector(_PetscOwner):
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
        solver: the model's solver (its constrained rows and seam prolongation are reused).
        prefix: PETSc options prefix of the metric's KSP.
        options: PETSc options (without prefix) overriding the defaults.
        regularization: ``eps`` relative to ``max diag(G^T G) / max diag(W)``.
        smoothing: weight of the second-derivative term of the impulse metric
            (:func:`forms.impulse_metric`; 0 = the bare mass matrix).
    """

    def __init__(
        self,
        solver: ShellSolver,
        prefix: str = "bhem_contact_",
        options: Mapping[str, object] | None = None,
        regularization: float = 1e-8,
        smoothing: float = 1.0,
    ):
        model = solver.model
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
            form = fem.form(
                forms.impulse_metric(
                    ufl.TrialFunction(space), ufl.TestFunction(space), model.x_rest, model.density, model.thickness,
                    (grid.h1, grid.h2), mass_weight, smoothing_weight, model.dx,
                ),
                jit_params=default_jit_params(),
            )  # fmt: skip
            matrix = fem_petsc.assemble_matrix(form)
            matrix.assemble()
            if solver.prolongation is None:
                return matrix
            closed = matrix.PtAP(solver.prolongation)
            matrix.destroy()
            return closed

        self.mass = assemble(1.0, smoothing)  # M + S: the metric without a Jacobian
        self.smoothing = assemble(0.0, smoothing)  # S alone, added to dt^2 J
        self.bc_rows = solver.bc_rows
        self.bc_local = solver.bc_local
        # Flat nodal entry (distinct node, kind) -> global closed block and reference-DOF scale.
        m1, m2 = model.rest_surface.grid.node_shape
        blocks = disc.owned_closed_open_block
        node = disc.distinct_node[blocks]
        key = (node[:, 0] * m2 + node[:, 1]) * 4 + disc.block_kind[blocks]
        self.owned_flat = key
        self.flat_block = np.full(m1 * m2 * 4, -1, dtype=np.int64)
        self._constrained_global = np.zeros(3 * disc.num_closed, dtype=bool)
        for rows in comm.allgather(np.asarray(solver.bc_rows, dtype=np.int64)):
            self._constrained_global[rows] = True
        # Sparse right-hand sides serially only: PETSc 3.18's parallel path stops with MUMPS
        # INFOG(1) = -27 (the sparse RHS pointers do not match); in parallel G^T goes dense.
        self.sparse_rhs = comm.size == 1
        self.flat_scale = np.zeros(m1 * m2 * 4)
        for keys, first, scales in comm.allgather((key, disc.closed_offset, disc.block_scale[blocks])):
            self.flat_block[keys] = first + np.arange(len(keys))
            self.flat_scale[keys] = scales
        self.n_local, self.n_global = 3 * disc.num_owned_closed, 3 * disc.num_closed
        self.first_owned = 3 * disc.closed_offset
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

    def _to_closed(self, flat: np.ndarray) -> PETSc.Vec:
        """Owned closed vector of flat parametric nodal data ``(N, 3)`` (known on every rank)."""
        vec = PETSc.Vec().createMPI((self.n_local, self.n_global), comm=self.model.comm)
        vec.array[:] = (flat[self.owned_flat] * self.flat_scale[self.owned_flat, None]).ravel()
        return vec

    def _to_flat(self, vec: PETSc.Vec) -> np.ndarray:
        """Collective: flat parametric nodal data ``(N, 3)`` of a closed vector, on every rank."""
        out = np.zeros((len(self.flat_block), 3))
        local = (self.owned_flat, vec.array_r.reshape(-1, 3).copy())
        for keys, values in self.model.comm.allgather(local):
            out[keys] = values / self.flat_scale[keys, None]
        return out

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
        pushed = _push_options(self.prefix, self.options, self.option_overrides)
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
        status = self._mumps_status(ksp)
        if status is not None and status < 0:  # not MUMPS (options overridden): errors surface in the solves
            raise SolverError(f"contact metric '{self.prefix}' could not be factored: {self._mumps_info(ksp)}")

    @staticmethod
    def _mumps_status(ksp: PETSc.KSP | None) -> int | None:
        """MUMPS INFOG(1) of a factorization (None if there is none or it is not MUMPS')."""
        try:
            return int(ksp.getPC().getFactorMatrix().getMumpsInfog(1))
        except (PETSc.Error, AttributeError):
            return None

    def _mumps_info(self, ksp: PETSc.KSP | None = None) -> str:
        status = self._mumps_status(ksp or (self.scalar_ksp if self._scalar_active else self.ksp))
        return "no MUMPS information" if status is None else f"MUMPS INFOG(1) = {status}"

    def _closed_rows(self, index: np.ndarray, coefficients: np.ndarray) -> tuple[np.ndarray, ...]:
        """Row ``(K,)`` entries / ``(K, 3)`` coefficients -> global closed indices and values (the
        absent second point of a collider contact has zero weights and is dropped), then the
        positions among this rank's owned closed DOFs and values of the owned ones."""
        closed = 3 * self.flat_block[index][:, None] + np.arange(3)
        values = coefficients / self.flat_scale[index][:, None]
        nonzero = values != 0.0
        closed, values = closed[nonzero], values[nonzero]
        owned = (closed >= self.first_owned) & (closed < self.first_owned + self.n_local)
        return closed, values, closed[owned] - self.first_owned, values[owned]

    def _right_hand_sides(self, columns: list[tuple[np.ndarray, np.ndarray]], scalar: bool = False) -> PETSc.Mat:
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
        if not self.sparse_rhs:
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
            rhs = self._right_hand_sides(
                [(self.flat_block[index[r]], weights[r] / self.flat_scale[index[r]]) for r in fresh], scalar=True
            )
            solved = self._solve_columns(self.scalar_ksp, rhs, f"{len(fresh)} new contact points")
            self._scalar_z = np.hstack([self._scalar_z, solved])
        self._scalar_used.update(columns.tolist())
        return columns

    def _scalar_gz(self, index: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """Collective: ``w_a . W_s^-1 w`` of the points ``(index (r, K), weights (r, K))`` against
        every column of ``_scalar_z``, ``(r, columns)``."""
        first, count = self.first_owned // 3, self.n_local // 3
        products = np.zeros((len(index), self._scalar_z.shape[1]))
        for r in range(len(index)):
            blocks, values = self.flat_block[index[r]] - first, weights[r] / self.flat_scale[index[r]]
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
            rhs = self._right_hand_sides([self._row_closed[row][:2] for row in new])
            self._z = np.hstack([self._z, self._solve_columns(self.ksp, rhs, f"{len(new)} new contact rows")])
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
        residual = np.asarray(targets, dtype=float).copy()
        if current is not None:
            residual -= np.einsum("rkc,rkc->r", coefficients, current[index])
        used, position = np.unique(ids, return_inverse=True)
        gtg_max = float(self._diagonal_of(used).max(initial=0.0))
        eps = self.regularization * gtg_max / self.weighted_max if gtg_max > 0 else 1.0
        reduced = np.full(len(used), -np.inf) if combine is np.maximum else np.zeros(len(used))
        combine.at(reduced, position, residual)
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
            return self._to_flat(correction)
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
        try:
            multipliers = np.linalg.solve(matrix, reduced)
            # one step of iterative refinement: the dual matrix is as ill-conditioned as eps is small
            multipliers += np.linalg.solve(matrix, reduced - matrix @ multipliers)
        except np.linalg.LinAlgError as error:
            raise SolverError(
                f"contact projection '{self.prefix}' failed: singular dual system of {len(used)} contact rows"
            ) from error
        return self._correction(used, multipliers)

    def solve_pushing(self, current: np.ndarray | None, lower: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Collective: the correction ``d`` with ``rows . (current + d) >= lower`` whose impulses
        only push (a linear complementarity problem on the dual system, :func:`solve_lcp`).

        Returns:
            ``(d (N, 3) flat nodal, impulse (r,) of each selected row)``.
        """
        from bhem_hpc.collision.lcp import ComplementarityError, solve_lcp  # contact scenes only

        used, position, matrix, reduced = self._dual(current, lower, np.maximum)
        try:
            multipliers, _ = solve_lcp(matrix, reduced)
        except (ComplementarityError, np.linalg.LinAlgError) as error:
            raise SolverError(f"contact projection '{self.prefix}' failed: {error}") from error
        impulse = multipliers[position]
        return self._correction(used, multipliers), impulse

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

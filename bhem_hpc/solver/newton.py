"""The Newton driver of the shell problem (PETSc SNES), apart from the problem (:mod:`.problem`).

:class:`ShellSolver` owns a SNES (Newton + line search) whose linear solves are MUMPS direct
factorizations (LDL^T by default, LU when the Jacobian is not symmetric). Options live under the
solver's own prefix; defaults are pushed only where nothing is set yet, so the command line
(``-bhem_static_snes_rtol 1e-12``, ...) and a scene's ``options`` table override them. The
driver adds load stepping with secant predictors and increment cuts, the energy line search, the
diagonal regularization of indefinite Jacobians and the augmented-Lagrangian multiplier updates.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from petsc4py import PETSc

from bhem_hpc.model.shell import ShellModel
from bhem_hpc.solver.petsc import (
    KSP_REASONS,
    PETSC_ERRORS,
    SNES_REASONS,
    PetscOwner,
    SolverError,
    SolverSetupError,
    negative_pivots,
    push_options,
    solve_stopped,
    unused_options,
)
from bhem_hpc.solver.problem import ShellProblem

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
    solver.problem.update_state(x)
    solver.problem.assemble_residual(x, f)


def _energy_precheck(x: PETSc.Vec, y: PETSc.Vec, solver: ShellSolver) -> None:
    solver.damp_step(x, y)


def _jacobian_callback(snes: PETSc.SNES, x: PETSc.Vec, jac: PETSc.Mat, pmat: PETSc.Mat, solver: ShellSolver) -> None:
    solver.problem.assemble_jacobian(pmat)


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
        #: ``load factor -> values of the constrained DOFs`` (``model.constrained``) for static load
        #: steps, e.g. prescribed motions whose time is the load factor (rotations turn vectors); None:
        #: straight from the initial values to the targets.
        self.prescribed = None
        disc = model.discretization
        comm = model.comm
        n_local, n_global = 3 * disc.num_owned_closed, 3 * disc.num_closed
        self.x = PETSc.Vec().createMPI((n_local, n_global), comm=comm)
        self.f = self.x.duplicate()
        opts = PETSc.Options()
        # the caller's options stay in the database for the solver's life (some are read only at
        # the first factorization) and are removed by close(); the defaults only for setup
        self._overrides = push_options(prefix, {}, options or {})
        pushed = push_options(prefix, default_options(model), {})
        try:  # the pushed defaults are removed again whatever happens
            ldlt = opts.getString(prefix + "pc_type", "") == "cholesky"
            mumps = opts.getString(prefix + "pc_factor_mat_solver_type", "") == "mumps"
            # MUMPS' LDL^T takes SBAIJ (one triangle) serially; seams (PtAP) and MPI need AIJ.
            serial_sbaij = ldlt and mumps and model.symmetric and comm.size == 1 and disc.closed_is_open
            self.matrix_format = "sbaij" if serial_sbaij else "aij"
            self.report = SolveReport()
            self.problem = ShellProblem(model, self.matrix_format, self.report)
            self.jacobian = self.problem.jacobian
            self.bc_rows = self.problem.bc_rows
            self.prolongation = self.problem.prolongation

            PETSc.Log.begin()  # event timers for linear_solver_seconds (idempotent, cheap)
            self.snes = PETSc.SNES().create(comm)
            self.snes.setOptionsPrefix(prefix)
            self.snes.setFunction(_residual_callback, self.f, kargs={"solver": self})
            self.snes.setJacobian(_jacobian_callback, self.jacobian, self.jacobian, kargs={"solver": self})
            self._trial: PETSc.Vec | None = None  # the energy line search's trial state
            if model.potential_form is not None:
                self._trial = self.x.duplicate()
                self.snes.setLineSearchPreCheck(_energy_precheck, kargs={"solver": self})
            try:
                self.snes.setFromOptions()
            except PETSc.Error as exc:
                given = {k: v for k, v in opts.getAll().items() if k.startswith(prefix)}
                self.close()
                raise SolverSetupError(
                    f"SNES solver '{prefix}': PETSc rejected its options (error code {exc.ierr}: "
                    f"{PETSC_ERRORS.get(exc.ierr, 'see the PETSc message above')}); options under the "
                    f"prefix: {dict(sorted(given.items()))}"
                ) from None
        finally:
            for name in pushed:
                opts.delValue(name)

    # -- assembly --------------------------------------------------------------------------------
    def _solve_constrained(self, max_updates: int = 30) -> bool:
        """SNES solve, wrapped in augmented-Lagrangian multiplier updates when points are held."""
        for _ in range(max_updates):
            try:
                self.snes.solve(None, self.x)
            except PETSc.Error as exc:  # not a divergence: PETSc refused to go on (e.g. a bad option)
                raise solve_stopped(self.prefix, exc) from None
            if not self._converged() or not len(self.problem.alm_multipliers):
                return self._converged()
            self.problem.update_state(self.x)
            if self.problem.update_multipliers():
                return True
        log.info("%s: augmented Lagrangian not converged after %d multiplier updates", self.prefix, max_updates)
        return False

    def damp_step(self, x: PETSc.Vec, y: PETSc.Vec, max_backtracks: int = 30) -> None:
        """Scale the Newton step ``x -> x - y`` so that the total potential decreases.

        Backtracking with safeguarded quadratic interpolation on the potential (Armijo constant
        1e-4). Once the predicted decrease ``F.y`` is below the round-off of the potential
        itself, the energy cannot judge a step and the full Newton step is taken (the local,
        quadratically convergent regime).
        """
        self.problem.update_state(x)
        energy0 = self.problem.potential_energy()
        slope = -self.f.dot(y)  # d/dlambda of the potential along x - lambda y, at lambda = 0
        resolution = 1e-12 * abs(energy0)
        if self.negative_pivots() > 0 or slope > 0:
            slope = self._regularized_direction(y)
        if abs(slope) <= 1e3 * resolution:
            return
        step = 1.0
        for _ in range(max_backtracks):
            self._trial.waxpy(-step, y, x)
            self.problem.update_state(self._trial)
            energy = self.problem.potential_energy()
            if np.isfinite(energy) and energy <= energy0 + 1e-4 * step * slope + resolution:
                break
            curvature = energy - energy0 - slope * step
            guess = -slope * step**2 / (2 * curvature) if np.isfinite(energy) and curvature > 0 else 0.1 * step
            step = min(0.5 * step, max(0.1 * step, guess))
        else:
            # No decrease found: take no step rather than accept an energy increase; Newton then
            # stalls and the caller's recovery (regularized retry, smaller increment) takes over.
            log.info("%s: energy backtracking found no decrease in %d steps", self.prefix, max_backtracks)
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
        start = time.perf_counter()
        max_increment = 1.0 / load_steps
        increment = max_increment
        self.problem.state_to_vector(self.x)
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
            if not self.solve_at(trial):
                cuts += 1
                self.report.cuts += 1
                if cuts > max_cuts:
                    self._raise(trial, f"{max_cuts} halvings of the load increment")
                log.info(
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
        self.problem.update_state(self.x)
        self.report.wall_s += time.perf_counter() - start
        return self.report

    def solve_at(self, load_factor: float) -> bool:
        """One Newton solve (SNES) at ``load_factor`` from the current iterate ``self.x``: loads scaled
        to it, prescribed values from :attr:`prescribed` (or interpolated linearly from the initial
        values to the targets). Returns whether it converged (``self.x`` holds the result)."""
        model = self.model
        model.load_factor.value = load_factor
        if self.prescribed is not None:
            self.problem.bc_values = np.asarray(self.prescribed(load_factor), dtype=float)
        else:
            initial, target = model.constrained_initial, model.constrained_target
            self.problem.bc_values = initial + load_factor * (target - initial)
        self.problem.set_point_targets(load_factor, ramp=True)
        if len(self.problem.bc_local):
            self.x.array[self.problem.bc_local] = self.problem.bc_values
        return self._solve_constrained()

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
        self.problem.bc_values = model.constrained_target.copy() if bc_values is None else np.asarray(bc_values, float)
        self.problem.state_to_vector(self.x)
        start = self.x.copy()
        try:
            for attempt, regularization in enumerate((0.0, *regularizations)):
                self.problem.regularization = regularization
                start.copy(self.x)
                if len(self.problem.bc_local):
                    self.x.array[self.problem.bc_local] = self.problem.bc_values
                converged = self._solve_constrained()
                pivots = self.negative_pivots()
                if converged:
                    # A converged step whose last LDL^T showed negative pivots is a stationary point
                    # of an indefinite incremental potential: recorded, not retried (a regularized
                    # retry converges to the same point).
                    self.problem.update_state(self.x)
                    its = self.snes.getIterationNumber()
                    self.report.newton_iterations.append(its)
                    self.report.negative_pivots.append(pivots)
                    return its
                if attempt == len(regularizations):
                    break
                self.report.regularized_retries += 1
                log.info(
                    "%s: attempt %d failed (%s, %d negative pivots); retrying with diagonal regularizer %.0e",
                    self.prefix,
                    attempt,
                    SNES_REASONS.get(self.snes.getConvergedReason()),
                    pivots,
                    regularizations[attempt],
                )
            self._raise(1.0, f"{len(regularizations)} regularized retries")
        finally:
            self.problem.regularization = 0.0
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
        return negative_pivots(self.snes.getKSP())

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
        self.problem.state_to_vector(self.x)

        def timed(action) -> float:
            comm.Barrier()
            t0 = time.perf_counter()
            action()
            comm.Barrier()
            return time.perf_counter() - t0

        def residual() -> None:
            self.problem.update_state(self.x)
            self.problem.assemble_residual(self.x, self.f)

        times = {
            "assemble_residual_s": timed(residual),
            "assemble_jacobian_s": timed(lambda: self.problem.assemble_jacobian(self.jacobian)),
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

    def counters(self) -> dict[str, float]:
        """Cumulative figures of this solver (the PETSc timings: of this process); the difference of
        two snapshots covers what happened in between, and ``negative_pivots`` is the last one's."""
        factor, solve = self.linear_solver_seconds()
        report = self.report
        return {
            "assembly_s": report.assemble_residual_s + report.assemble_jacobian_s,
            "factorization_s": factor,
            "linear_solve_s": solve,
            "regularized_retries": report.regularized_retries,
            "regularized_iterations": report.regularized_iterations,
            "negative_pivots": report.negative_pivots[-1] if report.negative_pivots else -1,
        }

    @staticmethod
    def linear_solver_seconds() -> tuple[float, float]:
        """Cumulative ``(factorization, triangular solves)`` seconds of this process (PETSc log)."""

        def seconds(*events: str) -> float:
            return sum(PETSc.Log.Event(name).getPerfInfo()["time"] for name in events)

        factor = seconds("MatCholFctrSym", "MatCholFctrNum", "MatLUFactorSym", "MatLUFactorNum")
        return factor, seconds("MatSolve")

    # -- lifetime -------------------------------------------------------------------------------
    def unused_options(self) -> list[str]:
        """Options under this solver's prefix (command line or caller's) that PETSc never read:
        misspelled or not applicable. Ask after the solves, before :meth:`close`."""
        return unused_options(self.prefix)

    def close(self) -> None:
        """Destroy the PETSc objects this solver owns, its problem's too (idempotent)."""
        if self._closed:
            return
        self._closed = True
        opts = PETSc.Options()
        for name in self._overrides:
            opts.delValue(name)
        for obj in (self.snes, self.x, self.f, self._trial):
            if obj is not None:
                obj.destroy()
        self.problem.close()

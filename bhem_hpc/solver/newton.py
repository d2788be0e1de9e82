"""The Newton driver of the shell problem (PETSc SNES), apart from the problem (:mod:`.problem`).

:class:`ShellSolver` owns a SNES (Newton + line search) whose linear solves are MUMPS direct
factorizations (LDL^T by default, LU when the Jacobian is not symmetric). Options live under the
solver's own prefix; defaults are pushed only where nothing is set yet, so the command line
(``-bhem_static_snes_rtol 1e-12``, ...) and a scene's ``options`` table override them. The
driver adds the energy line search, the descent directions of indefinite Jacobians (projected
Hessian, diagonal regularization), the trust-region recovery and the augmented-Lagrangian
multiplier updates. The linear strategy's options and fallback are :mod:`.linear_strategy`, load
stepping :mod:`.load_steps`, and the timing of a Newton iteration is in the benchmarks.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence

import numpy as np
from petsc4py import PETSc

from bhem_hpc.bodies.petsc import make_problem
from bhem_hpc.bodies.shared_dofs import SharedDofs
from bhem_hpc.model.hessian import COMPOSED_HESSIANS, HessianLadder
from bhem_hpc.model.shell import ShellModel
from bhem_hpc.solver.acceleration import AccelerationTest, attach_acceleration_test
from bhem_hpc.solver.anderson import CHORD_ANDERSON_DEPTH, AndersonMixing, anderson_depth
from bhem_hpc.solver.contributions import Contribution
from bhem_hpc.solver.energy_trust_region import EnergyTrustRegion
from bhem_hpc.solver.failure import solve_failure
from bhem_hpc.solver.linear import LinearSolverChoice, LinearSolverError
from bhem_hpc.solver.linear_strategy import (
    FactoredState,
    choose_for_models,
    default_options,
    linear_refactor_cost,
    switch_to_mumps,
)
from bhem_hpc.solver.load_steps import solve_in_load_steps
from bhem_hpc.solver.model_group import ModelGroup
from bhem_hpc.solver.petsc import (
    KSP_REASONS,
    SNES_REASONS,
    PetscOwner,
    SolverSetupError,
    mumps_factor,
    negated,
    negative_pivots,
    push_options,
    rejected_options,
    solve_stopped,
    stage_seconds,
    unused_options,
)
from bhem_hpc.solver.report import SolveReport, solver_counters
from bhem_hpc.solver.reuse import FACTORIZATION_POLICIES, FactorizationReuse
from bhem_hpc.solver.trust_region import TrustRegionNewton

log = logging.getLogger(__name__)
#: Where the residual has stopped falling (by half per iteration) and a full Newton step would lower
#: the potential by less than this times its magnitude (its round-off), the iterate minimizes it to
#: its precision and the solve stops: a stiff term (a penalty joint far from the origin) can keep the
#: residual above ``atol`` there in round-off alone. Not sooner: an energy this flat still leaves
#: errors of the order of the square root of its round-off in the state, which Newton removes.
ROUNDOFF_DECREASE = 16 * np.finfo(float).eps
#: The counters of :meth:`ShellSolver.counters` that count what Newton did besides plain steps.
RECOVERY_COUNTERS = ("projected_iterations", "trust_region_solves", "trust_region_failures")
#: The counters of :meth:`ShellSolver.counters` that count the linear solver's work.
LINEAR_COUNTERS = ("refactorizations", "chord_iterations", "refactor_retries", "krylov_iterations", "linear_solves")


def residual_callback(snes: PETSc.SNES, x: PETSc.Vec, f: PETSc.Vec, solver: ShellSolver) -> None:
    """SNES function callback (``kargs={"solver": solver}``): the residual of ``solver``'s problem at
    ``x`` into ``f``. Public for other SNES on the same problem (path following, trust region)."""
    solver.problem.update_state(x)
    if solver.problem.adapt_to_iterate():  # an energy changed (IPC's barrier stiffness grew)
        solver.forget_energy()
    solver.problem.assemble_residual(x, f)


def jacobian_callback(snes: PETSc.SNES, x: PETSc.Vec, jac: PETSc.Mat, pmat: PETSc.Mat, solver: ShellSolver) -> None:
    """SNES Jacobian callback for another SNES on ``solver``'s problem: assembles at every call (the
    problem's state is ``x``, set by :func:`residual_callback`) and drops ``solver``'s kept
    factorization, whose matrix it overwrites."""
    solver.problem.assemble_jacobian(pmat)
    solver.reuse.invalidate()  # another SNES (the path's) filled the shared matrix


def _kept_jacobian_callback(
    snes: PETSc.SNES, x: PETSc.Vec, jac: PETSc.Mat, pmat: PETSc.Mat, solver: ShellSolver
) -> None:
    """Assemble the Jacobian only when the refactor policy asks; otherwise the matrix is left
    untouched, so PETSc's PC sees an unchanged operator and keeps its factorization (a chord step)."""
    iteration, norm = snes.getIterationNumber(), snes.getFunctionNorm()
    if iteration == 0:
        rtol, atol, _, _ = snes.getTolerances()
        solver.target_norm = max(rtol * norm, atol)
    if solver.reuse.refactor_now(iteration, norm, solver.target_norm, solver.operator_signature()):
        solver.problem.assemble_jacobian(pmat)
        solver.remember_factored_state()


class ShellSolver(PetscOwner):
    """Newton solver for a :class:`ShellModel`: static equilibria (:meth:`solve`, with load stepping)
    and single time steps (:meth:`solve_step`, driven by :class:`~bhem_hpc.solver.dynamics.TimeStepper`).

    Args:
        model: the shell problem (forms, constraints, loads), or several bodies' models solved as one
            problem (:class:`~bhem_hpc.bodies.petsc.StackedProblem`, body after body; see
            :class:`~bhem_hpc.solver.model_group.ModelGroup` for what they must share).
        prefix: PETSc options prefix of this solver.
        options: PETSc options (without prefix) that override the defaults, e.g. from a scene.
        factorization: ``"reuse"``: keep the Jacobian and its factorization (or preconditioner)
            across Newton iterations and solves while chord steps converge well
            (:class:`FactorizationReuse`); ``"fresh"``: assemble and factor at every Newton iteration.
        linear: ``"direct"`` (MUMPS), ``"iterative"`` (preconditioned GMRES) or ``"auto"``
            (:func:`~bhem_hpc.solver.linear.choose_linear_solver`: by size, mass dominance and memory).
        contributions: energy contributions besides the model's terms
            (:class:`~bhem_hpc.solver.contributions.Contribution`); a :class:`StepBounded` one caps
            every line-search step. With several bodies: contributions that couple them, on the
            stacked problem's open blocks.
        acceleration_tolerance: time steps converge once the residual's root-mean-square
            acceleration is at most this [m/s^2] (:mod:`.acceleration`), instead of at ``rtol``.
        shared_dofs: closed DOFs that bodies share as one unknown (:mod:`~bhem_hpc.bodies.shared_dofs`).

    Raises:
        LinearSolverError: an unknown ``linear`` or a direct solver that would not fit in memory.
    """

    #: newtontr, made at the first failed time step
    trust_region: TrustRegionNewton | None
    #: the energy trust region (``hessian = "trust_region"``), made at the first time step
    energy_trust_region: EnergyTrustRegion | None
    #: a contribution's stopping test ended the current solve: its step is taken once SNES stops
    _final_step: bool = False

    def __init__(
        self, model: ShellModel | Sequence[ShellModel], prefix: str = "bhem_static_",
        options: Mapping[str, object] | None = None, factorization: str = "reuse", linear: str = "auto",
        contributions: Sequence[Contribution] = (), acceleration_tolerance: float | None = None,
        shared_dofs: SharedDofs | None = None):  # fmt: skip
        if factorization not in FACTORIZATION_POLICIES:
            raise ValueError(f"factorization must be one of {FACTORIZATION_POLICIES}, got {factorization!r}")
        #: the bodies solved together; :attr:`model` is the first (the only one of a single body)
        self.bodies = ModelGroup(model)
        self.model, self.prefix = self.bodies.models[0], prefix
        self._closed, self._energy_scale, self._stopped_on_step, self._last_norm = False, 0.0, False, np.inf
        # the potential at the state the energy line search accepted last (None: not evaluated there)
        self._accepted_energy: float | None = None
        self.target_norm = 0.0  # the residual norm at which the current SNES solve converges
        # recoveries made when needed; the adaptive Hessian's ladder; acceleration_tolerance's test
        self.trust_region, self.energy_trust_region, self.ladder = None, None, HessianLadder()
        self.acceleration: AccelerationTest | None = None
        self.linear = self._choose_linear(linear)
        #: linear-solver fallbacks taken: ``{"from", "to", "reason"}`` (also logged)
        self.fallbacks: list[dict] = []
        #: ``load factor -> values of the constrained DOFs`` (``model.constrained``) for static load
        #: steps, e.g. prescribed motions whose time is the load factor (rotations turn vectors); None:
        #: straight from the initial values to the targets.
        self.prescribed, comm = None, self.bodies.comm
        self.factored_state = FactoredState(self.bodies.models)
        opts = PETSc.Options()
        # the caller's options stay in the database for the solver's life (some are read only at
        # the first factorization) and are removed by close(); the defaults only for setup
        self._caller_options = dict(options or {})
        self._overrides = push_options(prefix, {}, options or {})
        self._own_options: list[str] = []  # defaults kept in the database: not the user's to spell right
        pushed = push_options(prefix, default_options(self.bodies.stiffest(), self.linear.kind), {})
        try:  # the pushed defaults are removed again whatever happens
            ldlt = opts.getString(prefix + "pc_type", "") == "cholesky"
            mumps = opts.getString(prefix + "pc_factor_mat_solver_type", "") == "mumps"
            # MUMPS' LDL^T takes SBAIJ (one triangle) serially; seams (PtAP) and MPI need AIJ.
            one = self.bodies.closed_is_open  # one body without seams
            serial_sbaij = ldlt and mumps and self.bodies.symmetric and comm.size == 1 and one
            # Block Jacobi and additive Schwarz / ILU work on the 3 x 3 blocks as assembled (no
            # conversion); hypre, the seams' PtAP and several bodies need AIJ.
            blocked = opts.getString(prefix + "pc_type", "") in ("bjacobi", "asm") and one
            self.matrix_format = "sbaij" if serial_sbaij else "baij" if blocked else "aij"
            self.report = SolveReport()
            self.problem = make_problem(self.bodies.models, self.matrix_format, self.report, contributions, shared_dofs)
            self.jacobian, self.bc_rows = self.problem.jacobian, self.problem.bc_rows
            self.x = PETSc.Vec().createMPI(self.jacobian.getSizes()[1], comm=comm)  # the unknowns' layout
            self.f = self.x.duplicate()
            # a pattern grown by contributions' blocks (problem.py): MUMPS analyses the matrix anew
            self.problem.on_pattern_growth = lambda: self.snes.getKSP().getPC().reset()
            self._choose_hessian()
            self.reuse = FactorizationReuse(factorization == "reuse", self.bodies.dynamic, linear_refactor_cost(
                self.linear.kind, self._dofs, self.problem.has_step_bounds))  # fmt: skip

            PETSc.Log.begin()  # event timers for counters() (idempotent, cheap)
            self._stage = PETSc.Log.Stage(f"{prefix}solve")  # one per prefix: the same stage if reused
            self.snes = PETSc.SNES().create(comm)
            self.snes.setOptionsPrefix(prefix)
            self.snes.setFunction(residual_callback, self.f, kargs={"solver": self})
            self.snes.setJacobian(_kept_jacobian_callback, self.jacobian, self.jacobian, kargs={"solver": self})
            self._trial: PETSc.Vec | None = None  # the energy line search's trial state
            if self.bodies.has_potential:
                self._trial = self.x.duplicate()
                self.snes.setLineSearchPreCheck(lambda x, y, solver: solver.damp_step(x, y), kargs={"solver": self})
            try:
                self.snes.setFromOptions()
                depth = anderson_depth(opts.getString(prefix + "chord_anderson_depth", str(CHORD_ANDERSON_DEPTH)),
                                       prefix)
            except (PETSc.Error, ValueError) as exc:
                given = {k: v for k, v in opts.getAll().items() if k.startswith(prefix)}
                self.close()
                raise (SolverSetupError(f"SNES solver '{prefix}': {exc}") if isinstance(exc, ValueError) else
                       rejected_options(f"SNES solver '{prefix}'", exc, "; options under the prefix: "
                                        f"{dict(sorted(given.items()))}")) from None  # fmt: skip
            self.anderson = AndersonMixing(depth, reduce=lambda a: comm.allreduce(a))
            if acceleration_tolerance is not None:
                self.acceleration = attach_acceleration_test(self, acceleration_tolerance)
        finally:
            for name in pushed:
                if name.startswith(prefix + "mat_mumps_"):  # read at the first factorization
                    self._overrides.append(name)
                    self._own_options.append(name)
                else:
                    opts.delValue(name)

    def _choose_hessian(self) -> None:
        """The adaptive Hessian starts each solve with the exact one and steps down its ladder where
        LDL^T shows negative pivots (:meth:`_descent_direction`); a Krylov solve shows no inertia, so
        the iterative path takes the projected Hessian (positive semi-definite: steps go downhill)."""
        if self._adaptive:
            self.problem.hessian = "projected" if self.linear.kind == "iterative" else "exact"

    @property
    def _adaptive(self) -> bool:
        return self.problem.hessian_kinds() == COMPOSED_HESSIANS["adaptive"]

    @property
    def _dofs(self) -> int:
        return self.bodies.closed_sizes[1]

    def _choose_linear(self, requested: str) -> LinearSolverChoice:
        choice = choose_for_models(self.bodies.models, requested)
        log.info("%s: %s linear solver (%s)", self.prefix, choice.kind, choice.reason)
        return choice

    def _fall_back_to_direct(self, reason: str) -> bool:
        """Switch a failing Krylov solver to MUMPS (when a factorization fits); logged and recorded
        in :attr:`fallbacks`. Returns whether it switched."""
        if self.linear.kind != "iterative" or self.fallbacks:
            return False
        try:
            choice = choose_for_models(self.bodies.models, "direct", self.linear.available_bytes)
        except LinearSolverError as exc:
            log.warning("%s: the Krylov solve failed (%s) and %s", self.prefix, reason, exc)
            return False
        switch_to_mumps(self.snes.getKSP(), self.bodies.symmetric, self.matrix_format)
        self.linear = choice
        self._choose_hessian()
        self.reuse.refactor_cost = linear_refactor_cost(self.linear.kind, self._dofs, self.problem.has_step_bounds)
        self.reuse.invalidate()
        self.fallbacks.append({"from": "iterative", "to": "direct", "reason": reason})
        log.warning("%s: the Krylov solve failed (%s); continuing with the direct solver (MUMPS)", self.prefix, reason)
        return True

    def operator_signature(self) -> tuple:
        """What the Jacobian depends on besides the state: the time step (the mass term scales with
        1 / dt^2) and the diagonal regularizer; a kept factorization of another is not reused."""
        return (self.bodies.time_step, self.problem.regularization)

    def _snes_solve(self) -> None:
        """One SNES solve from ``self.x``. A solve that failed on a kept factorization is repeated
        from the same start with a fresh one; one whose Krylov solve failed, with MUMPS (once per
        solver, when a factorization fits)."""
        start = self.x.copy()
        try:
            for _ in range(3):
                self.reuse.start_solve()
                self._energy_scale = 0.0  # the potential's magnitude, once damp_step has met it
                self._stopped_on_step, self._final_step, self._last_norm = False, False, np.inf
                self._accepted_energy = None
                self.anderson.reset()
                self._stage.push()
                try:
                    self.snes.solve(None, self.x)
                except PETSc.Error as exc:  # not a divergence: PETSc refused to go on (e.g. a bad option)
                    raise solve_stopped(self.prefix, exc) from None
                finally:
                    self._stage.pop()
                if self._final_step:  # the step a contribution's test ended the solve on (damp_step)
                    self.x.axpy(-1.0, self._trial)
                self.report.krylov_iterations += self.snes.getLinearSolveIterations()
                self.report.linear_solves += self.snes.getIterationNumber()
                reason = self.snes.getConvergedReason()
                if reason == PETSc.SNES.ConvergedReason.DIVERGED_LINEAR_SOLVE:
                    ksp_reason = self.snes.getKSP().getConvergedReason()
                    if self._fall_back_to_direct(f"KSP {KSP_REASONS.get(ksp_reason, ksp_reason)}"):
                        start.copy(self.x)
                        continue
                if self._converged() and self._final_step and self.problem.has_step_bounds:
                    self.reuse.ended_by_step_test(self.snes.getFunctionNorm())
                if self._converged() or not self.reuse.used_chord_steps():
                    return
                log.info("%s: chord steps on a kept factorization failed (%s); refactoring", self.prefix,
                         SNES_REASONS.get(self.snes.getConvergedReason()))  # fmt: skip
                self.reuse.failed()
                self.report.refactor_retries += 1
                start.copy(self.x)
        finally:
            start.destroy()

    def _solve_constrained(self, max_updates: int = 30) -> bool:
        """SNES solve, wrapped in augmented-Lagrangian multiplier updates when points are held."""
        for _ in range(max_updates):
            self._snes_solve()
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
        slope = self._mix_chord_step(x, y)  # d/dlambda of the potential along x - lambda y, at lambda = 0
        if slope > 0 and self.reuse.on_kept_factorization():
            slope = self._fresh_direction(x, y)  # a kept factorization's step that goes uphill
        indefinite = self.negative_pivots() > 0 or slope > 0
        accepted, self._accepted_energy = self._accepted_energy, None
        norm = self.snes.getFunctionNorm()
        stalled, self._last_norm = norm > 0.5 * self._last_norm, norm  # the residual at its floor
        at_roundoff = stalled and abs(slope) <= ROUNDOFF_DECREASE * self._energy_scale
        # or a contribution's own test (IPC's) ends the solve: its step, small and collision-free,
        # is taken once SNES has stopped (:meth:`_snes_solve`), not left to the line search
        self._final_step = not (indefinite or at_roundoff) and self.problem.has_step_tests and bool(
            self._along_step(x, y, self.problem.step_converged))  # fmt: skip
        if not indefinite and (at_roundoff or self._final_step):
            if self._final_step:
                y.copy(self._trial)
            y.zeroEntries()  # SNES stops on the empty step; :meth:`_converged` takes it
            self._stopped_on_step = True
            return
        if not indefinite and abs(slope) <= 1e-9 * self._energy_scale:
            self._bound_step(x, y)
            return  # below the round-off of the potential met earlier in this solve: no assembly needed
        if accepted is not None and x.equal(self._trial):
            energy0 = accepted  # SNES took the step this line search accepted last: the same state
        else:
            self.problem.update_state(x)
            energy0 = self.problem.potential_energy()
        self._energy_scale = abs(energy0)
        resolution = 1e-12 * abs(energy0)
        if indefinite:
            slope = self._descent_direction(x, y)
        slope *= self._bound_step(x, y)
        if abs(slope) <= 1e3 * resolution:
            return
        step = 1.0
        for _ in range(max_backtracks):
            self._trial.waxpy(-step, y, x)
            self.problem.update_state(self._trial)
            energy = self.problem.potential_energy()
            if np.isfinite(energy) and energy <= energy0 + 1e-4 * step * slope + resolution:
                self._accepted_energy = energy
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

    def forget_energy(self) -> None:
        """The potential changed at fixed states: drop the line search's last energy and the kept factorization."""
        self._accepted_energy = None
        self.reuse.invalidate()

    def _along_step(self, x: PETSc.Vec, y: PETSc.Vec, query: Callable[[PETSc.Vec], float]) -> float:
        """Collective: the problem's ``query`` of the step ``x -> x - y`` (its direction), at ``x``."""
        self.problem.update_state(x)
        with negated(y) as direction:
            return query(direction)

    def _bound_step(self, x: PETSc.Vec, y: PETSc.Vec) -> float:
        """Shorten the step ``x -> x - y`` to what the step-bounded contributions admit (a barrier
        is never crossed, not even by a trial of the line search). Returns the factor applied."""
        if not self.problem.has_step_bounds:
            return 1.0
        bound = self._along_step(x, y, self.problem.max_step)
        if bound < 1.0:
            y.scale(bound)
            self.report.bounded_steps += 1
        return bound

    def _mix_chord_step(self, x: PETSc.Vec, y: PETSc.Vec) -> float:
        """Replace a chord step ``y`` by its Anderson mixing with the earlier chord steps on the same
        factorization when the mixed step goes downhill; a step on a new factorization starts a new
        history. Returns the slope ``-F.y`` of the step kept."""
        if not self.reuse.on_kept_factorization():
            self.anderson.reset()
        mixed = self.anderson.mixed_step(x.getArray(readonly=True), y.getArray(readonly=True))
        slope = -self.f.dot(y)
        if mixed is not None:
            raw = y.copy()
            y.setArray(mixed)
            mixed_slope = -self.f.dot(y)
            if mixed_slope < 0:
                slope = mixed_slope
            else:  # not a descent direction: the chord step as it was
                raw.copy(y)
            raw.destroy()
        return slope

    def _fresh_direction(self, x: PETSc.Vec, y: PETSc.Vec) -> float:
        """Re-solve for ``y`` with the Jacobian assembled and factored at ``x`` (counted as a
        refactorization). Returns the new slope ``-F.y``."""
        self.problem.assemble_jacobian(self.jacobian)
        self.remember_factored_state()
        self.reuse.refactored(self.operator_signature())
        ksp = self.snes.getKSP()
        ksp.setOperators(self.jacobian)
        ksp.solve(self.f, y)
        self.anderson.reset()
        if not self._linear_solve_ok(ksp, y, "the fresh Jacobian's step"):
            return 0.0
        self.anderson.mixed_step(x.getArray(readonly=True), y.getArray(readonly=True))  # the new history's first
        return -self.f.dot(y)

    def _descent_direction(self, x: PETSc.Vec, y: PETSc.Vec) -> float:
        """Re-solve for ``y`` where the step's Jacobian is indefinite or went uphill; returns the new
        slope ``-F.y``. The adaptive Hessian steps down its ladder: from an indefinite exact Hessian
        (quadratic convergence wherever inertia keeps it positive definite: stiff shells) to the one
        projected out of the plane for the rest of the solve (compressed cloth), and from that to the
        projected one for this iteration (strong in-plane compression). Otherwise (an uphill step of
        round-off size, other kinds) the diagonal is regularized."""
        if self._adaptive and self.problem.hessian == "exact" and self.negative_pivots() > 0:
            self.problem.hessian = "out_of_plane"
            slope = self._fresh_direction(x, y)
            if self.negative_pivots() <= 0 and slope <= 0:
                return slope
        if not (self._adaptive and self.problem.hessian == "out_of_plane"):
            return self._regularized_direction(y)
        self.problem.hessian = "projected"  # positive semi-definite, for this iteration
        try:
            slope = self._fresh_direction(x, y)
        finally:
            self.problem.hessian = "out_of_plane"
        self.report.projected_iterations += 1
        return slope

    def _linear_solve_ok(self, ksp: PETSc.KSP, y: PETSc.Vec, what: str) -> bool:
        """Whether a linear solve inside the line search converged; if not, no step is taken
        (``y = 0``: Newton stalls and the caller's recovery takes over) and the reason is logged."""
        reason = ksp.getConvergedReason()
        if reason >= 0:
            return True
        log.info("%s: linear solve for %s failed (KSP %s); no step", self.prefix, what, KSP_REASONS.get(reason, reason))
        y.set(0.0)
        return False

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
            if not self._linear_solve_ok(ksp, y, "a regularized step"):
                break
            if self.negative_pivots() <= 0:
                break
        magnitude.destroy()
        self.reuse.invalidate()  # the factorization is of the regularized matrix
        self.anderson.reset()
        self.report.regularized_iterations += 1
        log.info("%s: indefinite Jacobian regularized with r = %.0e", self.prefix, applied)
        return -self.f.dot(y)

    # -- solves ---------------------------------------------------------------------------------
    def solve(self, load_steps: int = 1, max_cuts: int = 10) -> SolveReport:
        """Solve for equilibrium, ramping loads and prescribed values from 0 to 1 in load steps
        (:func:`~bhem_hpc.solver.load_steps.solve_in_load_steps`, which documents the arguments).

        Raises:
            SolverError: naming the solver, the load factor and the SNES/KSP reasons.
        """
        return solve_in_load_steps(self, load_steps, max_cuts)

    def solve_at(self, load_factor: float) -> bool:
        """One Newton solve (SNES) at ``load_factor`` from the current iterate ``self.x``: loads scaled
        to it, prescribed values from :attr:`prescribed` (or interpolated linearly from the initial
        values to the targets). Returns whether it converged (``self.x`` holds the result)."""
        self.bodies.set_load_factor(load_factor)
        if self.prescribed is not None:
            self.problem.bc_values = np.asarray(self.prescribed(load_factor), dtype=float)
        else:
            initial, target = self.bodies.constrained_initial, self.bodies.constrained_target
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
        self.bodies.set_load_factor(1.0)
        target = self.bodies.constrained_target if bc_values is None else np.asarray(bc_values, float)
        self.problem.bc_values = target
        self.problem.state_to_vector(self.x)
        start = self.x.copy()
        if self._adaptive and self.linear.kind == "direct":  # where this step starts the ladder
            self.problem.hessian = self.ladder.start(self.problem.hessian)
        try:
            if self._uses_energy_trust_region():
                its = self._energy_trust_region_step()
                if its >= 0:
                    return its
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
                    return self._step_converged(self.snes.getIterationNumber(), pivots)
                if attempt == 0 and self._trust_region_applies() and self._trust_region_recovers(start):
                    return self._step_converged(self.trust_region.iterations(), self.negative_pivots())
                if attempt == len(regularizations):
                    break
                self.report.regularized_retries += 1
                log.info("%s: attempt %d failed (%s, %d negative pivots); retrying with diagonal regularizer %.0e",
                         self.prefix, attempt, SNES_REASONS.get(self.snes.getConvergedReason()), pivots,
                         regularizations[attempt])  # fmt: skip
            self.raise_failure(1.0, f"trust-region Newton and {len(regularizations)} regularized retries")
        finally:
            self.problem.regularization = 0.0
            start.destroy()
        return -1  # unreachable: raise_failure always raises

    def _step_converged(self, iterations: int, pivots: int) -> int:
        """Record a converged time step's Newton iterations and negative pivots; returns the former."""
        self.problem.update_state(self.x)
        self.report.newton_iterations.append(iterations)
        self.report.negative_pivots.append(pivots)
        return iterations

    def _uses_energy_trust_region(self) -> bool:
        """Whether time steps start with the energy trust region (``hessian = "trust_region"``), made
        at the first one. Its CG needs a symmetric positive definite preconditioner, the projected
        Hessian's Cholesky factors (MUMPS): the iterative path iterates with the projected Hessian."""
        if self.energy_trust_region is None:
            kinds = set(self.problem.hessian_kinds())
            if kinds != {"exact", "projected"} or self.linear.kind != "direct" or not self.bodies.has_potential:
                return False
            self.energy_trust_region = EnergyTrustRegion(self, default_options(self.bodies.stiffest(), "direct"))
        return not len(self.problem.alm_multipliers)  # it rejects trials that a step bound cuts short

    def _energy_trust_region_step(self) -> int:
        """The time step by the energy trust region from ``self.x`` (constrained DOFs set first);
        its iterations, or -1 (``self.x`` back at the start) when it did not converge."""
        if len(self.problem.bc_local):
            self.x.array[self.problem.bc_local] = self.problem.bc_values
        self._stage.push()  # its factorizations and solves count in this solver's timings
        try:
            converged = self.energy_trust_region.solve(self.x)
        finally:
            self._stage.pop()
        self.report.linear_solves += self.energy_trust_region.iterations
        if not converged:
            self.report.trust_region_failures += 1
            return -1
        return self._step_converged(self.energy_trust_region.iterations, 0)  # it factors an SPD matrix

    def _trust_region_applies(self) -> bool:
        """The trust-region recovery lacks the augmented Lagrangian (point constraints) and step bounds (a barrier)."""
        return not len(self.problem.alm_multipliers) and not self.problem.has_step_bounds

    def _trust_region_recovers(self, start: PETSc.Vec) -> bool:
        """After a failed line-search solve: the trust-region Newton from the step's start."""
        if self.trust_region is None:
            self.trust_region = TrustRegionNewton(self, default_options(self.bodies.stiffest(), self.linear.kind),
                                                  (residual_callback, jacobian_callback),
                                                  self._caller_options)  # fmt: skip
        return self.trust_region.recover(start)

    def _converged(self) -> bool:
        """Whether the last SNES solve converged. A step-size test (the update fell below ``stol``)
        counts only with a residual near the solve's target: the energy line search takes no step
        when it finds no decrease, which SNES would otherwise report as converged."""
        reason, norm = self.snes.getConvergedReason(), self.snes.getFunctionNorm()
        stalled = reason == PETSc.SNES.ConvergedReason.CONVERGED_SNORM_RELATIVE and not self._stopped_on_step
        if stalled and norm > 1e3 * self.target_norm:
            return False
        return reason > 0 and bool(np.isfinite(norm))

    def raise_failure(self, factor: float, after: str) -> None:
        """Raise the :class:`SolverError` of a solve that failed at load ``factor`` after ``after``."""
        raise solve_failure(self, factor, after)

    def factor_matrix(self) -> PETSc.Mat | None:
        """The MUMPS factor of the last factorization (:func:`~bhem_hpc.solver.petsc.mumps_factor`)."""
        return mumps_factor(self.snes.getKSP())

    def negative_pivots(self) -> int:
        """Negative pivots of the last LDL^T factorization (MUMPS INFOG(12)); -1 if unknown."""
        return negative_pivots(self.snes.getKSP())

    def inertia_at_state(self) -> int:
        """Collective: assemble and factor the Jacobian at the model's current state (no step taken)
        and return its negative pivots (-1: the linear solver does not report them)."""
        self.problem.state_to_vector(self.x)
        self.problem.update_state(self.x)
        self.problem.assemble_jacobian(self.jacobian)
        self.reuse.invalidate()  # the kept factorization is replaced by this one
        ksp = self.snes.getKSP()
        ksp.setOperators(self.jacobian)
        ksp.getPC().setUp()
        return self.negative_pivots()

    def remember_factored_state(self) -> None:
        """Note the state and Hessian kind the Jacobian just assembled depends on (:class:`FactoredState`)."""
        self.factored_state.remember(self.problem.hessian_kinds().index(self.problem.hessian))

    def reuse_checkpoint(self) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        """Collective: the kept factorization's checkpoint (:meth:`FactoredState.checkpoint`)."""
        return self.factored_state.checkpoint(self.reuse)

    def restore_reuse_checkpoint(self, arrays: dict[str, np.ndarray], state: dict[str, float]) -> None:
        """Collective: remake the kept factorization of a checkpoint (assembled and factored at its
        state), so a continued run decides and computes as the uninterrupted one."""
        self.factored_state.restore(arrays, state, self.problem, self.snes.getKSP())
        self.reuse.restore(state, self.operator_signature())

    def counters(self) -> dict[str, float]:
        """Cumulative figures of this solver (:func:`~bhem_hpc.solver.report.solver_counters`), with the
        seconds of its stage's ``PCSetUp`` and ``KSPSolve`` on this process; the difference of two
        snapshots covers what happened in between."""
        factor, solve = stage_seconds(self._stage, "PCSetUp"), stage_seconds(self._stage, "KSPSolve")
        return solver_counters(self.report, self.reuse, factor, solve)

    def unused_options(self) -> list[str]:
        """Options under this solver's prefix (command line or caller's) that PETSc never read:
        misspelled or not applicable (this solver's own defaults left out: a run that never factors
        leaves its MUMPS defaults unread). Ask after the solves, before :meth:`close`."""
        return [name for name in unused_options(self.prefix) if name not in self._own_options]

    def close(self) -> None:
        """Destroy the PETSc objects this solver owns, its problem's too (idempotent)."""
        if self._closed:
            return
        self._closed = True
        opts = PETSc.Options()
        for name in self._overrides:
            opts.delValue(name)
        for owner in (self.trust_region, self.energy_trust_region, self.acceleration and self.acceleration.residual):
            if owner is not None:
                owner.close()
        for obj in (self.snes, self.x, self.f, self._trial):
            if obj is not None:
                obj.destroy()
        self.problem.close()

"""Newton trust region on the incremental potential (PETSc TAO ``ntr``): the time-step solve of
``hessian = "trust_region"``.

Each iteration minimizes the quadratic model of the potential with the exact Hessian inside a
trust region, by Steihaug's conjugate gradients (KSP ``stcg``) preconditioned by a MUMPS Cholesky
factorization of the projected (positive definite) Hessian. The exact Hessian's directions of
negative curvature, which make a line-search Newton stall on compressed cloth, end the CG at the
region's boundary instead; the radius follows the ratio of the actual to the predicted decrease of
the potential, so every accepted step lowers the energy. A single shell's exact Hessian is applied
matrix-free (:mod:`bhem_hpc.solver.hessian_action`: an assembly of the residual's derivative per CG
iteration instead of the matrix's per trust-region iteration); several bodies' is assembled. Where
contributions bound steps (IPC's barrier), a trial whose straight path from the current iterate the
bound cuts short (it would pass through a contact) counts as an infinite potential: TAO rejects it
and shrinks the region, so no iterate is ever in intersection. There the first radius is the
first Newton step's length, not TAO's interpolation along the gradient, whose long probes contact
cuts. Contributions that adapt between line-search iterations (the barrier's stiffness) keep their
parameters within a trust-region solve.
Its options live under its own prefix (``<solver prefix>ntr_``; the CG and its preconditioner
under ``<solver prefix>ntr_tao_ntr_``).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from typing import TYPE_CHECKING

from petsc4py import PETSc

from bhem_hpc.solver.acceleration import tao_stopping_test
from bhem_hpc.solver.contributions import ContributionSteps
from bhem_hpc.solver.hessian_action import ExactHessianAction, exact_hessian_action
from bhem_hpc.solver.petsc import PetscOwner, SolverSetupError, push_options, rejected_options, solve_stopped

if TYPE_CHECKING:
    from bhem_hpc.solver.newton import ShellSolver

log = logging.getLogger(__name__)
#: Trust-region iterations one time step may take (the first step of the shear job needs 66: its
#: edges start moving at once and every CG meets negative curvature).
MAX_ITERATIONS = 150
#: The Steihaug CG's relative tolerance: the model's minimizer is needed roughly far from the
#: solution and exactly close to it, where the first CG iteration on the Cholesky-preconditioned
#: system is already nearly exact.
CG_RTOL = "1e-2"
#: Trust-region iterations that share one factorization of the preconditioner (the projected Hessian
#: at the first of them; CG makes up for its age with more, cheap iterations). Cotton, Hermite 25 x 25,
#: 10 steps, s/step for periods 1, 2, 3, 5: drape 1.11, 0.92, 0.85, 0.82; hanging 0.36, 0.31, 0.27,
#: 0.25; shear 1.42, 1.40, 1.18, 1.32; never refactored: 1.54, 0.24, 4.79.
PRECONDITIONER_PERIOD = 3
#: The first radius of a solve where contributions bound steps (``ntr_tao_ntr_init_type``): the
#: length of the first Newton step. TAO's default ("interpolation") probes steps along the gradient
#: from a radius of 100; there each probe is a collision-free-step query, the probes that contact
#: cuts are refused, and the radius starts at the first one uncut: 1e-4 m on the crushed can by
#: IPC, whose first iterations then only grow it (steps 36-40 from one checkpoint: 10, 13, 28, 12,
#: 8 iterations by interpolation; 8, 12, 27, 7, 5 from the Newton step's length).
STEP_BOUNDED_INITIAL_RADIUS = "direction"
#: The Krylov solvers of the trust-region subproblem a scene may choose (``ntr_tao_ntr_ksp_type``).
SUBPROBLEM_SOLVERS = ("stcg", "nash")
TAO_REASONS = {v: k for k, v in vars(PETSc.TAO.Reason).items() if k.isupper()}


class EnergyTrustRegion(PetscOwner):
    """A TAO ``ntr`` solver on a :class:`~bhem_hpc.solver.newton.ShellSolver`'s problem, which must have
    a potential (a conservative problem) and both Hessian kinds ``"exact"`` and ``"projected"``.

    Args:
        solver: the solver whose problem (residual, potential, Hessians) and tolerances it uses.
        direct_options: the solver's MUMPS options (``pc_*``, ``mat_mumps_*``), applied to the
            preconditioner under this solver's KSP prefix where the database has no value (a scene's
            ``ntr_*`` options are there already, under the solver's prefix).

    The Hessian is the line-search solver's matrix, assembled with the exact kind; the preconditioner
    a matrix of the same layout.
    """

    def __init__(self, solver: ShellSolver, direct_options: Mapping[str, str]):
        self.solver = solver
        self.prefix = solver.prefix + "ntr_"
        self._closed = False
        comm = solver.model.comm
        self.preconditioner = solver.jacobian.duplicate()
        self.gradient = solver.f.duplicate()
        #: the current iterate, from which a trial's straight path must stay free of contact
        self.iterate = solver.f.duplicate()
        self.step = solver.f.duplicate()  # the step test's projected Newton step
        #: the exact Hessian applied matrix-free, or None (then assembled into the solver's Jacobian)
        self.action: ExactHessianAction | None = exact_hessian_action(solver.problem)
        self.tao: PETSc.TAO | None = None
        self._hessians = 0  # Hessians asked for in the current solve (the preconditioner's age)
        rtol, atol, _, _ = solver.snes.getTolerances()
        ksp_prefix = self.prefix + "tao_ntr_"
        own = {"tao_max_it": str(MAX_ITERATIONS), "tao_gatol": f"{atol:.3e}", "tao_gttol": f"{rtol:.3e}",
               "tao_grtol": "0"}  # fmt: skip
        if solver.problem.has_step_bounds:
            own["tao_ntr_init_type"] = STEP_BOUNDED_INITIAL_RADIUS
        linear = {"ksp_type": "stcg", "ksp_rtol": CG_RTOL, "ksp_max_it": "200",
                  **{k: v for k, v in direct_options.items() if k.startswith(("pc_", "mat_mumps_"))}}  # fmt: skip
        linear["pc_type"] = "cholesky"  # the projected Hessian is symmetric positive definite
        pushed = push_options(self.prefix, own, {}) + push_options(ksp_prefix, linear, {})
        opts = PETSc.Options()
        try:
            self.tao = PETSc.TAO().create(comm)
            self.tao.setOptionsPrefix(self.prefix)
            self.tao.setType("ntr")
            self.tao.setObjectiveGradient(self._objective_gradient, self.gradient)
            self.tao.setObjective(self._objective)
            model = solver.jacobian if self.action is None else self.action.matrix
            self.tao.setHessian(self._hessian, model, self.preconditioner)
            problem = solver.problem
            #: the solver's step test (``solver.velocity_tolerance``), or None. Not the contributions' (IPC's
            #: ``velocity_tolerance``): a small projected step is no equilibrium where the exact Hessian is
            #: indefinite. Taken on the crushed can by IPC, steps 21-45, it ended the steps before the snap
            #: after 1 to 4 iterations, and the wall then snapped in steps 43-45 in 107, 116 and 143
            #: iterations (5 recoveries, a dt halving), against at most 17 without it (measured).
            self.velocity_test = problem.step_velocity_test if isinstance(problem, ContributionSteps) else None
            if solver.acceleration is not None or self.velocity_test is not None:  # the line search's tests
                test = solver.acceleration
                self.tao.setConvergenceTest(tao_stopping_test, kargs={
                    "residual": None if test is None else test.residual,
                    "tolerance": 0.0 if test is None else test.tolerance,
                    "step_small": None if self.velocity_test is None else self._step_small})  # fmt: skip
            try:
                self.tao.setFromOptions()
            except PETSc.Error as exc:
                self.close()
                raise rejected_options(f"TAO solver '{self.prefix}'", exc) from None
            subproblem = self.tao.getKSP().getType()
            if subproblem not in SUBPROBLEM_SOLVERS:
                self.close()
                raise SolverSetupError(
                    f"TAO solver '{self.prefix}': option -{ksp_prefix}ksp_type = {subproblem!r}: the trust region's "
                    f"subproblem takes {' or '.join(map(repr, SUBPROBLEM_SOLVERS))} ('gltr' frees an invalid pointer "
                    "in PETSc 3.18's ntr and aborts the process)")  # fmt: skip
        finally:
            for name in pushed:
                opts.delValue(name)

    def _step_small(self, tao: PETSc.TAO) -> bool:
        """Collective: the solver's step test on the projected Newton step ``P^-1 g`` from the current
        iterate, ``P`` the preconditioner's factorization (of the projected Hessian, at most
        :data:`PRECONDITIONER_PERIOD` - 1 iterates old); the solve ends at the iterate, the step untaken."""
        if tao.getIterationNumber() < 1:  # nothing factored yet in this solve
            return False
        tao.getKSP().getPC().apply(tao.getGradient()[0], self.step)
        return self.velocity_test.passes(self.solver.problem.open_direction_blocks(self.step))

    # -- TAO callbacks (the problem's state follows the point asked about) ----------------------
    def _objective(self, tao: PETSc.TAO, x: PETSc.Vec) -> float:
        problem = self.solver.problem
        if problem.has_step_bounds:
            direction = x.copy()
            direction.axpy(-1.0, self.iterate)
            problem.update_state(self.iterate)
            bound = problem.max_step(direction)
            direction.destroy()
            if bound < 1.0:
                return math.inf
        problem.update_state(x)
        return problem.potential_energy()

    def _objective_gradient(self, tao: PETSc.TAO, x: PETSc.Vec, gradient: PETSc.Vec) -> float:
        problem = self.solver.problem
        problem.update_state(x)
        problem.assemble_residual(x, gradient)
        return problem.potential_energy()

    def _hessian(self, tao: PETSc.TAO, x: PETSc.Vec, hessian: PETSc.Mat, preconditioner: PETSc.Mat) -> None:
        """At each iterate TAO accepts (before any trial from it)."""
        problem = self.solver.problem
        x.copy(self.iterate)
        problem.update_state(x)
        kind = problem.hessian
        assembled = self.solver.jacobian  # the problem assembles into its own matrix; the projected kind is copied out
        try:
            # counted per solve, not by TAO's iteration number: an initial radius other than TAO's
            # interpolation asks for the first Hessian at iteration 1, with nothing factored yet
            if self._hessians % PRECONDITIONER_PERIOD == 0:
                problem.hessian = "projected"
                problem.assemble_jacobian(assembled)
                self._copy_preconditioner(assembled)
                # factored at the CG's next setup: counted with the line search's factorizations
                self.solver.reuse.refactorizations += 1
            problem.hessian = "exact"
            if self.action is None:
                problem.assemble_jacobian(assembled)
            else:
                self.action.set_iterate()
        finally:
            problem.hessian = kind
        self._hessians += 1
        self.solver.reuse.invalidate()  # the line-search solver's kept factorization is of another matrix

    def _copy_preconditioner(self, hessian: PETSc.Mat) -> None:
        """Copy ``hessian`` (the projected kind) into the preconditioner. Contact between bodies grows
        the Hessian's pattern (the stacked problem); a grown pattern is copied as such and the
        factorization's analysis redone."""
        total = PETSc.Mat.InfoType.GLOBAL_SUM
        same = hessian.getInfo(total)["nz_used"] == self.preconditioner.getInfo(total)["nz_used"]
        structure = PETSc.Mat.Structure.SAME_NONZERO_PATTERN if same else PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN
        hessian.copy(self.preconditioner, structure=structure)
        if not same:
            self.tao.getKSP().getPC().reset()

    # -- solve ----------------------------------------------------------------------------------
    def solve(self, x: PETSc.Vec) -> bool:
        """Minimize the potential from ``x`` (overwritten with the result, or left as it was when the
        gradient did not meet the solver's tolerances: absolute, relative or acceleration); whether it converged."""
        start = x.copy()
        self._hessians = 0
        try:
            self.tao.setSolution(x)
            try:
                self.tao.solve()
            except PETSc.Error as exc:
                raise solve_stopped(self.prefix, exc) from None
            reason = self.tao.getConvergedReason()
            # not a step-size test: a radius shrunk to nothing is no equilibrium
            converged = reason in (PETSc.TAO.Reason.CONVERGED_GATOL, PETSc.TAO.Reason.CONVERGED_GTTOL,
                                   PETSc.TAO.Reason.CONVERGED_USER)  # fmt: skip
            if not converged:
                log.info("%s: %s after %d trust-region iterations, |g| = %.3e; the step starts again with "
                         "line-search Newton", self.prefix, TAO_REASONS.get(reason, reason), self.iterations,
                         self.tao.getSolutionStatus()[2])  # fmt: skip
                start.copy(x)
            return converged
        finally:
            start.destroy()

    @property
    def iterations(self) -> int:
        """Trust-region iterations of the last solve."""
        return self.tao.getIterationNumber()

    def close(self) -> None:
        """Destroy the TAO solver and its matrices (idempotent)."""
        if self._closed:
            return
        self._closed = True
        for obj in (self.tao, self.preconditioner, self.gradient, self.iterate, self.step):
            if obj is not None:
                obj.destroy()
        if self.action is not None:
            self.action.close()

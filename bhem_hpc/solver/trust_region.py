"""Trust-region Newton (PETSc ``newtontr``): the recovery of a time step whose line-search Newton
failed, before the regularized retries and before the step's dt is halved.

Where the line-search Newton stalls (a step that the energy line search cannot shorten enough, an
iteration limit hit while the residual still falls slowly), a trust region bounds every step by a
radius that adapts to how well the quadratic model predicted the decrease: it needs no descent
direction, so an indefinite Jacobian does not stop it. It shares the solver's residual, Jacobian
matrix and linear-solver kind; its options live under its own prefix (``<solver prefix>tr_``).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

from petsc4py import PETSc

from bhem_hpc.solver.petsc import SNES_REASONS, PetscOwner, push_options, rejected_options, solve_stopped

if TYPE_CHECKING:
    from bhem_hpc.solver.newton import ShellSolver

log = logging.getLogger(__name__)
#: Newton iterations the trust region may take (it shortens steps, so it may need more than Newton)
TRUST_REGION_MAX_IT = 100


class TrustRegionNewton(PetscOwner):
    """A ``newtontr`` SNES on a :class:`~bhem_hpc.solver.newton.ShellSolver`'s problem.

    Args:
        solver: the line-search solver it recovers (its residual, Jacobian and tolerances).
        defaults: the solver's PETSc defaults (linear solver, tolerances), used under this prefix
            where the options database has no value.
        callbacks: the line-search solver's residual and Jacobian callbacks (SNES signatures, taking
            ``solver``): the same assembly serves both SNES.
        overrides: the caller's options of the line-search solver (e.g. a scene's); all but its
            ``snes_*`` (and this solver's own ``tr_*``) ones apply here too, so both solve their linear
            systems alike.
    """

    def __init__(self, solver: ShellSolver, defaults: dict[str, str], callbacks: tuple[Callable, Callable],
                 overrides: Mapping[str, object]):  # fmt: skip
        self.solver = solver
        self.prefix = solver.prefix + "tr_"
        self._closed = False
        opts = PETSc.Options()
        rtol, atol, stol, _ = solver.snes.getTolerances()
        own = {k: v for k, v in defaults.items() if not k.startswith(("snes_linesearch", "mat_mumps"))}
        own |= {"snes_type": "newtontr", "snes_max_it": str(TRUST_REGION_MAX_IT), "snes_rtol": f"{rtol:.3e}",
                "snes_atol": f"{atol:.3e}", "snes_stol": f"{stol:.3e}"}  # fmt: skip
        inherited = {k: v for k, v in overrides.items() if not str(k).lstrip("-").startswith(("snes_", "tr_"))}
        pushed = push_options(self.prefix, own, inherited)
        try:
            self.snes = PETSc.SNES().create(solver.model.comm)
            self.snes.setOptionsPrefix(self.prefix)
            residual, jacobian = callbacks
            self.snes.setFunction(residual, solver.f, kargs={"solver": solver})
            self.snes.setJacobian(jacobian, solver.jacobian, solver.jacobian, kargs={"solver": solver})
            try:
                self.snes.setFromOptions()
            except PETSc.Error as exc:
                self.snes.destroy()
                self._closed = True
                raise rejected_options(f"SNES solver '{self.prefix}'", exc) from None
        finally:
            for name in pushed:
                opts.delValue(name)

    def solve(self, x: PETSc.Vec) -> bool:
        """Solve from ``x`` (overwritten with the result); whether it converged."""
        try:
            self.snes.solve(None, x)
        except PETSc.Error as exc:
            raise solve_stopped(self.prefix, exc) from None
        reason = self.snes.getConvergedReason()
        log.info("%s: %s after %d trust-region Newton iterations, |F| = %.3e", self.prefix,
                 SNES_REASONS.get(reason, reason), self.snes.getIterationNumber(),
                 self.snes.getFunctionNorm())  # fmt: skip
        return reason > 0

    def recover(self, start: PETSc.Vec) -> bool:
        """After a failed solve of the line-search solver: this solve from its step's ``start`` into
        its ``x`` (counted in its report's ``trust_region_solves`` when it converges; logged either
        way); whether it converged."""
        solver = self.solver
        log.info("%s: Newton failed (%s); trying trust-region Newton", solver.prefix,
                 SNES_REASONS.get(solver.snes.getConvergedReason()))  # fmt: skip
        start.copy(solver.x)
        if len(solver.problem.bc_local):
            solver.x.array[solver.problem.bc_local] = solver.problem.bc_values
        solver.problem.regularization = 0.0
        converged = self.solve(solver.x)
        solver.report.linear_solves += self.iterations()
        if converged:
            solver.report.trust_region_solves += 1
        return converged

    def iterations(self) -> int:
        return self.snes.getIterationNumber()

    def close(self) -> None:
        """Destroy the SNES (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self.snes.destroy()

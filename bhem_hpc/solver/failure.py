"""What a failed nonlinear solve says: which solver, its SNES and KSP reasons, MUMPS' status, which
energy terms dominate the residual where it stopped, and what the user can change."""

from __future__ import annotations

from typing import TYPE_CHECKING

from bhem_hpc.solver.petsc import KSP_REASONS, SNES_REASONS, SolverError

if TYPE_CHECKING:
    from bhem_hpc.solver.newton import ShellSolver


def solve_failure(solver: ShellSolver, factor: float, after: str) -> SolverError:
    """The error of ``solver``'s solve that failed at load ``factor`` after ``after`` (collective:
    it assembles the terms' residuals at the state where the solve stopped)."""
    snes = solver.snes
    reason = snes.getConvergedReason()
    ksp_reason = snes.getKSP().getConvergedReason()
    mumps = ""
    factor_matrix = solver.factor_matrix()
    if factor_matrix is not None:
        mumps = f", MUMPS INFOG(1) = {factor_matrix.getMumpsInfog(1)}"
    return SolverError(
        f"SNES solver '{solver.prefix}' failed at load factor {factor:.4g} after {after}: "
        f"{SNES_REASONS.get(reason, reason)} after {snes.getIterationNumber()} Newton iterations, "
        f"|F| = {snes.getFunctionNorm():.3e}; last linear solve: KSP "
        f"{KSP_REASONS.get(ksp_reason, ksp_reason)}{mumps}; {dominant_terms(solver)}"
    )


def dominant_terms(solver: ShellSolver) -> str:
    """Which terms make up the residual at ``solver.x``, and what the user can change."""
    solver.problem.update_state(solver.x)
    norms = solver.problem.term_residual_norms()
    ranked = sorted(norms.items(), key=lambda item: -item[1])
    listed = ", ".join(f"{name} {norm:.2e}" for name, norm in ranked[:3])
    if solver.model.dynamics is not None:
        advice = "a smaller dt, a finer or coarser resolution, or solver.hessian = 'trust_region' or 'projected'"
    else:
        advice = "more load steps (time.load_steps), or a path method"
    return f"residual by term (largest first): {listed}; the {ranked[0][0]} term dominates; try {advice}"

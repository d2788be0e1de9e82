"""Static load stepping: the load factor from 0 to 1 in increments that halve on failure and grow
back on success, each step predicted by the secant of the last two equilibria.

It drives any solver with the :class:`StaticSolver` interface (:class:`~bhem_hpc.solver.newton.ShellSolver`);
path following past limit points is :mod:`.path`.
"""

from __future__ import annotations

import logging
import time
from typing import Protocol

from petsc4py import PETSc

from bhem_hpc.solver.petsc import SNES_REASONS, SolverError
from bhem_hpc.solver.problem import ShellProblem
from bhem_hpc.solver.report import SolveReport

log = logging.getLogger(__name__)


class StaticSolver(Protocol):
    """What load stepping needs of a Newton solver."""

    prefix: str
    x: PETSc.Vec
    snes: PETSc.SNES
    problem: ShellProblem
    report: SolveReport

    def solve_at(self, load_factor: float) -> bool:
        """One Newton solve at ``load_factor`` from ``x``; whether it converged."""

    def negative_pivots(self) -> int:
        """Negative pivots of the last factorization (-1: unknown)."""

    def raise_failure(self, factor: float, after: str) -> None:
        """Raise the error of a solve that failed at load ``factor``."""


def solve_in_load_steps(solver: StaticSolver, load_steps: int = 1, max_cuts: int = 10) -> SolveReport:
    """Solve ``solver``'s problem for equilibrium, ramping loads and prescribed values from 0 to 1.

    The load factor advances in increments of at most ``1 / load_steps``; a load step whose
    Newton solve fails is retried from the last equilibrium with half the increment (at most
    ``max_cuts`` halvings in a row), and the increment grows back after successes. Each step
    starts from a secant prediction along the last two equilibria.

    Raises:
        SolverError: naming the solver, the load factor and the SNES/KSP reasons.
    """
    if isinstance(load_steps, bool) or not isinstance(load_steps, int) or load_steps < 1:
        raise SolverError(f"solver '{solver.prefix}': load_steps must be an integer >= 1, got {load_steps!r}")
    start = time.perf_counter()
    max_increment = 1.0 / load_steps
    increment = max_increment
    solver.problem.state_to_vector(solver.x)
    accepted = solver.x.copy()
    history: list[tuple[float, PETSc.Vec]] = []
    factor, cuts = 0.0, 0
    while factor < 1.0 - 1e-12:
        trial = min(1.0, factor + increment)
        accepted.copy(solver.x)
        if history:
            # Secant predictor: continue the path of the last two equilibria (captures the
            # in-plane pull-in that a Newton step linearized at the last state misses).
            last_factor, last = history[-1]
            solver.x.axpy((trial - factor) / (factor - last_factor), accepted - last)
        if not solver.solve_at(trial):
            cuts += 1
            solver.report.cuts += 1
            if cuts > max_cuts:
                solver.raise_failure(trial, f"{max_cuts} halvings of the load increment")
            log.info(
                "%s: Newton failed at load factor %.4g (%s); halving the increment to %.3g",
                solver.prefix,
                trial,
                SNES_REASONS.get(solver.snes.getConvergedReason()),
                increment / 2,
            )
            increment /= 2
            continue
        cuts = 0
        its = solver.snes.getIterationNumber()
        solver.report.newton_iterations.append(its)
        solver.report.residual_norms.append(solver.snes.getFunctionNorm())
        solver.report.negative_pivots.append(solver.negative_pivots())
        solver.report.load_steps += 1
        log.info(
            "%s: load factor %.4g: %d Newton iterations, |F| = %.3e",
            solver.prefix,
            trial,
            its,
            solver.snes.getFunctionNorm(),
        )
        if history:
            history[0][1].destroy()
        history = [(factor, accepted)]
        accepted = solver.x.copy()
        factor = trial
        increment = min(max_increment, 2 * increment)
    for _, vec in history:
        vec.destroy()
    accepted.destroy()
    solver.problem.update_state(solver.x)
    solver.report.wall_s += time.perf_counter() - start
    return solver.report

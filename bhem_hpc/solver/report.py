"""What a Newton solve did, counted as it goes (no PETSc: the problem and the driver both add to it)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from bhem_hpc.solver.reuse import FactorizationReuse


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
    projected_iterations: int = 0
    trust_region_solves: int = 0
    trust_region_failures: int = 0  # time steps the energy trust region left to line-search Newton
    multiplier_updates: int = 0
    bounded_steps: int = 0  # line-search steps shortened by a contribution's bound
    refactor_retries: int = 0
    krylov_iterations: int = 0
    linear_solves: int = 0
    assemble_residual_s: float = 0.0
    assemble_jacobian_s: float = 0.0
    #: matrix-free Hessian products (:mod:`~bhem_hpc.solver.hessian_action`): assemblies that run
    #: within the linear solves, counted as assembly, not as solving
    hessian_products_s: float = 0.0
    wall_s: float = 0.0


def solver_counters(
    report: SolveReport, reuse: FactorizationReuse, factorization_s: float, linear_solve_s: float
) -> dict[str, float]:
    """A solver's cumulative figures: ``report``'s counts and timings, the factorization policy
    ``reuse``'s (:class:`~bhem_hpc.solver.reuse.FactorizationReuse`) and the PETSc timings of this
    process; ``negative_pivots`` is the last factorization's."""
    return {
        "assembly_s": report.assemble_residual_s + report.assemble_jacobian_s + report.hessian_products_s,
        "factorization_s": factorization_s,
        "linear_solve_s": linear_solve_s - report.hessian_products_s,
        "regularized_retries": report.regularized_retries,
        "regularized_iterations": report.regularized_iterations,
        "projected_iterations": report.projected_iterations,
        "trust_region_solves": report.trust_region_solves,
        "trust_region_failures": report.trust_region_failures,
        "negative_pivots": report.negative_pivots[-1] if report.negative_pivots else -1,
        "refactorizations": reuse.refactorizations,
        "chord_iterations": reuse.chord_iterations,
        "refactor_retries": report.refactor_retries,
        "krylov_iterations": report.krylov_iterations,
        "linear_solves": report.linear_solves,
    }

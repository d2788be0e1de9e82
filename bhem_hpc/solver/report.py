"""What a Newton solve did, counted as it goes (no PETSc: the problem and the driver both add to it)."""

from __future__ import annotations

from dataclasses import dataclass, field


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
    multiplier_updates: int = 0
    bounded_steps: int = 0  # line-search steps shortened by a contribution's bound
    refactor_retries: int = 0
    krylov_iterations: int = 0
    linear_solves: int = 0
    assemble_residual_s: float = 0.0
    assemble_jacobian_s: float = 0.0
    wall_s: float = 0.0

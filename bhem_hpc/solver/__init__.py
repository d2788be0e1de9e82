"""PETSc solvers: the Newton driver (:mod:`.newton`), implicit Euler stepping (:mod:`.dynamics`)
and the PETSc utilities they share (:mod:`.petsc`)."""

from bhem_hpc.solver.newton import ShellSolver, SolveReport
from bhem_hpc.solver.petsc import SolverError

__all__ = ["ShellSolver", "SolveReport", "SolverError"]

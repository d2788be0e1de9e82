"""Solvers: the Newton driver (:mod:`.newton`), implicit Euler stepping (:mod:`.dynamics`), path
following (:mod:`.path`), the PETSc utilities they share (:mod:`.petsc`), the linear strategy's
options and MUMPS switch (:mod:`.linear_strategy`), and, without PETSc, the refactor policy
(:mod:`.reuse`), Anderson mixing (:mod:`.anderson`), the choice of linear solver (:mod:`.linear`)
and the solve report (:mod:`.report`).

``ShellSolver``, ``SolveReport`` and ``SolverError`` load PETSc when first asked for, so the
PETSc-free modules import alone (a scene is checked without PETSc).
"""

from __future__ import annotations

from importlib import import_module

__all__ = ["ShellSolver", "SolveReport", "SolverError"]
_HOMES = {"ShellSolver": "bhem_hpc.solver.newton", "SolveReport": "bhem_hpc.solver.report",
          "SolverError": "bhem_hpc.solver.petsc"}  # fmt: skip


def __getattr__(name: str):
    if name in _HOMES:
        return getattr(import_module(_HOMES[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

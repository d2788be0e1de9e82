"""The acceleration residual of a time step, and the Newton stopping test on it
(``solver.acceleration_tolerance``).

A time step's residual is a force, ``r = M (x - x_pred) / dt^2 + f_int(x) - f_ext`` on the closed
DOFs. The acceleration it leaves unbalanced is ``M^-1 r``; its root-mean-square over the shell's
mass ``m``,

    a_rms = sqrt(r^T M^-1 r / m)   [m/s^2],

means the same whatever the discretization, the resolution and the DOF kinds (Hermite derivative
DOFs carry other units than positions): a uniform acceleration field ``a`` gives ``|a|``, so
gravity's load vector alone gives 9.81. Where inertia dominates the stiffness (``M / dt^2`` against
``K``), the position error a step leaves is about ``a_rms dt^2`` in the mass-weighted mean.

With a tolerance, Newton (the SNES, and the energy trust region's TAO) stops once ``a_rms`` is
below it, instead of at the relative tolerances ``rtol`` / ``gttol``, whose meaning depends on how
far a step's first guess was off; the absolute floor ``atol`` (round-off of the internal force)
still ends a solve. This is the acceleration criterion of Longva et al. (2023, "Pitfalls of
projection"), in the mass norm.

The test solves with ``M`` only where it can pass: ``r^T M^-1 r >= |r|^2 / lambda_max(M)``, and the
largest absolute row sum of ``M`` bounds ``lambda_max`` (:func:`certainly_above`); far from
convergence that bound already exceeds the tolerance.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import dolfinx.fem as fem
import dolfinx.fem.petsc as fem_petsc
import numpy as np
import ufl
from petsc4py import PETSc

from bhem_hpc import forms
from bhem_hpc.model.jit import compilation_report, default_jit_params
from bhem_hpc.model.shell import ShellModel
from bhem_hpc.solver.petsc import KSP_REASONS, PetscOwner, SolverError, push_options

if TYPE_CHECKING:
    from bhem_hpc.solids.acceleration import SolidAccelerationResidual
    from bhem_hpc.solver.newton import ShellSolver

#: The mass solve's defaults: a Cholesky factorization made once per run (MUMPS) for the direct
#: linear strategy; conjugate gradients on incomplete Cholesky blocks for the iterative one
#: (``M`` is well conditioned; ``a_rms`` needs a few digits).
DIRECT_MASS_OPTIONS = {"ksp_type": "preonly", "pc_type": "cholesky", "pc_factor_mat_solver_type": "mumps",
                       "mat_mumps_icntl_7": "2"}  # fmt: skip
ITERATIVE_MASS_OPTIONS = {"ksp_type": "cg", "pc_type": "bjacobi", "sub_pc_type": "icc", "ksp_rtol": "1e-6",
                          "ksp_max_it": "500"}  # fmt: skip


class AccelerationResidual(PetscOwner):
    """``a_rms`` of residual vectors on a time-stepped :class:`ShellModel`'s closed DOFs.

    Args:
        model: the shell model (dynamic: it has a mass).
        prolongation: the seam prolongation ``P`` of the problem (open = ``P`` closed), or None.
        constrained_rows: global closed rows held by constraints (left out: they hold ``x - x_bc``).
        constrained_local: the same rows as local indices of this rank's closed vector.
        prefix: PETSc options prefix of the mass solve.
        direct: factor ``M`` (MUMPS) rather than iterate on it.
    """

    def __init__(self, model: ShellModel, prolongation: PETSc.Mat | None, constrained_rows: np.ndarray,
                 constrained_local: np.ndarray, prefix: str, direct: bool = True):  # fmt: skip
        if model.dynamics is None:
            raise ValueError("an acceleration residual needs a time-stepped model (its mass)")
        self.prefix = prefix
        self._closed = False
        self.constrained_local = np.asarray(constrained_local, dtype=np.int64)
        space = model.discretization.function_space
        jit = default_jit_params()
        with compilation_report("the mass matrix", jit["cache_dir"]):
            trial, test = ufl.TrialFunction(space), ufl.TestFunction(space)
            mass = forms.mass_matrix(trial, test, model.x_rest, model.density, model.thickness, model.dx)
            total = forms.total_mass(model.x_rest, model.density, model.thickness, model.dx)
            mass_form, total_form = (fem.form(model.in_unknowns(f), jit_params=jit) for f in (mass, total))
        self.mass = float(model.comm.allreduce(fem.assemble_scalar(total_form)))
        if not self.mass > 0:
            raise ValueError(f"an acceleration residual needs a positive mass, got {self.mass!r} kg")
        open_mass = fem_petsc.assemble_matrix(mass_form)
        open_mass.assemble()
        if prolongation is None:
            self.matrix = open_mass
        else:
            self.matrix = open_mass.PtAP(prolongation)
            open_mass.destroy()
        self._solve_with_matrix(constrained_rows, model.comm, direct)

    def _solve_with_matrix(self, constrained_rows: np.ndarray, comm, direct: bool) -> None:
        """The mass solve of :attr:`matrix` (``M`` on the closed DOFs; its held rows and columns
        become the identity's) under :attr:`prefix`."""
        # the largest absolute row sum, before the held rows become the identity: at least the
        # largest eigenvalue of M restricted to the free DOFs (symmetric), which r^T M^-1 r sees
        self.largest_eigenvalue_bound = self.matrix.norm(PETSc.NormType.INFINITY)
        self.matrix.zeroRowsColumns(np.asarray(constrained_rows, dtype=PETSc.IntType), diag=1.0)
        self.matrix.setOption(PETSc.Mat.Option.SPD, True)
        self.ksp = PETSc.KSP().create(comm)
        self.ksp.setOptionsPrefix(self.prefix)
        self.ksp.setOperators(self.matrix)
        pushed = push_options(self.prefix, DIRECT_MASS_OPTIONS if direct else ITERATIVE_MASS_OPTIONS, {})
        try:
            self.ksp.setFromOptions()
        finally:
            opts = PETSc.Options()
            for name in pushed:
                opts.delValue(name)
        self.force = self.matrix.createVecLeft()
        self.acceleration = self.matrix.createVecRight()
        #: ``a_rms`` of the last residual asked about [m/s^2]
        self.last = float("nan")

    def rms(self, residual: PETSc.Vec) -> float:
        """Collective: ``a_rms`` of ``residual`` (closed layout; its constrained rows left out)."""
        self.last = float(np.sqrt(self.mass_norm_squared(residual.array_r) / self.mass))
        return self.last

    def mass_norm_squared(self, residual: np.ndarray) -> float:
        """Collective: ``r^T M^-1 r`` of this rank's owned entries ``residual`` of a closed residual
        (constrained rows left out) [N^2 / kg]."""
        self._load_free_force(residual)
        self.ksp.solve(self.force, self.acceleration)
        reason = self.ksp.getConvergedReason()
        if reason < 0:
            raise SolverError(f"KSP solver '{self.prefix}' (the mass solve of the acceleration residual) failed: "
                              f"{KSP_REASONS.get(reason, reason)}")  # fmt: skip
        return max(self.force.dot(self.acceleration), 0.0)

    def lower_bound_squared(self, residual: np.ndarray) -> float:
        """Collective: a lower bound of :meth:`mass_norm_squared` without a solve,
        ``|r|^2 / largest_eigenvalue_bound`` [N^2 / kg]."""
        self._load_free_force(residual)
        return self.force.dot(self.force) / self.largest_eigenvalue_bound

    def _load_free_force(self, residual: np.ndarray) -> None:
        """``force``: this rank's owned entries ``residual``, its constrained rows zero."""
        self.force.array[:] = residual
        if len(self.constrained_local):
            self.force.array[self.constrained_local] = 0.0

    def close(self) -> None:
        """Destroy the mass matrix, its solver and vectors (idempotent)."""
        if self._closed:
            return
        self._closed = True
        for obj in (self.ksp, self.matrix, self.force, self.acceleration):
            obj.destroy()


class BodiesAccelerationResidual(PetscOwner):
    """``a_rms`` of several bodies in one residual: ``sqrt(sum_b r_b^T M_b^-1 r_b / sum_b m_b)``, each
    body's mass its own (the bodies' mass matrix is block diagonal).

    Args:
        residuals: one :class:`AccelerationResidual` per body (owned and closed by this object).
        slices: where each body's closed DOFs sit in this rank's part of the stacked residual.
    """

    def __init__(self, residuals: list[AccelerationResidual | SolidAccelerationResidual], slices: list[slice]):
        self.residuals, self.slices = residuals, slices
        self.mass = sum(r.mass for r in residuals)
        self._closed = False
        self.last = float("nan")

    def rms(self, residual: PETSc.Vec) -> float:
        """Collective: ``a_rms`` of the stacked ``residual``."""
        values = residual.array_r
        parts = zip(self.residuals, self.slices, strict=True)
        total = sum(body.mass_norm_squared(values[part]) for body, part in parts)
        self.last = float(np.sqrt(total / self.mass))
        return self.last

    def lower_bound_squared(self, values: np.ndarray) -> float:
        """Collective: the sum of the bodies' lower bounds of ``r_b^T M_b^-1 r_b`` [N^2 / kg]."""
        parts = zip(self.residuals, self.slices, strict=True)
        return sum(body.lower_bound_squared(values[part]) for body, part in parts)

    def close(self) -> None:
        """Close every body's residual (idempotent)."""
        if self._closed:
            return
        self._closed = True
        for residual in self.residuals:
            residual.close()


@dataclass(frozen=True)
class AccelerationTest:
    """A solver's acceleration stopping test: the residual's measure and its tolerance [m/s^2]."""

    residual: AccelerationResidual | BodiesAccelerationResidual | SolidAccelerationResidual
    tolerance: float


def certainly_above(
    residual: AccelerationResidual | BodiesAccelerationResidual | SolidAccelerationResidual, vector: PETSc.Vec,
    tolerance: float,
) -> bool:  # fmt: skip
    """Collective: whether ``a_rms`` of ``vector`` exceeds ``tolerance`` by its lower bound alone."""
    return residual.lower_bound_squared(vector.array_r) > tolerance**2 * residual.mass


def _passes(
    residual: AccelerationResidual | BodiesAccelerationResidual | SolidAccelerationResidual, vector: PETSc.Vec,
    tolerance: float,
) -> bool:  # fmt: skip
    """Collective: ``a_rms`` of ``vector`` at most ``tolerance`` (a mass solve only where the bound allows it)."""
    return not certainly_above(residual, vector, tolerance) and residual.rms(vector) <= tolerance


def snes_acceleration_test(
    snes: PETSc.SNES, iteration: int, norms: tuple[float, float, float], residual: AccelerationResidual,
    tolerance: float,
) -> int:  # fmt: skip
    """SNES convergence test (``snes.setConvergenceTest(..., kargs={"residual": ..., "tolerance": ...})``):
    converged once ``a_rms`` of the current residual is at most ``tolerance`` [m/s^2], or its 2-norm is
    below ``atol`` (round-off); diverged on a non-finite residual. A step that stopped moving (below
    ``stol``) is reported as such, for the driver to judge. ``norms = (|x|, |step|, |F|)``."""
    _, atol, stol, _ = snes.getTolerances()
    x_norm, step_norm, f_norm = norms
    reasons = PETSc.SNES.ConvergedReason
    if not np.isfinite(f_norm):
        return reasons.DIVERGED_FNORM_NAN
    # an absolute test on the residual, in the mass norm: SNES 3.18 has no reason of the user's
    if f_norm < atol or _passes(residual, snes.getFunction()[0], tolerance):
        return reasons.CONVERGED_FNORM_ABS
    if iteration and step_norm < stol * x_norm:
        return reasons.CONVERGED_SNORM_RELATIVE
    return reasons.ITERATING


def tao_stopping_test(tao: PETSc.TAO, residual: AccelerationResidual | None, tolerance: float,
                      step_small: Callable[[PETSc.TAO], bool] | None = None) -> None:  # fmt: skip
    """TAO convergence test (``tao.setConvergenceTest``): ``CONVERGED_USER`` once ``a_rms`` of the
    current gradient is at most ``tolerance`` [m/s^2] (with a ``residual``) or once ``step_small(tao)``
    (the solver's step test); ``CONVERGED_GATOL`` below ``gatol``; diverged on non-finite values or
    at the iteration limit."""
    iteration, value, gradient_norm = tao.getSolutionStatus()[:3]
    gatol, _, _ = tao.getTolerances()
    reasons = PETSc.TAO.Reason
    if not (np.isfinite(value) and np.isfinite(gradient_norm)):
        reason = reasons.DIVERGED_NAN
    elif gradient_norm <= gatol:
        reason = reasons.CONVERGED_GATOL
    elif residual is not None and _passes(residual, tao.getGradient()[0], tolerance):
        reason = reasons.CONVERGED_USER
    elif step_small is not None and step_small(tao):
        reason = reasons.CONVERGED_USER
    elif iteration >= tao.getMaximumIterations():
        reason = reasons.DIVERGED_MAXITS
    else:
        reason = reasons.CONTINUE_ITERATING
    tao.setConvergedReason(reason)


def attach_acceleration_test(solver: ShellSolver, tolerance: float) -> AccelerationTest:
    """Make ``solver``'s SNES stop at ``a_rms <= tolerance`` [m/s^2] (its mass solve under the prefix
    ``<solver prefix>mass_``); the energy trust region takes the test from ``solver.acceleration``."""
    if not (np.isfinite(tolerance) and tolerance > 0):
        raise ValueError(f"acceleration_tolerance must be a number > 0 [m/s^2], got {tolerance!r}")
    # several bodies: each body's mass solve under its own prefix, <prefix>mass_<body>_
    residual = solver.problem.acceleration_residual(solver.prefix + "mass_", solver.linear.kind == "direct")
    solver.snes.setConvergenceTest(snes_acceleration_test, kargs={"residual": residual, "tolerance": tolerance})
    return AccelerationTest(residual, tolerance)

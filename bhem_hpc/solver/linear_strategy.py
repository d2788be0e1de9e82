"""The linear strategy of the Newton driver, apart from Newton: which linear solver (MUMPS or a
Krylov method) with which options, and the switch to MUMPS when a Krylov solve fails. The refactor
policy (:mod:`.reuse`) and the Anderson mixing of chord steps (:mod:`.anderson`) are the other two
parts; :class:`~bhem_hpc.solver.newton.ShellSolver` combines them.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import TYPE_CHECKING

import numpy as np
from petsc4py import PETSc

from bhem_hpc.bodies.layout import body_array_name
from bhem_hpc.solver.linear import LinearSolverChoice, available_memory, choose_linear_solver, mass_dominance
from bhem_hpc.solver.model_group import BodyModel
from bhem_hpc.solver.reuse import refactor_cost

if TYPE_CHECKING:
    from bhem_hpc.solver.problem import ShellProblem
    from bhem_hpc.solver.reuse import FactorizationReuse

log = logging.getLogger(__name__)
#: Jacobian nonzeros per DoF for the memory estimate of a factorization (Hermite ~100, B-splines
#: of degree 2 and 3 ~130: a bound for sizing, not a count).
NONZEROS_PER_DOF = 130
#: A Jacobian assembly and its preconditioner's setup, in Krylov-solved chord iterations.
ITERATIVE_REFACTOR_COST = 8.0


def linear_refactor_cost(kind: str, dofs: int, step_bounded: bool) -> float:
    """The refactor policy's cost of a new Jacobian and its factorization (or preconditioner), in
    chord iterations, for the linear strategy ``kind`` on ``dofs`` unknowns (:func:`refactor_cost`)."""
    if kind != "direct":  # a Krylov solve costs about as much as assembling its preconditioner
        return ITERATIVE_REFACTOR_COST
    return refactor_cost(dofs, step_bounded)


def default_options(model: BodyModel, linear: str = "direct") -> dict[str, str]:
    """Solver defaults for a model and a linear solver kind (all overridable under the prefix)."""
    # Absolute residual floor: round-off of the internal force is ~eps * its scale (a shell's
    # Y h * patch size)
    force_scale = model.force_scale
    nonlinear = {
        "snes_type": "newtonls",
        # Conservative problems: full step damped by the energy precheck (ShellSolver.damp_step).
        # Follower loads have no potential: full steps too, a failed solve cut back by the caller's
        # load or time steps. Backtracking on the residual norm crawls where the membrane is much
        # stiffer than bending (an end moment on a flat strip: the linear step's stretching raises
        # |F|, steps of 0.1 are taken, 30 iterations at 1/1000 of the load).
        "snes_linesearch_type": "basic",
        "snes_rtol": "1e-9",
        "snes_atol": f"{1e-13 * force_scale:.3e}",
        "snes_stol": "1e-14",
        "snes_max_it": "30",
    }
    if linear == "direct":
        return default_direct_options(model) | nonlinear
    dynamic = model.dynamics is not None
    krylov = {
        # flexible GMRES for time steps (their preconditioner is not symmetric, below; it keeps the
        # preconditioned directions, so forming the solution takes no extra application); GMRES for
        # statics (K may be indefinite along a path)
        "ksp_type": "fgmres" if dynamic else "gmres",
        # inexact Newton: the nonlinear test is on the true residual. Time steps: the Anderson-mixed
        # chord steps make up for a crude solve (1e-2 cost fewer Krylov iterations in all than 1e-3 on
        # the million-DoF cloth scene); statics end with Newton steps, which need accurate ones
        "ksp_rtol": "1e-2" if dynamic and model.symmetric else "1e-3",
        "ksp_atol": f"{1e-15 * force_scale:.3e}",
        "ksp_max_it": "1000",
        "ksp_norm_type": "unpreconditioned",
    }
    if dynamic:  # M / dt^2 + K: ILU(0) of each rank's rows grown by one layer of its neighbours'
        # (restricted additive Schwarz): without the overlap (block Jacobi) the coupling across rank
        # boundaries is lost and the Krylov iterations grow with the rank count. One rank: block
        # Jacobi, the same preconditioner without Schwarz's copy of the matrix.
        schwarz = {"pc_type": "asm", "pc_asm_overlap": "1", "pc_asm_type": "restrict"}
        pc = schwarz if model.comm.size > 1 else {"pc_type": "bjacobi"}
        pc |= {"sub_pc_type": "ilu", "sub_pc_factor_shift_type": "nonzero"}
    else:  # K alone: algebraic multigrid with the three displacement components coarsened together
        pc = {"pc_type": "hypre", "pc_hypre_type": "boomeramg", "pc_hypre_boomeramg_nodal_coarsen": "6",
              "pc_hypre_boomeramg_vec_interp_variant": "3", "pc_hypre_boomeramg_strong_threshold": "0.5"}  # fmt: skip
    return nonlinear | krylov | pc


def default_direct_options(model: BodyModel) -> dict[str, str]:
    """The direct solver's options (MUMPS)."""
    return {
        "ksp_type": "preonly",
        "pc_type": "cholesky" if model.symmetric else "lu",
        "pc_factor_mat_solver_type": "mumps",
        # Debian's MUMPS has no METIS: AMF (2) was the fastest of the built-in orderings here.
        "mat_mumps_icntl_7": "2",
        # workspace 100 % above the analysis' estimate (MUMPS' default: 20 %): delayed pivots of an
        # indefinite LDL^T on 2 ranks overran it (INFOG(1) = -9: a hairpin's arms meeting by IPC)
        "mat_mumps_icntl_14": "100",
    }


def choose_for_model(model: BodyModel, requested: str, available: float | None = None) -> LinearSolverChoice:
    """The linear solver for ``model``: ``requested`` (``"direct"``, ``"iterative"`` or ``"auto"``),
    judged by its size, how much the mass term dominates its stiffness and the memory ``available``
    (bytes; default: what this machine has free).

    Raises:
        LinearSolverError: an unknown ``requested`` or a direct solver that would not fit.
    """
    return choose_for_models([model], requested, available)


def choose_for_models(models: Sequence[BodyModel], requested: str, available: float | None = None
                      ) -> LinearSolverChoice:  # fmt: skip
    """:func:`choose_for_model` for several bodies in one solve: their DoFs added up, the mass
    dominance of the least mass-dominated body (the one a Krylov solve would struggle with)."""
    dofs = sum(model.closed_dofs[1] for model in models)
    dominance = min(map(_mass_dominance, models))
    first = models[0]
    available = available_memory(first.comm) if available is None else available
    return choose_linear_solver(requested, dofs, NONZEROS_PER_DOF * dofs, dominance, available,
                                first.dynamics is not None)  # fmt: skip


def _mass_dominance(model: BodyModel) -> float:
    density, young, poisson, element = model.linear_scales
    dt = float(model.time_step.value) if model.dynamics is not None else None
    return mass_dominance(density, young, poisson, element, dt)


def switch_to_mumps(ksp: PETSc.KSP, symmetric: bool, matrix_format: str) -> None:
    """Make ``ksp`` a MUMPS direct solve: LDL^T of a symmetric AIJ or SBAIJ matrix, else LU (the
    blocked matrix of the Krylov path)."""
    ksp.setType("preonly")
    pc = ksp.getPC()
    pc.setType("cholesky" if symmetric and matrix_format != "baij" else "lu")
    pc.setFactorSolverType("mumps")


class FactoredState:
    """The state a kept factorization's Jacobian was assembled at: each body's position (open DOFs,
    as assembled), in dynamics its previous position (stiffness damping), and the Hessian kind (its
    index among the problem's kinds: the adaptive Hessian changes kind within a time step). A
    checkpoint stores it so that a continued run remakes the same factorization.

    Args:
        models: the bodies' models in the problem's order (one for a single body).
    """

    def __init__(self, models: Sequence[BodyModel]):
        self.models = list(models)
        #: per body: (position, previous position or None), None before the first assembly
        self.arrays: list[tuple[np.ndarray, np.ndarray | None]] | None = None
        self.kind = 0

    def _current(self) -> list[tuple[np.ndarray, np.ndarray | None]]:
        return [m.open_state() for m in self.models]

    def _key(self, name: str, body: int) -> str:
        return body_array_name(name, body, len(self.models))

    def remember(self, kind: int) -> None:
        """The Jacobian of Hessian kind ``kind`` was just assembled at the models' current state."""
        self.arrays, self.kind = self._current(), kind

    def checkpoint(self, reuse: FactorizationReuse) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        """Collective: the remembered state as raw DOFs, and the refactor policy's state with the
        Hessian kind (both empty when no factorization is kept), for :meth:`restore`."""
        if self.arrays is None or not reuse.valid:
            return {}, {}
        arrays = {}
        for body, (model, (position, previous)) in enumerate(zip(self.models, self.arrays, strict=True)):
            arrays[self._key("factorization_state_dofs", body)] = model.gather_raw(position)
            if previous is not None:
                arrays[self._key("factorization_previous_dofs", body)] = model.gather_raw(previous)
        return arrays, reuse.state() | {"hessian_kind": self.kind}

    def restore(self, arrays: dict[str, np.ndarray], state: dict[str, float], problem: ShellProblem,
                ksp: PETSc.KSP) -> None:  # fmt: skip
        """Collective: assemble the Jacobian at a checkpoint's factored state, with the Hessian kind it
        was made with (a checkpoint without one: the problem's current kind), and factor it."""
        kinds, current = problem.hessian_kinds(), problem.hessian
        kind = state.get("hessian_kind", -1)
        ours = isinstance(kind, int | float | np.number) and 0 <= kind < len(kinds)
        with self.restored(arrays, int(kind) if ours else kinds.index(current)):
            problem.hessian = kinds[self.kind]
            try:
                problem.assemble_jacobian(problem.jacobian)
            finally:
                problem.hessian = current
            ksp.setOperators(problem.jacobian)
            ksp.setUp()

    @contextmanager
    def restored(self, arrays: dict[str, np.ndarray], kind: int) -> Iterator[None]:
        """Collective: within the block the models are at the checkpoint's factored state of Hessian
        kind ``kind`` (remembered); afterwards back at their own."""
        saved = self._current()
        for body, model in enumerate(self.models):
            position = model.scatter_raw(arrays[self._key("factorization_state_dofs", body)])
            previous = None
            if model.dynamics is not None:
                previous = model.scatter_raw(arrays[self._key("factorization_previous_dofs", body)])
            model.set_open_state(position, previous)
        self.remember(kind)
        try:
            yield
        finally:
            for model, (position, previous) in zip(self.models, saved, strict=True):
                model.set_open_state(position, previous)

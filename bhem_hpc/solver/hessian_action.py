"""The exact Hessian of a shell problem as a matrix-free operator (a PETSc ``python`` matrix): the
energy trust region's quadratic model, applied by assembling the directional derivative of the
residual instead of assembling the matrix.

Steihaug's conjugate gradients need the exact Hessian only through products with it, a handful per
trust-region iteration; the matrix itself costs an assembly per iteration (and, with B-splines, the
product ``P^T J P`` onto the control points). A product assembles the linear form
``dF(x)[w]`` (the UFL derivative of the residual in the direction ``w``), which costs about one
residual assembly, and adds the contributions' Hessian blocks (point constraints, barriers) from a
small matrix of their own, assembled once per iterate. Constrained rows and columns act as the
assembled Jacobian's: the identity.
"""

from __future__ import annotations

import time

import dolfinx.fem as fem
import dolfinx.fem.petsc as fem_petsc
import numpy as np
import ufl
from petsc4py import PETSc

from bhem_hpc.model.jit import compilation_report, default_jit_params
from bhem_hpc.solver.petsc import PetscOwner
from bhem_hpc.solver.problem import ShellProblem


class ExactHessianAction(PetscOwner):
    """``y = H(x_k) w`` on the closed DOFs of a :class:`ShellProblem`, at the iterate ``x_k`` last
    given to :meth:`set_iterate`; :attr:`matrix` is the PETSc operator (sizes of the problem's Jacobian).

    Args:
        problem: a single shell's problem without a diagonal regularizer while it is used.
    """

    def __init__(self, problem: ShellProblem):
        self.problem = problem
        self._closed = False
        model = problem.model
        space = model.discretization.function_space
        #: the direction on the open DOFs (with ghosts)
        self.direction = fem.Function(space, name="hessian_direction")
        jit = default_jit_params()
        with compilation_report("the exact Hessian's action", jit["cache_dir"]):
            self.form = fem.form(ufl.derivative(model.ufl_residual, model.x, self.direction), jit_params=jit)
        self.product_open = fem_petsc.create_vector(self.form)
        self.closed_direction = problem.jacobian.createVecRight()
        n_open = self.product_open.getSizes()
        self.contributions_hessian = PETSc.Mat().createBAIJ((n_open, n_open), bsize=3, nnz=1, comm=model.comm)
        self.contributions_hessian.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, False)
        self.contributions_hessian.setUp()
        self.contributions_product = self.product_open.duplicate()
        self._iterate_open = model.x.x.array.copy()
        self.matrix = PETSc.Mat().createPython(problem.jacobian.getSizes(), context=self, comm=model.comm)
        self.matrix.setUp()

    def set_iterate(self) -> None:
        """Collective: take the problem's current state as the iterate the operator is the Hessian at
        (its contributions' blocks assembled now)."""
        start = time.perf_counter()
        problem = self.problem
        if problem.regularization > 0:
            raise ValueError("the matrix-free Hessian has no diagonal regularizer; assemble the Jacobian instead")
        self._iterate_open = problem.model.x.x.array.copy()
        hessian = self.contributions_hessian
        hessian.zeroEntries()
        problem.add_contribution_hessians(hessian)
        hessian.assemble()
        problem.report.assemble_jacobian_s += time.perf_counter() - start

    def mult(self, mat: PETSc.Mat, w: PETSc.Vec, y: PETSc.Vec) -> None:
        """PETSc's product callback: ``y = H w`` (closed DOFs)."""
        start = time.perf_counter()
        problem = self.problem
        state = problem.model.x.x.array
        if not np.array_equal(state, self._iterate_open):  # a trial point was evaluated since
            state[:] = self._iterate_open
        w.copy(self.closed_direction)
        if len(problem.bc_local):  # the constrained columns are zero
            self.closed_direction.array[problem.bc_local] = 0.0
        problem.open_direction(self.closed_direction, self.direction.vector)
        product = self.product_open
        with product.localForm() as local:
            local.set(0.0)
        fem_petsc.assemble_vector(product, self.form)
        product.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        self.contributions_hessian.mult(self.direction.vector, self.contributions_product)
        product.axpy(1.0, self.contributions_product)
        problem.to_closed(product, y)
        if len(problem.bc_local):  # the constrained rows are the identity's
            y.array[problem.bc_local] = w.array_r[problem.bc_local]
        problem.report.hessian_products_s += time.perf_counter() - start

    def close(self) -> None:
        """Destroy the PETSc objects (idempotent)."""
        if self._closed:
            return
        self._closed = True
        for obj in (self.matrix, self.contributions_hessian, self.contributions_product, self.product_open,
                    self.closed_direction):  # fmt: skip
            obj.destroy()


def exact_hessian_action(problem: object) -> ExactHessianAction | None:
    """The matrix-free exact Hessian of ``problem`` where it has one (a single shell's
    :class:`ShellProblem`), else None."""
    return ExactHessianAction(problem) if isinstance(problem, ShellProblem) else None

"""PETSc code of the studies: the tetrahedral FEM reference of the SEM cantilever (dolfinx's
nonlinear problem and Newton solver on P2 tetrahedra)."""

from __future__ import annotations

import numpy as np
import ufl
from dolfinx import fem, geometry, mesh
from dolfinx.fem.petsc import NonlinearProblem
from dolfinx.nls.petsc import NewtonSolver
from mpi4py import MPI
from petsc4py import PETSc

from bhem_hpc.solids.sem import SolidMaterial


def fem_tip_deflection(
    beam: tuple[float, float, float], material: SolidMaterial, gravity: np.ndarray, cells: int = 40
) -> float:
    """The cantilever's tip sag [m] (z displacement at the end face's centre) with P2 tetrahedra
    on ``cells x cells/10 x cells/10`` boxes cut in six, the same Neo-Hookean energy, dolfinx."""
    length, width, height = beam
    comm = MPI.COMM_SELF
    across = max(2, cells // 10)
    domain = mesh.create_box(comm, [np.zeros(3), np.array(beam)], [cells, across, across], mesh.CellType.tetrahedron)
    space = fem.VectorFunctionSpace(domain, ("Lagrange", 2))
    u = fem.Function(space)
    facets = mesh.locate_entities_boundary(domain, 2, lambda x: np.isclose(x[0], 0.0))
    bc = fem.dirichletbc(np.zeros(3, dtype=PETSc.ScalarType), fem.locate_dofs_topological(space, 2, facets), space)
    young, poisson = material.young, material.poisson
    mu, lam = young / (2 * (1 + poisson)), young * poisson / ((1 + poisson) * (1 - 2 * poisson))
    f = ufl.Identity(3) + ufl.grad(u)
    log_j = ufl.ln(ufl.det(f))
    psi = mu / 2 * (ufl.tr(f.T * f) - 3) - mu * log_j + lam / 2 * log_j**2
    weight = fem.Constant(domain, PETSc.ScalarType(tuple(material.density * gravity)))
    dx = ufl.dx(metadata={"quadrature_degree": 4})  # P2 displacements: the energy needs degree 4
    residual = ufl.derivative(psi * dx - ufl.dot(weight, u) * dx, u, ufl.TestFunction(space))
    solver = NewtonSolver(comm, NonlinearProblem(residual, u, [bc]))
    solver.convergence_criterion, solver.rtol, solver.atol = "incremental", 1e-10, 1e-12
    solver.solve(u)
    point = np.array([[length, width / 2, height / 2]])
    tree = geometry.BoundingBoxTree(domain, 3)
    cell = geometry.compute_colliding_cells(domain, geometry.compute_collisions(tree, point), point).links(0)[0]
    return float(u.eval(point, [cell])[2])

"""The bicubic Hermite Basix element: DOF functionals, polynomial space, C1 continuity, solve."""

from __future__ import annotations

import basix
import dolfinx.fem as fem
import dolfinx.fem.petsc as fem_petsc
import numpy as np
import ufl

from bhem_hpc.discretization import HermiteDiscretization
from bhem_hpc.discretization.element import VERTEX_DOF_DERIVATIVES, create_hermite_element
from bhem_hpc.geometry.surface import HermiteSurface, ParameterGrid


def test_kronecker_property():
    element = create_hermite_element()
    assert element.dim == 16 and element.degree == 3
    vertices = basix.geometry(basix.CellType.quadrilateral)
    tab = element.tabulate(2, vertices)  # (derivative, point, basis, value)
    functionals = np.zeros((16, 16))
    for v in range(4):
        for k, (dx, dy) in enumerate(VERTEX_DOF_DERIVATIVES):
            functionals[4 * v + k] = tab[basix.index(dx, dy), v, :, 0]
    np.testing.assert_allclose(functionals, np.eye(16), atol=1e-13)


def test_reproduces_every_bicubic_monomial(rng):
    element = create_hermite_element()
    vertices = basix.geometry(basix.CellType.quadrilateral)
    points = rng.random((25, 2))
    basis = element.tabulate(0, points)[0, :, :, 0]  # (points, 16)
    for a in range(4):
        for b in range(4):

            def d(f_x, f_y, x, y, a=a, b=b):
                # derivative of x^a y^b of orders (f_x, f_y)
                ca = np.prod(range(a - f_x + 1, a + 1)) if f_x <= a else 0.0
                cb = np.prod(range(b - f_y + 1, b + 1)) if f_y <= b else 0.0
                return ca * cb * x ** max(a - f_x, 0) * y ** max(b - f_y, 0)

            dofs = np.array([d(dx, dy, *vertices[v]) for v in range(4) for dx, dy in VERTEX_DOF_DERIVATIVES])
            np.testing.assert_allclose(basis @ dofs, points[:, 0] ** a * points[:, 1] ** b, atol=1e-13)


def _random_surface(rng, n1=3, n2=4):
    grid = ParameterGrid(n1, n2, (0.0, 1.5), (-0.5, 0.7))
    return HermiteSurface(grid, rng.normal(size=(*grid.node_shape, 4, 3)))


def test_c1_continuity_across_interior_edges(comm, rng):
    surface = _random_surface(rng)
    disc = HermiteDiscretization(surface.grid, comm)
    u = fem.Function(disc.function_space)
    u.x.array[:] = disc.surface_to_open(surface)
    t = np.linspace(0.05, 0.95, 7)
    ref_points = np.concatenate(
        [
            np.stack([np.zeros_like(t), t], 1),
            np.stack([np.ones_like(t), t], 1),
            np.stack([t, np.zeros_like(t)], 1),
            np.stack([t, np.ones_like(t)], 1),
        ]
    )
    grad = ufl.grad(u)
    expr = fem.Expression(
        ufl.as_vector([u[i] for i in range(3)] + [grad[i, j] for i in range(3) for j in range(2)]), ref_points
    )
    num_cells = disc.mesh.topology.index_map(2).size_local
    values = expr.eval(np.arange(num_cells, dtype=np.int32)).reshape(num_cells, len(ref_points), 9)
    origin = disc._cell_vertices[:num_cells, 0]
    xi = origin[:, None, :] + np.einsum("ba,pa->pb", disc.jacobian, ref_points)[None]
    keys = np.round(xi.reshape(-1, 2) / 1e-9).astype(np.int64)
    all_keys = np.concatenate(comm.allgather(keys))
    all_values = np.concatenate(comm.allgather(values.reshape(-1, 9)))
    order = np.lexsort(all_keys.T)
    k, v = all_keys[order], all_values[order]
    same = np.all(k[1:] == k[:-1], axis=1)
    assert same.sum() == 7 * ((3 - 1) * 4 + (4 - 1) * 3)  # 7 points on each of 17 interior edges, seen twice
    jumps = np.abs(v[1:][same] - v[:-1][same]).max()
    assert jumps < 1e-12 * np.abs(v).max()
    # and the values match the numpy surface model
    ev = surface.evaluate(xi[..., 0], xi[..., 1])
    np.testing.assert_allclose(values[..., :3], ev.x, atol=1e-12)
    np.testing.assert_allclose(values[..., 3:].reshape(*xi.shape[:2], 3, 2)[..., 0], ev.a1, atol=1e-11)


def test_float64_projection_solve_is_exact_for_bicubics(comm):
    """Assemble a mass matrix and solve an L2 projection of a bicubic field: exact recovery."""
    grid = ParameterGrid(4, 3, (0.0, 2.0), (0.0, 1.0))
    disc = HermiteDiscretization(grid, comm)
    space = disc.function_space
    xi = ufl.SpatialCoordinate(disc.mesh)
    target = ufl.as_vector([xi[0] ** 3 * xi[1] ** 2, xi[0] * xi[1] ** 3 - xi[0] ** 2, 1 + xi[0] ** 2 * xi[1] ** 3])
    u, v = ufl.TrialFunction(space), ufl.TestFunction(space)
    dx = ufl.Measure("dx", metadata={"quadrature_degree": 9})
    problem = fem_petsc.LinearProblem(
        ufl.inner(u, v) * dx,
        ufl.inner(target, v) * dx,
        petsc_options={"ksp_type": "preonly", "pc_type": "lu", "pc_factor_mat_solver_type": "mumps"},
    )
    uh = problem.solve()
    assert uh.x.array.dtype == np.float64
    error = fem.assemble_scalar(fem.form(ufl.inner(uh - target, uh - target) * dx))
    norm = fem.assemble_scalar(fem.form(ufl.inner(target, target) * dx))
    assert comm.allreduce(error) < 1e-24 * comm.allreduce(norm)

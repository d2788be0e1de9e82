"""Parametric nodal data <-> reference-cell DOFs, in one place, checked through dolfinx."""

from __future__ import annotations

import basix
import dolfinx.fem as fem
import numpy as np
import pytest
import ufl

from bhem_hpc.discretization import HermiteDiscretization
from bhem_hpc.geometry import surface as S


@pytest.mark.parametrize(
    "make",
    [
        lambda: S.torus(2.0, 0.7, 6, 5),
        lambda: S.cylinder(1.0, 2.0, 3, 7, seam_angle=0.4),
        lambda: S.from_callable(
            lambda a, b: np.stack([a, 0.5 * b, 0.2 * np.sin(3 * a) * np.cos(b)], axis=-1),
            S.ParameterGrid(5, 3, (0.0, 1.3), (-1.0, 2.0)),
        ),
    ],
)
def test_round_trip_through_dolfinx_at_quadrature_points(comm, make):
    surface = make()
    disc = HermiteDiscretization(surface.grid, comm)
    u = fem.Function(disc.function_space)
    u.x.array[:] = disc.surface_to_open(surface)
    points, _ = basix.make_quadrature(basix.CellType.quadrilateral, 7)
    g = ufl.grad(u)
    gg = ufl.grad(g)
    values = ufl.as_vector(
        [u[i] for i in range(3)] + [g[i, a] for i in range(3) for a in range(2)] + [gg[i, 0, 1] for i in range(3)]
    )
    num_cells = disc.mesh.topology.index_map(2).size_local
    got = fem.Expression(values, points).eval(np.arange(num_cells, dtype=np.int32)).reshape(num_cells, len(points), 12)
    origin = disc._cell_vertices[:num_cells, 0]
    xi = origin[:, None, :] + np.einsum("ba,pa->pb", disc.jacobian, points)[None]
    ref = surface.evaluate(xi[..., 0], xi[..., 1])
    scale = np.abs(surface.nodal).max()
    np.testing.assert_allclose(got[..., 0:3], ref.x, atol=1e-12 * scale)
    np.testing.assert_allclose(got[..., 3:9:2], ref.a1, atol=1e-11 * scale)
    np.testing.assert_allclose(got[..., 4:9:2], ref.a2, atol=1e-11 * scale)
    np.testing.assert_allclose(got[..., 9:12], ref.a12, atol=1e-10 * scale)
    # closed layout round trip (seam nodes once) gives back the nodal data
    back = disc.closed_to_surface(disc.surface_to_closed(surface))
    np.testing.assert_allclose(back.nodal, surface.nodal, rtol=1e-15, atol=1e-15 * scale)
    assert comm.allreduce(disc.num_owned_closed) == disc.num_closed == 4 * surface.grid.num_nodes


def test_point_basis_evaluates_the_surface(comm, rng):
    surface = S.cylinder(1.0, 2.0, 3, 6)
    disc = HermiteDiscretization(surface.grid, comm)
    dofs = disc.surface_to_open(surface).reshape(-1, 3)
    for xi1, xi2 in zip(rng.random(6) * 2.0, rng.random(6) * 4 * np.pi - np.pi, strict=False):
        blocks, values = disc.point_basis(xi1, xi2)
        local = values @ dofs[blocks] if len(blocks) else np.zeros(3)
        owners = comm.allreduce(int(len(blocks) > 0))
        assert owners == 1  # exactly one rank owns the containing cell
        np.testing.assert_allclose(comm.allreduce(local), surface.evaluate(np.array(xi1), np.array(xi2)).x, atol=1e-13)

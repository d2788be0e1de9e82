"""The shell body as the :class:`~bhem_hpc.bodies.body.Body` the solver, contact and output see:
its point map reproduces the surface, its mass is rho h A, its DOF ranges tile the stacked vector."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import RUBBER, SHEET, STEEL
from mpi4py import MPI

from bhem_hpc.bodies.body import Body, ShellBody
from bhem_hpc.run import build_model
from bhem_hpc.scene.loader import load_scene
from bhem_hpc.solver.newton import ShellSolver


def _body(comm, tmp_path, index, discretization, material, origin):
    path = tmp_path / f"{discretization}.toml"
    if comm.rank == 0:
        height = 'height = "0.01 * sin(9.0 * xi1) * xi2"'
        text = SHEET.format(size=0.2, discretization=discretization, origin=origin, time="dt = 0.01\nsteps = 1",
                            rest="", **material)  # fmt: skip
        path.write_text(text.replace('discretization = "', height + '\ndiscretization = "', 1))
    comm.Barrier()
    scene = load_scene(path)
    return ShellBody(discretization, index, scene, build_model(scene, comm))


@pytest.mark.parametrize("discretization", ["hermite", "bspline2", "bspline3"])
def test_the_point_map_gives_the_surface_and_the_mass_is_rho_h_area(comm, shared_tmp_path, rng, discretization):
    body: Body = _body(comm, shared_tmp_path, 0, discretization, RUBBER, [0.0, 0.0, 0.0])
    parameters = rng.uniform(0.0, 0.2, size=(50, 2))
    parameters[:4] = [[0.0, 0.0], [0.2, 0.2], [0.05, 0.2], [0.1, 0.1]]  # corners and patch edges
    entries = body.entries(body.model.x.x.array)
    mapped = body.point_map(parameters) @ entries
    exact = body.scene.surface.evaluate(parameters[:, 0], parameters[:, 1]).x
    assert np.abs(mapped - exact).max() <= 1e-14
    assert body.point_map(parameters).shape == (50, len(entries))
    # the raised sheet's area from its metric, by fine midpoint quadrature of |a1 x a2|
    n = 400
    mid = (np.arange(n) + 0.5) * 0.2 / n
    point = body.scene.surface.evaluate(*np.meshgrid(mid, mid, indexing="ij"))
    area = np.linalg.norm(np.cross(point.a1, point.a2), axis=-1).sum() * (0.2 / n) ** 2
    assert body.mass() == pytest.approx(RUBBER["density"] * RUBBER["thickness"] * area, rel=1e-5)


def test_the_bodies_dof_ranges_tile_the_stacked_vector(comm, shared_tmp_path):
    bodies = [_body(comm, shared_tmp_path, 0, "hermite", STEEL, [0.0, 0.0, 0.0]),
              _body(comm, shared_tmp_path, 1, "bspline2", RUBBER, [0.5, 0.0, 0.0])]  # fmt: skip
    with ShellSolver([b.model for b in bodies], "tiled_") as solver:
        layout = solver.problem.closed
        ranges = [b.dof_range(layout) for b in bodies]
        owned = [3 * b.model.discretization.num_owned_closed for b in bodies]
        assert [r.stop - r.start for r in ranges] == owned
        assert ranges[0].start == 0 and ranges[0].stop == ranges[1].start and ranges[1].stop == layout.size_local
        total = comm.allreduce(layout.size_local, op=MPI.SUM)
        assert total == sum(3 * b.model.discretization.num_closed for b in bodies) == layout.size_global

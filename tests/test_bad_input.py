"""Bad input gets a clear error naming the value, before any assembly."""

from __future__ import annotations

import os
import re

import numpy as np
import pytest
from mpi4py import MPI

from bhem_hpc.discretization import DiscretizationError, HermiteDiscretization, shared_jacobian
from bhem_hpc.geometry import surface as S
from bhem_hpc.model import bcs
from bhem_hpc.model.material import Material, MaterialError
from bhem_hpc.model.shell import LineLoad, Loads, ModelError, PointLoad, ShellModel
from bhem_hpc.solver import ShellSolver, SolverError

GOOD = {"young": 1e6, "poisson": 0.3, "thickness": 0.01, "density": 1.0}


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("young", 0.0, r"material.young = 0.0 is invalid: must be in \(0, 1e15\] Pa"),
        ("young", -5.0, r"material.young = -5.0 is invalid"),
        ("thickness", 0.0, r"material.thickness = 0.0 is invalid: must be in \(0, 1e3\] m"),
        ("thickness", 1e200, r"material.thickness = 1e\+200 is invalid"),
        ("density", -1.0, r"material.density = -1.0 is invalid: must be in \[0, 1e6\]"),
        ("poisson", 0.51, r"material.poisson = 0.51 is invalid: must be in \(-1, 0.5\]"),
        ("poisson", -1.0, r"material.poisson = -1.0 is invalid"),
        ("young", float("nan"), r"material.young = nan is invalid"),
        ("thickness", "1mm", r"material.thickness must be a number, got '1mm'"),
    ],
)
def test_material_errors(field, value, message):
    with pytest.raises(MaterialError, match=message):
        Material(**{**GOOD, field: value})
    assert Material(**{**GOOD, "poisson": 0.5}).poisson == 0.5  # the upper bound is allowed


def test_non_uniform_or_inconsistent_grids_are_rejected(comm):
    cells = np.array([[[0, 0], [1, 0], [0, 1], [1, 1]], [[1, 0], [2, 0], [1, 1], [2, 1]]], dtype=float)
    assert np.allclose(shared_jacobian(cells, (1.0, 1.0), MPI.COMM_SELF), np.eye(2))
    graded = cells.copy()
    graded[1, [1, 3], 0] = 2.5
    with pytest.raises(DiscretizationError, match="do not share one Jacobian"):
        shared_jacobian(graded, (1.0, 1.0), MPI.COMM_SELF)
    flipped = cells.copy()
    flipped[1] = flipped[1][[1, 0, 3, 2]]  # second cell ordered right-to-left
    with pytest.raises(DiscretizationError, match="uniform, consistently ordered grid"):
        shared_jacobian(flipped, (1.0, 1.0), MPI.COMM_SELF)
    skewed = cells.copy()
    skewed[1, 3] += [0.2, 0.0]
    with pytest.raises(DiscretizationError, match="not a parallelogram"):
        shared_jacobian(skewed, (1.0, 1.0), MPI.COMM_SELF)
    sheared = np.array([[[0, 0], [1, 0.5], [0, 1], [1, 1.5]]], dtype=float)
    with pytest.raises(DiscretizationError, match="not axis aligned"):
        shared_jacobian(sheared, (1.0, 1.0), MPI.COMM_SELF)


def test_degenerate_rest_surface_is_rejected_before_assembly(comm):
    grid = S.ParameterGrid(2, 2, (0.0, 1.0), (0.0, 1.0))
    flat = S.flat_rectangle(1.0, 1.0, 2, 2)
    nodal = flat.nodal.copy()
    nodal[:, :, 2] = 0.0  # a2 = 0 everywhere: a line, not a surface
    nodal[:, :, 3] = 0.0
    nodal[:, :, 0, 1] = 0.0
    with pytest.raises(
        S.SurfaceError, match=r"rest surface is degenerate: \|a1 x a2\| = 0.000e\+00 at quadrature point"
    ):
        ShellModel(S.HermiteSurface(grid, nodal), Material(**GOOD), comm=comm)


def test_boundary_conditions_naming_missing_nodes(comm):
    rest = S.flat_rectangle(1.0, 1.0, 2, 2)
    with pytest.raises(
        bcs.BoundaryConditionError,
        match=r"names node \(3, 0\), which does not exist: the grid has nodes \(0..2, 0..2\)",
    ):
        ShellModel(rest, Material(**GOOD), constraints=[bcs.pin(np.array([[3, 0]]))], comm=comm)
    with pytest.raises(bcs.BoundaryConditionError, match="kinds"):
        bcs.prescribe(np.array([[0, 0]]), ["d3"], [0], [1.0])
    with pytest.raises(bcs.BoundaryConditionError, match=r"components \(5,\)"):
        ShellModel(
            rest,
            Material(**GOOD),
            constraints=[bcs.NodalConstraint(np.array([[0, 0]]), (0,), (5,))],
            comm=comm,
        )
    with pytest.raises(bcs.BoundaryConditionError, match="closed in that direction"):
        bcs.edge_nodes(S.cylinder(1.0, 1.0, 2, 4).grid, "xi2_min")
    with pytest.raises(bcs.BoundaryConditionError, match="values of shape"):
        bcs.prescribe(np.array([[0, 0], [1, 0]]), ["x"], [0, 1], np.ones((3, 1, 2))).validate(rest.grid)


def test_bad_loads_and_options(comm):
    rest = S.flat_rectangle(1.0, 1.0, 2, 2)
    material = Material(**GOOD)
    with pytest.raises(ModelError, match=r"loads.gravity must be 3 finite numbers, got \(0, 0\)"):
        ShellModel(rest, material, Loads(gravity=(0, 0)), comm=comm)
    with pytest.raises(ModelError, match=r"loads.line_loads\[0\].edge = 'top'"):
        ShellModel(rest, material, Loads(line_loads=(LineLoad("top", (0, 0, 1)),)), comm=comm)
    with pytest.raises(ModelError, match=r"point_loads\[0\].force"):
        ShellModel(rest, material, Loads(point_loads=(PointLoad(0.5, 0.5, (np.nan, 0, 0)),)), comm=comm)
    with pytest.raises(S.SurfaceError, match="xi1=2.0 lies outside"):
        ShellModel(rest, material, Loads(point_loads=(PointLoad(2.0, 0.5, (0, 0, 1)),)), comm=comm)
    with pytest.raises(ModelError, match="hessian = 'approx'"):
        ShellModel(rest, material, hessian="approx", comm=comm)
    with pytest.raises(ModelError, match="quadrature points per direction = 7"):
        ShellModel(rest, material, quadrature_points=7, comm=comm)
    model = ShellModel(rest, material, comm=comm)
    with (
        ShellSolver(model) as solver,
        pytest.raises(SolverError, match="load_steps must be an integer >= 1, got 0"),
    ):
        solver.solve(0)


def test_surface_from_another_grid_is_rejected(comm):
    disc = HermiteDiscretization(S.ParameterGrid(2, 2, (0.0, 1.0), (0.0, 1.0)), comm)
    with pytest.raises(DiscretizationError, match="differs"):
        disc.surface_to_open(S.flat_rectangle(1.0, 1.0, 3, 2))


def test_scene_files_are_regular_files_beside_the_scene(comm, shared_tmp_path, monkeypatch):
    """A surface file is found relative to the scene's folder, not the working directory, and a
    FIFO (which would block the reader forever) is refused before it is opened."""
    from helpers import BASE

    from bhem_hpc.scene import SceneError, load_scene

    folder = shared_tmp_path / "scenes"
    elsewhere = shared_tmp_path / "cwd"
    if comm.rank == 0:
        folder.mkdir()
        elsewhere.mkdir()
        S.flat_rectangle(0.4, 0.3, 3, 2).save(elsewhere / "sheet.npz")  # only in the working directory
        os.mkfifo(folder / "pipe.npz")
    comm.Barrier()
    monkeypatch.chdir(elsewhere)
    shape = 'kind = "rectangle"\nsize = [0.4, 0.3]\npatches = [3, 2]'
    for name, state in (("sheet.npz", "missing"), ("pipe.npz", "not a regular file")):
        scene = folder / f"{name}.toml"
        if comm.rank == 0:
            scene.write_text(BASE.replace(shape, f'kind = "file"\npath = "{name}"'))
        comm.Barrier()
        with pytest.raises(SceneError, match=rf"key 'surface.path' must be an existing regular file, .*is {state}"):
            load_scene(scene)


@pytest.mark.parametrize(
    ("option", "message"),
    [
        ('snes_type = "nosuch"', r"PETSc rejected its options \(error code 86: an unknown type name"),
        ('snes_divergence_tolerance = "abc"', r"PETSc rejected its options \(error code 63"),
        ('pc_factor_mat_solver_type = "nosolver"', r"stopped the solve with error code 92 \(no such factorization"),
    ],
)
def test_bad_petsc_options_end_in_one_line_without_retries(comm, shared_tmp_path, capsys, option, message):
    """A PETSc option PETSc refuses, at setup or at the first factorization: exit code 2, one line
    naming the solver; no time-step halvings (a smaller step cannot fix an option)."""
    from helpers import BASE

    from bhem_hpc import cli

    scene = shared_tmp_path / "bad.toml"
    if comm.rank == 0:
        scene.write_text(BASE + f"\n[solver]\noptions = {{ {option} }}\n")
    comm.Barrier()
    code = cli.main(["run", str(scene), "--out", str(shared_tmp_path / "out"), "--no-progress", "--steps", "1"])
    assert code == 2
    if comm.rank == 0:
        lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("bhem-hpc: error:")]
        assert len(lines) == 1 and "SNES solver 'bhem_'" in lines[0] and "halvings" not in lines[0]
        assert re.search(message, lines[0]), lines[0]

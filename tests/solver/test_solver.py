"""The SNES solver: loads, boundary conditions, options, failures."""

from __future__ import annotations

import numpy as np
import pytest
from petsc4py import PETSc

from bhem_hpc.geometry import surface as S
from bhem_hpc.model import bcs
from bhem_hpc.model.material import Material
from bhem_hpc.model.shell import LineLoad, Loads, PointLoad, ShellModel
from bhem_hpc.solver import ShellSolver, SolverError

BEAM = Material(young=1e6, poisson=0.0, thickness=0.01, density=1000.0)
LENGTH, WIDTH = 1.0, 0.1
EI = BEAM.young * WIDTH * BEAM.thickness**3 / 12


def strip(patches=16):
    return S.flat_rectangle(LENGTH, WIDTH, patches, 1)


def clamped_strip_model(comm, loads, patches=16, **kw):
    rest = strip(patches)
    return ShellModel(rest, BEAM, loads, [bcs.clamp(bcs.edge_nodes(rest.grid, "xi1_min"))], comm=comm, **kw)


def centreline_deflection(model, xi1):
    return float(model.state_surface().evaluate(np.array(xi1), np.array(WIDTH / 2)).x[2])


def test_point_load_at_an_arbitrary_point_matches_beam_theory(comm):
    force, a = 1e-6, 0.37  # a is not a node: 0.37 * 16 = 5.92
    model = clamped_strip_model(comm, Loads(point_loads=(PointLoad(a, WIDTH / 2, (0.0, 0.0, -force)),)))
    with ShellSolver(model) as solver:
        solver.solve()
    expected = -force * a**2 * (3 * LENGTH - a) / (6 * EI)
    assert abs(centreline_deflection(model, LENGTH) / expected - 1) < 1e-6
    loaded = model.state_surface().evaluate(np.array(a), np.array(WIDTH / 2)).x
    assert abs(model.energies()["external_work"] / (-force * loaded[2]) - 1) < 1e-12


def test_line_load_on_the_free_edge_matches_beam_theory(comm):
    traction = 1e-5  # N per m of edge
    model = clamped_strip_model(comm, Loads(line_loads=(LineLoad("xi1_max", (0.0, 0.0, -traction)),)))
    with ShellSolver(model) as solver:
        solver.solve()
    expected = -traction * WIDTH * LENGTH**3 / (3 * EI)
    assert abs(centreline_deflection(model, LENGTH) / expected - 1) < 1e-6
    # work of the dead edge load at the deflected position: (-t) * w_tip * width
    assert abs(model.energies()["external_work"] / (-traction * expected * WIDTH) - 1) < 1e-6


def test_prescribed_derivatives_and_pins(comm):
    """Rotate the tip tangent d1 by a small angle: a clamped-guided beam with an end rotation."""
    rest = strip(12)
    tip = bcs.edge_nodes(rest.grid, "xi1_max")
    angle = 1e-4
    constraints = [
        bcs.clamp(bcs.edge_nodes(rest.grid, "xi1_min")),
        bcs.pin(tip),
        # an edge rotation fixes d1 and its derivative along the edge, d12 (else the edge may warp)
        bcs.prescribe(tip, ["d1", "d12"], [0, 2], [[[np.cos(angle), np.sin(angle)], [0.0, 0.0]]]),
    ]
    model = ShellModel(rest, BEAM, None, constraints, comm=comm)
    with ShellSolver(model) as solver:
        solver.solve()
    final = model.state_surface()
    np.testing.assert_allclose(final.nodal[-1, :, 1, 2], np.sin(angle), rtol=1e-12)
    np.testing.assert_allclose(final.nodal[-1, :, 0], rest.nodal[-1, :, 0], atol=1e-14)
    # Beam with both ends held in place, tip rotated: w(x) = theta x^2 (x - L) / L^2
    xi = np.array([0.25, 0.5, 0.75])
    w = final.evaluate(xi, np.full(3, WIDTH / 2)).x[:, 2]
    np.testing.assert_allclose(w, angle * xi**2 * (xi - LENGTH) / LENGTH**2, rtol=1e-3, atol=1e-12)


def test_exact_and_pseudo_hessian_reach_the_same_equilibrium(comm):
    gravity = 5.0 * BEAM.young * BEAM.thickness**2 / (12 * BEAM.density)
    results = {}
    for hessian in ("exact", "pseudo"):
        model = clamped_strip_model(comm, Loads(gravity=(0.0, 0.0, -gravity)), hessian=hessian)
        with ShellSolver(model) as solver:
            report = solver.solve(3)
        results[hessian] = (centreline_deflection(model, LENGTH), sum(report.newton_iterations))
    assert abs(results["exact"][0] / results["pseudo"][0] - 1) < 1e-6  # both within SNES tolerances
    assert results["exact"][1] <= results["pseudo"][1]


def test_options_under_the_prefix_override_defaults(comm):
    model = clamped_strip_model(comm, Loads(gravity=(0.0, 0.0, -1.0)))
    with ShellSolver(model, prefix="custom_", options={"snes_rtol": 1e-3, "pc_type": "lu"}) as solver:
        assert solver.snes.getOptionsPrefix() == "custom_"
        assert solver.snes.getTolerances()[0] == pytest.approx(1e-3)
        assert solver.snes.getKSP().getPC().getType() == "lu"
    assert not PETSc.Options().hasName("custom_snes_rtol")  # pushed values are removed again
    PETSc.Options()["custom2_snes_rtol"] = 1e-5  # as if given on the command line
    try:
        with ShellSolver(model, prefix="custom2_", options={"snes_rtol": 1e-3}) as solver:
            assert solver.snes.getTolerances()[0] == pytest.approx(1e-5)
    finally:
        PETSc.Options().delValue("custom2_snes_rtol")


def test_failed_solve_raises_naming_solver_and_reasons(comm):
    gravity = 50.0 * BEAM.young * BEAM.thickness**2 / (12 * BEAM.density)
    model = clamped_strip_model(comm, Loads(gravity=(0.0, 0.0, -gravity)))
    with ShellSolver(model, prefix="doomed_", options={"snes_max_it": 1}) as solver:
        with pytest.raises(SolverError, match=r"SNES solver 'doomed_' failed at load factor .*DIVERGED_MAX_IT.*KSP"):
            solver.solve(1, max_cuts=2)
        assert solver.report.cuts == 3


def test_periodic_cylinder_under_inner_pressure_matches_membrane_theory(comm):
    """Closed cylinder, axial motion held (nu = 0): hoop stretch ``sqrt(1 + 2 p R / (Y h))``.

    With PK2 hoop stress ``S = Y (lambda^2 - 1) / 2`` and ring equilibrium ``h lambda S = p lambda R``.
    The pressure acts along ``a1 x a2``, which points inwards on this parameterization, so
    ``p < 0`` inflates.
    """
    radius, pressure = 1.0, 1.0
    material = Material(young=1e6, poisson=0.0, thickness=0.01)
    rest = S.cylinder(radius, 0.5, 2, 12)
    axial = bcs.NodalConstraint(np.argwhere(np.ones(rest.grid.node_shape, bool)), (0, 1, 2, 3), (2,))
    # In-plane rigid motions: y held where the surface moves along x, and vice versa.
    hold_y = bcs.NodalConstraint(np.array([[0, 0], [0, 6]]), (0,), (1,))
    hold_x = bcs.NodalConstraint(np.array([[0, 3], [0, 9]]), (0,), (0,))
    model = ShellModel(rest, material, Loads(pressure=-pressure), [axial, hold_x, hold_y], comm=comm)
    with ShellSolver(model) as solver:
        assert solver.snes.getKSP().getPC().getType() == "lu"  # follower load: not symmetric
        solver.solve()
    stretch = np.linalg.norm(model.state_surface().nodal[:, :, 0, :2], axis=-1) / radius
    expected = np.sqrt(1 + 2 * pressure * radius / (material.young * material.thickness))
    assert np.ptp(stretch) < 1e-9
    assert abs((stretch.mean() - 1) / (expected - 1) - 1) < 2e-3


def test_post_buckling_needs_and_gets_the_regularizer(comm):
    """A clamped strip shortened by 5 %: the straight state is a saddle (indefinite Hessian).

    Newton regularizes the indefinite iterations and reaches the buckled minimum, whose amplitude
    matches the inextensible first mode ``w = A (1 - cos(2 pi x / L)) / 2`` with
    ``shortening = A^2 pi^2 / (4 L)``.
    """
    rest = strip(16)
    grid = rest.grid
    imperfect = S.from_callable(lambda a, b: np.stack([a, b, 1e-4 * np.sin(np.pi * a)], -1), grid)
    tip = bcs.edge_nodes(grid, "xi1_max")
    shortening = 0.05
    constraints = [
        bcs.clamp(bcs.edge_nodes(grid, "xi1_min")),
        bcs.NodalConstraint(tip, (1, 2, 3)),
        bcs.prescribe(
            tip,
            ["x"],
            [0, 1, 2],
            np.array([[LENGTH - shortening, 0.0, 0.0], [LENGTH - shortening, WIDTH, 0.0]])[:, None],
        ),
    ]
    model = ShellModel(rest, BEAM, None, constraints, comm=comm, initial=imperfect)
    with ShellSolver(model) as solver:
        report = solver.solve(5)
        assert report.regularized_iterations > 0
        assert solver.inertia_at_state() == 0  # a minimum, not a saddle
    amplitude = np.abs(model.state_surface().nodal[:, :, 0, 2]).max()
    assert abs(amplitude / (np.sqrt(4 * LENGTH * shortening) / np.pi) - 1) < 0.05


def test_a_solver_that_never_factors_reports_only_the_callers_unused_options(comm):
    """Its own MUMPS defaults, read only at a first factorization, are not the user's misspelling."""
    model = clamped_strip_model(comm, Loads())
    with ShellSolver(model, prefix="unused_", options={"snes_rtoll": 1e-3}, linear="direct") as solver:
        assert solver.unused_options() == ["unused_snes_rtoll"]

"""The rational B-spline discretization: layouts, rational point bases, exact geometry (areas and
masses), gradient and Hessian on control points against differences, rigid motions, free fall,
and the Scordelis-Lo roof in exact rational patches."""

from __future__ import annotations

import math

import numpy as np
import pytest
from dolfinx import fem
from helpers import (
    assert_closed_derivatives,
    assert_falls_freely,
    assert_rigid_motion_has_no_energy,
    random_rotation,
)

from bhem_hpc import forms
from bhem_hpc.discretization import RationalBSplineDiscretization, create_discretization
from bhem_hpc.geometry import bspline as B
from bhem_hpc.geometry.grid import ParameterGrid
from bhem_hpc.geometry.nurbs import NurbsSurface, cylinder_panel, revolved_arc_panel
from bhem_hpc.geometry.rational_bspline import RationalBSplineSurface, insert_knot, on_uniform_knots
from bhem_hpc.geometry.trim import Trim
from bhem_hpc.model import bcs
from bhem_hpc.model.material import Material
from bhem_hpc.model.shell import Dynamics, Loads, ShellModel
from bhem_hpc.solver import ShellSolver
from bhem_hpc.solver.dynamics import TimeStepper

MATERIAL = Material(young=1e3, poisson=0.3, thickness=0.05, density=2.0)
MAJOR, MINOR = 1.0, 0.4
TUBE, AROUND = (0.9, 2.1), (0.2, 1.4)  # the torus patch's angles [rad]: about the tube, about the axis


def torus_patch() -> NurbsSurface:
    """A patch of the torus (major radius 1, minor 0.4): polar angles TUBE about the tube's circle,
    AROUND about the z axis."""
    return revolved_arc_panel((MAJOR, 0.0), MINOR, TUBE, AROUND, "torus patch")


def torus_area() -> float:
    """``int r (R + r sin(t)) dt dtheta`` over the patch."""
    return MINOR * (MAJOR * (TUBE[1] - TUBE[0]) + MINOR * (math.cos(TUBE[0]) - math.cos(TUBE[1]))) * (
        AROUND[1] - AROUND[0])


def uneven_torus_patch(degree: int, repeats: int = 1) -> NurbsSurface:
    """The torus patch raised to ``degree`` with knots at 1/pi (``repeats`` times) along u and 0.27
    along v: on no uniform lattice, so the shell keeps these knots."""
    patch = on_uniform_knots(torus_patch(), (1, 1), degree).nurbs()
    knots, homogeneous = patch.u.knots, patch.homogeneous
    for _ in range(repeats):
        knots, homogeneous = insert_knot(knots, degree, homogeneous, 1 / math.pi)
    knots_v, moved = insert_knot(patch.v.knots, degree, np.moveaxis(homogeneous, 1, 0), 0.27)
    homogeneous = np.moveaxis(moved, 0, 1)
    return NurbsSurface((degree, degree), knots, knots_v, homogeneous[..., :3] / homogeneous[..., 3:],
                        homogeneous[..., 3], "uneven torus patch")  # fmt: skip


@pytest.fixture(params=[(2, "uniform"), (3, "uniform"), (2, "own knots"), (3, "own knots"), (3, "a C1 knot")])
def rest(request) -> RationalBSplineSurface:
    degree, knots = request.param
    if knots == "uniform":
        return on_uniform_knots(torus_patch(), (4, 3), degree)
    surface = on_uniform_knots(uneven_torus_patch(degree, 2 if knots == "a C1 knot" else 1), (4, 3))
    assert surface.knots is not None and surface.knots[0] is not None and surface.knots[1] is not None
    return surface


def test_the_torus_patch_lies_on_the_torus(rest):
    """The helper's surface and its exact conversion: every point at distance r from the tube's axis."""
    u, v = np.meshgrid(np.linspace(0, 1, 13), np.linspace(0, 1, 11), indexing="ij")
    x = rest.evaluate(u.ravel(), v.ravel()).x
    from_axis = np.hypot(x[:, 0], x[:, 1]) - MAJOR
    np.testing.assert_allclose(np.hypot(from_axis, x[:, 2]), MINOR, atol=1e-14)


def test_layouts_round_trip_and_point_bases_are_rational(comm, rest, rng):
    disc = create_discretization(rest, comm)
    assert isinstance(disc, RationalBSplineDiscretization)
    surface = rest.with_nodal(rest.nodal + 0.01 * rng.normal(size=rest.nodal.shape))
    np.testing.assert_allclose(disc.open_to_surface(disc.surface_to_open(surface)).control, surface.control, atol=1e-13)
    np.testing.assert_array_equal(disc.closed_to_surface(disc.surface_to_closed(surface)).control, surface.control)
    open_values = disc.surface_to_open(surface).reshape(-1, 3)
    for xi in ((0.13, 0.71), (0.5, 0.0), (1.0, 0.37)):
        blocks, frame = disc.point_frame_basis(*xi)
        point = surface.evaluate(np.array(xi[0]), np.array(xi[1]))
        local = frame @ open_values[blocks] if len(blocks) else np.zeros((3, 3))
        found = comm.allreduce(local)
        np.testing.assert_allclose(found, [point.x, point.a1, point.a2], atol=1e-12)
        blocks, values = disc.point_basis(*xi)
        np.testing.assert_allclose(comm.allreduce(values @ open_values[blocks] if len(blocks) else np.zeros(3)),
                                   point.x, atol=1e-13)  # fmt: skip


def test_the_mass_is_the_exact_surfaces(comm, rest):
    """rho t times the torus patch's area: to the quadrature's error only (rational integrands), far
    below the interpolating polynomial B-spline of the same spans."""
    exact = MATERIAL.density * MATERIAL.thickness * torus_area()
    mass = total_mass(ShellModel(rest, MATERIAL, comm=comm))
    part = torus_patch()
    interpolated = B.from_callable(lambda u, v: part.evaluate(*rest.model_parameters(u.ravel(), v.ravel()))[0]
                                   .reshape(*u.shape, 3), rest.grid, degree=rest.degree)  # fmt: skip
    approximate = total_mass(ShellModel(interpolated, MATERIAL, comm=comm))
    assert abs(mass / exact - 1) < 1e-7 and abs(approximate / exact - 1) > 10 * abs(mass / exact - 1)


def total_mass(model: ShellModel) -> float:
    form = forms.total_mass(model.x_rest, model.density, model.thickness, model.dx)
    return model.comm.allreduce(fem.assemble_scalar(fem.form(model.in_unknowns(form))))


def test_gradient_and_hessian_match_central_differences(comm, rest, rng):
    """The forms rewritten in the homogeneous unknowns: ``E_w^T F`` and ``E_w^T J E_w`` against
    differences of the potential and of the residual in control-point directions (a curved rest
    shape, a random state, gravity)."""
    state = rest.with_nodal(rest.nodal + 0.03 * rng.normal(size=rest.nodal.shape))
    model = ShellModel(rest, MATERIAL, Loads(gravity=(0.0, 0.0, -9.81)), comm=comm, initial=state)
    with ShellSolver(model, prefix=f"ratfd{rest.degree}_") as solver:
        disc = model.discretization
        assert_closed_derivatives(solver, disc, disc.surface_to_closed(state), rng, 3, comm)


def test_rigid_motions_have_no_energy(comm, rest, rng):
    assert_rigid_motion_has_no_energy(rest, rest.transformed(random_rotation(rng), rng.normal(size=3)), MATERIAL, comm)


def test_a_free_rational_sheet_falls_exactly(comm, rest):
    """Implicit Euler under gravity alone: the rational basis sums to one, so every control point
    drops by ``g dt^2 N (N + 1) / 2`` (the mass rewritten in the unknowns, exactly)."""
    assert_falls_freely(rest, MATERIAL, comm, 4, 1e-8)


def test_a_grid_of_another_shape_or_weights_is_refused(comm, rest):
    disc = create_discretization(rest, comm)
    other = RationalBSplineSurface(rest.grid, rest.degree, rest.control, rest.weights * 1.5, rest.knots)
    with pytest.raises(ValueError, match="with these weights"):
        disc.surface_to_open(other)
    with pytest.raises(ValueError, match="weights must have shape"):
        RationalBSplineDiscretization(ParameterGrid(2, 2, (0, 1), (0, 1)), rest.degree, np.ones((2, 2)), comm)


def _panel_under_pressure(comm, rest) -> float:
    """A steel cylindrical panel (R 1, 60 degrees, 1 m long, 5 cm) hinged round its edges under a
    follower pressure of 2 MPa: the centre's radial displacement [m]."""
    steel = Material(2.0e11, 0.3, 0.05, 7850.0)
    edges = ("xi1_min", "xi1_max", "xi2_min", "xi2_max")
    model = ShellModel(rest, steel, Loads(pressure=2.0e6), [bcs.hinged_edge(rest, e) for e in edges], comm=comm)
    with ShellSolver(model, prefix="ratpress_") as solver:
        solver.solve()
    at = (np.array(0.5), np.array(0.5 if isinstance(rest, RationalBSplineSurface) else 90 * math.pi / 180))
    moved, start = model.state_surface().evaluate(*at).x, rest.evaluate(*at).x
    return float(np.hypot(*moved[:2]) - np.hypot(*start[:2]))


def test_a_follower_pressure_on_exact_patches_matches_the_interpolated_shell(comm):
    """The pressure's virtual work and its non-symmetric tangent rewritten in the unknowns: the exact
    cubic cylinder and its bicubic interpolant (12 x 12 spans) give one centre displacement within
    2e-5 (measured 3.3e-6; 4.1e-5 at 6 x 6 and 1.8e-7 at 24 x 24 spans: two discretizations
    converging to one value at the rate h^4)."""
    part = cylinder_panel(1.0, (0.0, 1.0), (60 * math.pi / 180, 120 * math.pi / 180))
    exact = on_uniform_knots(part, (12, 12), 3)
    grid = ParameterGrid(12, 12, (0.0, 1.0), (60 * math.pi / 180, 120 * math.pi / 180))
    interpolated = B.from_callable(lambda z, a: np.stack([np.cos(a), np.sin(a), z], -1), grid, degree=3)
    rational, polynomial = _panel_under_pressure(comm, exact), _panel_under_pressure(comm, interpolated)
    assert rational < -2e-4 and abs(rational / polynomial - 1) < 2e-5, (rational, polynomial)


def test_a_trimmed_rational_sheet_falls_freely_as_implicit_euler_says(comm, rest):
    """The cut-cell weights and the rational forms together: gravity and mass carry the same
    weights, so every kept control point of the trimmed torus patch follows implicit Euler's
    sequence exactly; those moving no kept point are held."""
    angles = np.linspace(0.0, 2 * np.pi, 201)
    trim = Trim.of(rest.grid, [np.column_stack([0.5 + 0.25 * np.cos(angles), 0.5 + 0.25 * np.sin(angles)])],
                   rest.degree + 1)  # fmt: skip
    dt, steps = 0.01, 3
    model = ShellModel(rest, MATERIAL, Loads(gravity=(0.0, 0.0, -9.81)), comm=comm, quadrature_points=trim,
                       dynamics=Dynamics(dt))  # fmt: skip
    with ShellSolver(model, prefix="rattrim_") as solver:
        stepper = TimeStepper(model, solver)
        for _ in range(steps):
            stepper.advance()
    moved = model.state_surface().control - rest.control
    held = np.concatenate([c.nodes for c in model.constraints])
    kept = np.ones(moved.shape[:2], dtype=bool)
    kept[held[:, 0], held[:, 1]] = False
    assert 0 < kept.sum() < kept.size
    np.testing.assert_allclose(moved[kept][:, 2], -9.81 * dt**2 * steps * (steps + 1) / 2, rtol=1e-8)
    np.testing.assert_allclose(moved[~kept], 0.0, atol=1e-14 if rest.knots is None else 1e-12)  # least squares

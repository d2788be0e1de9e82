"""The B-spline discretization: layouts, gradient and Hessian on control points, rigid motions, plates,
the cantilever master curve, dynamics, constraints, and 2 ranks against serial runs."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import (
    assert_closed_derivatives,
    assert_falls_freely,
    assert_rigid_motion_has_no_energy,
    random_rotation,
)
from mpi4py import MPI
from petsc4py import PETSc

from bhem_hpc.discretization import BSplineDiscretization, DiscretizationError
from bhem_hpc.geometry import bspline as B
from bhem_hpc.model.bcs import NodalConstraint
from bhem_hpc.model.material import Material
from bhem_hpc.model.shell import Loads, ShellModel
from bhem_hpc.solver import ShellSolver
from bhem_hpc.studies.references import CLAMPED_SQUARE_PLATE, heavy_cantilever_tip, simply_supported_square_plate

MATERIAL = Material(young=1e3, poisson=0.3, thickness=0.05, density=2.0)
PLATE = Material(young=1e6, poisson=0.3, thickness=0.01, density=1.0)


def boundary_controls(surface: B.BSplineSurface, rows: int) -> np.ndarray:
    """Control points ``(k, 2)`` within ``rows`` of the boundary of an open surface."""
    c1, c2 = surface.node_shape
    i1, i2 = np.meshgrid(np.arange(c1), np.arange(c2), indexing="ij")
    near = np.minimum(np.minimum(i1, c1 - 1 - i1), np.minimum(i2, c2 - 1 - i2)) < rows
    return np.stack([i1[near], i2[near]], axis=1)


@pytest.mark.parametrize("degree", B.DEGREES)
def test_layouts_round_trip(comm, degree, rng):
    rest = B.torus(1.0, 0.3, 6, 5, degree=degree)
    disc = BSplineDiscretization(rest.grid, degree, comm)
    surface = B.BSplineSurface(rest.grid, degree, rest.control + 0.01 * rng.normal(size=rest.control.shape))
    np.testing.assert_allclose(disc.open_to_surface(disc.surface_to_open(surface)).control, surface.control, atol=1e-13)
    np.testing.assert_array_equal(disc.closed_to_surface(disc.surface_to_closed(surface)).control, surface.control)
    # open DOFs are the spline's values at the DOF points
    points = disc.block_points
    np.testing.assert_allclose(
        disc.surface_to_open(surface).reshape(-1, 3), surface.evaluate(points[:, 0], points[:, 1]).x, atol=1e-13
    )
    raw = disc.gather_raw_dofs(disc.surface_to_open(surface))
    np.testing.assert_array_equal(disc.scatter_raw_dofs(raw), disc.surface_to_open(surface))


@pytest.mark.parametrize(("degree", "quadrature"), [(2, None), (3, None), (2, "reduced")])
def test_closed_gradient_and_hessian_match_central_differences(comm, degree, quadrature, rng):
    """``E^T F(E x_c)`` and ``E^T J E`` against differences of the potential and of the residual in
    control-point directions, on a curved rest shape and a random state."""
    rest = B.sphere_zone(0.8, 0.4, 1.6, 4, 5, degree=degree)
    state = B.BSplineSurface(rest.grid, degree, rest.control + 0.03 * rng.normal(size=rest.control.shape))
    model = ShellModel(rest, MATERIAL, Loads(gravity=(0.0, 0.0, -9.81)), comm=comm, initial=state,
                       quadrature_points=quadrature)  # fmt: skip
    with ShellSolver(model, prefix=f"bsfd{degree}_") as solver:
        disc = model.discretization
        assert_closed_derivatives(solver, disc, disc.surface_to_closed(state), rng, 4, comm)


@pytest.mark.parametrize(
    ("degree", "closed", "quadrature"),
    [(2, False, None), (3, False, None), (2, True, None), (3, True, None), (2, False, "reduced"), (2, True, "reduced")],
)
def test_rigid_motions_have_no_energy(comm, degree, closed, quadrature, rng):
    rest = (
        B.cylinder(1.0, 1.5, 4, 6, degree=degree)
        if closed
        else B.annulus_sector(0.3, 1.0, 0.0, 2.0, 4, 5, degree=degree)
    )
    moved = rest.transformed(random_rotation(rng), rng.normal(size=3))
    assert_rigid_motion_has_no_energy(rest, moved, MATERIAL, comm, quadrature)


def plate_deflection(degree: int, spans: int, support: str, comm, quadrature: int | str | None = None) -> float:
    """Centre deflection of a square plate under uniform load in ``q a^4 / D`` (small deflection)."""
    rest = B.flat_rectangle(1.0, 1.0, spans, spans, degree=degree)
    c1, c2 = rest.node_shape
    if support == "clamped":  # the two outer rows of control points: position and slope
        constraints = [NodalConstraint(boundary_controls(rest, 2), (0,))]
    else:  # the boundary curve held in z; three corners in plane (no rigid in-plane motion)
        corners = np.array([[0, 0], [c1 - 1, 0], [0, c2 - 1]])
        constraints = [NodalConstraint(boundary_controls(rest, 1), (0,), (2,)), NodalConstraint(corners, (0,), (0, 1))]
    q = 1e-6 * PLATE.bending_stiffness
    model = ShellModel(rest, PLATE, Loads(gravity=(0.0, 0.0, -q / (PLATE.density * PLATE.thickness))), constraints,
                       comm=comm, quadrature_points=quadrature)  # fmt: skip
    with ShellSolver(model, prefix="bsplate_") as solver:
        solver.solve(1)
    return float(-model.state_surface().evaluate(np.array(0.5), np.array(0.5)).x[2] * PLATE.bending_stiffness / q)


@pytest.mark.parametrize("support", ["simply_supported", "clamped"])
@pytest.mark.parametrize("degree", B.DEGREES)
def test_plates_converge_at_the_rate_theory_gives(comm, degree, support):
    """The centre deflection (a functional) converges at ``2 (p - 1)``; asserted 0.9 of that."""
    reference = CLAMPED_SQUARE_PLATE if support == "clamped" else simply_supported_square_plate()
    errors = [abs(plate_deflection(degree, n, support, comm) / reference - 1) for n in (4, 8, 16)]
    rates = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(rates > 0.9 * 2 * (degree - 1)), (errors, rates)
    assert errors[-1] < (2e-2 if degree == 2 else 2e-5), errors


def test_reduced_quadrature_converges_on_plates(comm):
    """The B-spline paper's reduced rule: the clamped plate converges at close to the full rule's
    rate 2 (asserted > 1.4 between 4, 8 and 16 spans, the rate still rising) and both plates stay
    within 1.5 x of the full rule's error at 16 spans."""
    clamped = [abs(plate_deflection(2, n, "clamped", comm, "reduced") / CLAMPED_SQUARE_PLATE - 1) for n in (4, 8, 16)]
    rates = np.log2(np.array(clamped[:-1]) / np.array(clamped[1:]))
    assert np.all(rates > 1.4) and rates[1] > rates[0], (clamped, rates)
    for support, reference in (
        ("clamped", CLAMPED_SQUARE_PLATE),
        ("simply_supported", simply_supported_square_plate()),
    ):
        full = abs(plate_deflection(2, 16, support, comm) / reference - 1)
        reduced = abs(plate_deflection(2, 16, support, comm, "reduced") / reference - 1)
        assert reduced < 1.5 * full + 1e-3, (support, full, reduced)


@pytest.mark.parametrize("degree", B.DEGREES)
def test_cantilever_master_curve_within_one_percent(comm, degree):
    """Strip under self-weight (nu = 0) against the heavy elastica at 32 spans, Gamma* = 20."""
    length, width, gamma = 1.0, 0.1, 20.0
    material = Material(young=1e6, poisson=0.0, thickness=0.01, density=1000.0)
    gravity = gamma * material.young * material.thickness**2 / (12 * material.density * length**3)
    rest = B.flat_rectangle(length, width, 32, 1, degree=degree)
    clamped = np.array([[i, j] for i in range(2) for j in range(rest.node_shape[1])])
    model = ShellModel(rest, material, Loads(gravity=(0.0, 0.0, -gravity)), [NodalConstraint(clamped, (0,))], comm=comm)
    with ShellSolver(model, prefix="bscant_") as solver:
        solver.solve(10)
    tip = model.state_surface().evaluate(np.array(length), np.array(width / 2)).x
    drop = -tip[2] / length
    assert abs(drop / heavy_cantilever_tip(gamma)[1] - 1) < 1e-2, drop


def test_a_free_sheet_falls_exactly(comm):
    """Implicit Euler under gravity alone: every control point drops by ``g dt^2 N (N + 1) / 2``."""
    assert_falls_freely(B.flat_rectangle(0.5, 0.3, 3, 2, degree=2), MATERIAL, comm, 5, 1e-9)


def test_spline_constraints_refuse_derivative_kinds(comm):
    rest = B.flat_rectangle(1.0, 1.0, 3, 3, degree=2)
    with pytest.raises(ValueError, match=r"constraint kinds \(1,\) must be a non-empty subset of \('x',\)"):
        ShellModel(rest, MATERIAL, constraints=[NodalConstraint(np.array([[0, 0]]), (1,))], comm=comm)
    with pytest.raises(ValueError, match=r"names node \(5, 0\), which does not exist"):
        ShellModel(rest, MATERIAL, constraints=[NodalConstraint(np.array([[5, 0]]), (0,))], comm=comm)
    disc = BSplineDiscretization(rest.grid, 2, comm)
    with pytest.raises(DiscretizationError, match="do not exist for B-splines"):
        disc.select_dofs(np.array([[0, 0]]), (0, 3), (0,))


@pytest.mark.parallel
@pytest.mark.parametrize("degree", B.DEGREES)
def test_two_ranks_give_the_serial_numbers(comm, degree):
    """The clamped plate on every rank alone (serial) and on all ranks together."""
    serial = plate_deflection(degree, 6, "clamped", MPI.COMM_SELF)
    parallel = plate_deflection(degree, 6, "clamped", comm)
    assert comm.size > 1 and PETSc.COMM_WORLD.getSize() == comm.size
    assert abs(parallel - serial) <= 1e-10 * abs(serial)


@pytest.mark.parametrize(("degree", "bound"), [(2, 6e-3), (3, 1e-8)])
def test_point_load_anywhere_matches_beam_theory(comm, degree, bound):
    """A clamped strip (nu = 0, 16 spans) under a point load at xi1 = 0.37, inside a span: tip
    deflection against beam theory (C1 quadratic splines approximate the cubic deflection, cubic
    splines all but reproduce it)."""
    from bhem_hpc.model.shell import PointLoad

    beam = Material(young=1e6, poisson=0.0, thickness=0.01, density=1000.0)
    length, width, force, a = 1.0, 0.1, 1e-6, 0.37
    ei = beam.young * width * beam.thickness**3 / 12
    rest = B.flat_rectangle(length, width, 16, 1, degree=degree)
    clamped = np.array([[i, j] for i in range(2) for j in range(rest.node_shape[1])])
    loads = Loads(point_loads=(PointLoad(a, width / 2, (0.0, 0.0, -force)),))
    model = ShellModel(rest, beam, loads, [NodalConstraint(clamped, (0,))], comm=comm)
    with ShellSolver(model, prefix="bspoint_") as solver:
        solver.solve()
    tip = model.state_surface().evaluate(np.array(length), np.array(width / 2)).x[2]
    expected = -force * a**2 * (3 * length - a) / (6 * ei)
    assert abs(tip / expected - 1) < bound, tip / expected - 1


@pytest.mark.parallel
@pytest.mark.parametrize("degree", B.DEGREES)
def test_raw_dofs_do_not_depend_on_the_rank_count(comm, degree, rng):
    """Checkpoints hold raw DOFs: gathered on all ranks they equal the serial ones bit for bit, so
    a run restarts on any rank count."""
    rest = B.torus(1.0, 0.3, 6, 5, degree=degree)
    control = rest.control + 0.01 * comm.bcast(rng.normal(size=rest.control.shape) if comm.rank == 0 else None)
    surface = B.BSplineSurface(rest.grid, degree, control)
    serial = BSplineDiscretization(rest.grid, degree, MPI.COMM_SELF)
    parallel = BSplineDiscretization(rest.grid, degree, comm)
    raw = parallel.gather_raw_dofs(parallel.surface_to_open(surface))
    np.testing.assert_array_equal(raw, serial.gather_raw_dofs(serial.surface_to_open(surface)))
    np.testing.assert_array_equal(parallel.scatter_raw_dofs(raw), parallel.surface_to_open(surface))

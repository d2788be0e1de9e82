"""Trimmed shells: the model integrates only over the trim's region (energies against the region's
area and moments), holds the entries that move nothing kept, and refuses loads off the region."""

from __future__ import annotations

import numpy as np
import pytest

from bhem_hpc.geometry import bspline as B
from bhem_hpc.geometry import surface as S
from bhem_hpc.geometry.trim import Trim, TrimError, legendre_moments
from bhem_hpc.model.loads import LineLoad, Loads, PointLoad
from bhem_hpc.model.material import Material
from bhem_hpc.model.shell import ShellModel

COTTON = Material(young=2.0e6, poisson=0.243, thickness=3.18e-4, density=472.6)
RADIUS, CENTRE = 0.35, (0.5, 0.5)


def disk(count=400):
    angles = np.linspace(0.0, 2 * np.pi, count + 1)
    return np.column_stack([CENTRE[0] + RADIUS * np.cos(angles), CENTRE[1] + RADIUS * np.sin(angles)])


def rest_surface(discretization):
    if discretization == "hermite":
        return S.flat_rectangle(1.0, 1.0, 8, 8)
    return B.flat_rectangle(1.0, 1.0, 12, 12, degree=int(discretization[-1]))


def with_positions(rest, move):
    """``rest`` with every entry's position mapped by ``move`` (linear maps keep Hermite
    derivatives consistent when applied to them too)."""
    if isinstance(rest, B.BSplineSurface):
        return B.BSplineSurface(rest.grid, rest.degree, move(rest.control))
    return rest.with_nodal(move(rest.nodal))


@pytest.mark.parametrize("discretization", ["hermite", "bspline2", "bspline3"])
def test_a_uniform_stretch_costs_the_disks_share_of_the_sheets_energy(comm, discretization):
    """A uniform stretch has a constant energy density: the trimmed sheet's membrane energy is the
    whole sheet's times the region's area (the polygon's), to round-off; gravity's potential of a
    sheet lifted by z = c x^2 is rho h g c int x^2 over the region."""
    rest = rest_surface(discretization)
    loops = [disk()]
    trim = Trim.of(rest.grid, loops, {"hermite": 4, "bspline2": 3, "bspline3": 4}[discretization])
    stretched = with_positions(rest, lambda p: p * np.array([1.1, 0.97, 1.0]))
    whole = ShellModel(rest, COTTON, comm=comm, initial=stretched).energies()
    cut = ShellModel(rest, COTTON, comm=comm, initial=stretched, quadrature_points=trim).energies()
    area = legendre_moments(list(trim.loops), 0)[0, 0]
    assert area == pytest.approx(np.pi * RADIUS**2, rel=1e-4)
    assert cut["membrane"] == pytest.approx(whole["membrane"] * area, rel=1e-11)
    # lifted: z = c x^2 (exact in every discretization: quadratic in the parameters)
    c, g = 0.2, 9.81
    if isinstance(rest, B.BSplineSurface):
        lifted = B.from_callable(lambda xi1, xi2: np.stack([xi1, xi2, c * xi1**2], axis=-1), rest.grid,
                                 degree=rest.degree)  # fmt: skip
    else:
        zero = np.zeros_like
        lifted = S.from_callable(
            lambda xi1, xi2: np.stack([xi1, xi2, c * xi1**2], axis=-1), rest.grid,
            (lambda xi1, xi2: np.stack([1.0 + zero(xi1), zero(xi1), 2 * c * xi1], axis=-1),
             lambda xi1, xi2: np.stack([zero(xi1), 1.0 + zero(xi1), zero(xi1)], axis=-1),
             lambda xi1, xi2: np.zeros(np.shape(xi1) + (3,))))  # fmt: skip
    loads = Loads(gravity=(0.0, 0.0, -g))
    energies = ShellModel(rest, COTTON, loads, comm=comm, initial=lifted, quadrature_points=trim).energies()
    second_moment = np.pi * RADIUS**2 * (RADIUS**2 / 4 + CENTRE[0] ** 2)
    rho_h = COTTON.density * COTTON.thickness
    assert energies["gravity"] == pytest.approx(rho_h * g * c * second_moment, rel=2e-3)


def test_entries_outside_are_held_and_loads_off_the_region_refused(comm):
    rest = B.flat_rectangle(1.0, 1.0, 12, 12, degree=2)
    trim = Trim.of(rest.grid, [disk()], 3)
    model = ShellModel(rest, COTTON, comm=comm, quadrature_points=trim)
    held = np.concatenate([c.nodes for c in model.constraints])
    # control point (i, j) of a quadratic spline on 12 spans moves spans i-2..i: the corners' are
    # far outside the disk, the centre's inside
    held_set = {tuple(n) for n in held.tolist()}
    assert (0, 0) in held_set and (13, 13) in held_set and (7, 7) not in held_set
    assert 0 < len(held_set) < 14 * 14
    with pytest.raises(TrimError, match=r"line_loads\[0\] acts on edge 'xi1_max', which the trim cuts"):
        ShellModel(rest, COTTON, Loads(line_loads=(LineLoad("xi1_max", (1.0, 0.0, 0.0)),)), comm=comm,
                   quadrature_points=trim)  # fmt: skip
    with pytest.raises(TrimError, match=r"point_loads\[0\] at \(xi1, xi2\) = \(0.05, 0.05\) lies outside"):
        ShellModel(rest, COTTON, Loads(point_loads=(PointLoad(0.05, 0.05, (0.0, 0.0, -1.0)),)), comm=comm,
                   quadrature_points=trim)  # fmt: skip


def test_a_trimmed_sheet_falls_freely_as_implicit_euler_says(comm):
    """Gravity and mass carry the same weights, cut cells too: every kept control point follows
    the exact implicit Euler sequence; the held ones (outside) stay where they were."""
    from bhem_hpc.model.shell import Dynamics
    from bhem_hpc.solver import ShellSolver
    from bhem_hpc.solver.dynamics import TimeStepper

    rest = B.flat_rectangle(1.0, 1.0, 12, 12, degree=2)
    dt, steps, g = 0.01, 4, 9.81
    trim = Trim.of(rest.grid, [disk()], 3)
    model = ShellModel(rest, COTTON, Loads(gravity=(0.0, 0.0, -g)), comm=comm, quadrature_points=trim,
                       dynamics=Dynamics(dt))  # fmt: skip
    with ShellSolver(model, prefix="trim_fall_") as solver:
        stepper = TimeStepper(model, solver)
        records = [stepper.advance() for _ in range(steps)]
    assert all(r.dt_halvings == 0 for r in records)
    control = model.state_surface().control
    held = np.concatenate([c.nodes for c in model.constraints])
    kept = np.ones(control.shape[:2], dtype=bool)
    kept[held[:, 0], held[:, 1]] = False
    drop = -g * dt**2 * steps * (steps + 1) / 2
    np.testing.assert_allclose(control[kept][:, 2], drop, rtol=1e-8)
    np.testing.assert_allclose(control[~kept], rest.control[~kept], atol=1e-14)


def test_a_cotton_disk_on_a_pole_drapes_without_a_dt_halving(comm):
    """Cotton (2 MPa, 0.318 mm) trimmed to a disk of 0.7 m, held at its four central control
    points, falls and drapes for 0.2 s at dt = 10 ms with the energy trust region (the cotton drape
    job's solver; line-search Newton halves dt here as on the untrimmed square): every step converges
    without a dt halving, the rim falls below the centre and the total energy never grows."""
    from bhem_hpc.model.bcs import NodalConstraint
    from bhem_hpc.model.shell import Dynamics
    from bhem_hpc.solver import ShellSolver
    from bhem_hpc.solver.dynamics import TimeStepper

    rest = B.flat_rectangle(1.0, 1.0, 12, 12, degree=2)
    trim = Trim.of(rest.grid, [disk()], 3)
    pole = NodalConstraint(nodes=np.array([(6, 6), (6, 7), (7, 6), (7, 7)]), kinds=(0,))
    model = ShellModel(rest, COTTON, Loads(gravity=(0.0, 0.0, -9.81)), [pole], comm=comm, quadrature_points=trim,
                       dynamics=Dynamics(0.01), hessian="trust_region")  # fmt: skip
    totals = []
    with ShellSolver(model, prefix="trim_pole_") as solver:
        stepper = TimeStepper(model, solver)
        records = []
        for _ in range(20):
            records.append(stepper.advance())
            e = model.energies()
            totals.append(e["kinetic"] + e["membrane"] + e["bending"] + e["gravity"])
    assert sum(r.dt_halvings for r in records) == 0
    assert np.all(np.diff(totals) <= 1e-9 * abs(totals[0]))
    rim = model.state_surface().evaluate(np.array([CENTRE[0] + 0.95 * RADIUS]), np.array([CENTRE[1]])).x
    centre = model.state_surface().evaluate(np.array([CENTRE[0]]), np.array([CENTRE[1]])).x
    assert rim[0, 2] < centre[0, 2] - 0.05

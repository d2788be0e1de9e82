"""Energy, gradient and Hessian of the discrete shell: finite differences, pseudo Hessian, invariance."""

from __future__ import annotations

import dolfinx.fem as fem
import numpy as np
import pytest
import ufl
from helpers import (
    central_difference,
    gather_matrix,
    jacobian_dense,
    open_state_global,
    potential,
    random_rotation,
    residual_open,
    set_open_state_global,
)

from bhem_hpc.forms.bending import _bending_strain
from bhem_hpc.forms.kinematics import area_density, metric, plane_stress_lame, svk_bilinear
from bhem_hpc.geometry import surface as S
from bhem_hpc.model.material import Material
from bhem_hpc.model.shell import Loads, ShellModel
from bhem_hpc.solver import ShellSolver

MATERIAL = Material(young=1e3, poisson=0.3, thickness=0.05, density=2.0)


def curved_rest():
    return S.cylinder(1.0, 1.0, 3, 3, closed=False, angle=np.pi / 2)


def deformed(surface, rng, amplitude=0.05):
    return S.HermiteSurface(surface.grid, surface.nodal + amplitude * rng.normal(size=surface.nodal.shape))


@pytest.fixture
def model_pair(comm, rng):
    rest = curved_rest()
    state = deformed(rest, rng)
    loads = Loads(gravity=(0.0, 0.0, -9.81))
    exact = ShellModel(rest, MATERIAL, loads, hessian="exact", comm=comm, initial=state)
    pseudo = ShellModel(rest, MATERIAL, loads, hessian="pseudo", comm=comm, initial=state)
    return exact, pseudo


def test_gradient_matches_central_differences(model_pair, rng):
    model, _ = model_pair
    q0 = open_state_global(model)
    gradient = residual_open(model)
    for _ in range(3):
        d = rng.normal(size=q0.shape)
        fd = central_difference(model, q0, d, 1e-5, potential)
        assert abs(fd - gradient @ d) < 1e-6 * abs(gradient @ d)


def test_exact_hessian_matches_central_differences(model_pair, rng):
    model, _ = model_pair
    q0 = open_state_global(model)
    hessian = jacobian_dense(model)
    np.testing.assert_allclose(hessian, hessian.T, atol=1e-10 * np.abs(hessian).max())
    for _ in range(3):
        d = rng.normal(size=q0.shape)
        fd = central_difference(model, q0, d, 1e-6, residual_open)
        assert np.linalg.norm(fd - hessian @ d) < 1e-6 * np.linalg.norm(hessian @ d)


def test_pseudo_hessian_drops_exactly_the_second_curvature_derivative(model_pair):
    exact, pseudo = model_pair
    x, x_rest = exact.x, exact.x_rest
    space = exact.discretization.function_space
    v, w = ufl.TestFunction(space), ufl.TrialFunction(space)
    lmbda, mu = plane_stress_lame(exact.young, exact.poisson)
    strain = _bending_strain(x, x_rest)
    second = ufl.derivative(ufl.derivative(strain, x, v), x, w)
    dropped = 2 * exact.thickness**3 / 3 * svk_bilinear(second, strain, ufl.inv(metric(x_rest)), lmbda, mu)
    dropped_form = fem.form(dropped * area_density(x_rest) * exact.dx)
    j_exact, j_pseudo = jacobian_dense(exact), jacobian_dense(pseudo)
    j_dropped = jacobian_dense(exact, dropped_form)
    scale = np.abs(j_exact).max()
    assert np.abs(j_dropped).max() > 1e-4 * scale  # the term is there to drop
    np.testing.assert_allclose(j_exact - j_pseudo, j_dropped, atol=1e-11 * scale)


def test_rigid_motions_of_a_curved_shell_have_zero_energy_and_residual(comm, rng):
    rest = curved_rest()
    model = ShellModel(rest, MATERIAL, comm=comm)
    set_open_state_global(model, open_state_global(model))
    model.set_state(deformed(rest, rng, 0.01))
    reference_energy = sum(model.energies().values())
    reference_residual = np.linalg.norm(residual_open(model))
    for _ in range(3):
        rotation = random_rotation(rng)
        model.set_state(rest.transformed(rotation, rng.normal(size=3)))
        assert sum(model.energies().values()) < 1e-12 * reference_energy
        assert np.linalg.norm(residual_open(model)) < 1e-10 * reference_residual


def _closed_cylinder_model(comm, seam_angle=0.0):
    rest = S.cylinder(1.0, 1.5, 3, 8, seam_angle=seam_angle)
    return rest, ShellModel(rest, MATERIAL, comm=comm)


@pytest.mark.parametrize(
    "make",
    [
        lambda: S.cylinder(1.0, 1.5, 3, 8),
        lambda: S.torus(2.0, 0.6, 6, 5),
        lambda: S.sphere_zone(1.0, 0.2, 2.0, 4, 8),
    ],
    ids=["closed cylinder", "torus", "sphere zone"],
)
def test_closed_surfaces_rigid_motion_zero_energy_and_closed_residual(comm, rng, make):
    rest = make()
    model = ShellModel(rest, MATERIAL, comm=comm)

    def closed_residual_and_energy(surface):
        model.set_state(surface)
        solver.problem.state_to_vector(solver.x)
        solver.problem.update_state(solver.x)
        solver.problem.assemble_residual(solver.x, solver.f)
        return solver.f.norm(), sum(model.energies().values())

    with ShellSolver(model) as solver:
        assert solver.problem.prolongation is not None
        reference_residual, reference_energy = closed_residual_and_energy(deformed(rest, rng, 0.01))
        assert reference_residual > 0 and reference_energy > 0
        residual, energy = closed_residual_and_energy(rest.transformed(random_rotation(rng), rng.normal(size=3)))
        assert energy < 1e-12 * reference_energy
        assert residual < 1e-10 * reference_residual


def test_stiffness_spectrum_does_not_depend_on_the_seam(comm):
    spectra = []
    for seam in (0.0, 0.37, 2.0):
        _, model = _closed_cylinder_model(comm, seam)
        with ShellSolver(model) as solver:
            solver.problem.assemble_jacobian(solver.jacobian)
            dense = gather_matrix(solver.jacobian)
        assert dense.shape == (3 * 4 * 8 * 4,) * 2  # seam nodes kept once
        spectra.append(np.linalg.eigvalsh(0.5 * (dense + dense.T)))
    scale = np.abs(spectra[0]).max()
    for other in spectra[1:]:
        np.testing.assert_allclose(other, spectra[0], atol=1e-9 * scale)
    # six rigid modes, no spurious zero-energy modes from the seam
    assert np.sum(np.abs(spectra[0]) < 1e-9 * scale) == 6

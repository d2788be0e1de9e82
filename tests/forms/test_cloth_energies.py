"""The B-spline cloth paper's energies: the FEM Baraff-Witkin membrane and the quadratic bending
energy. Finite-difference checks, rigid motions, the projected Hessian, the plate benchmark and
the errors of models that do not apply."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import (
    central_difference,
    jacobian_dense,
    open_state_global,
    potential,
    random_rotation,
    residual_open,
)

from bhem_hpc.geometry import bspline as B
from bhem_hpc.geometry import surface as S
from bhem_hpc.model import bcs
from bhem_hpc.model.material import Material, MaterialError
from bhem_hpc.model.shell import AreaLoad, Loads, ModelError, ShellModel
from bhem_hpc.solver import ShellSolver

#: cotton with the FEM Baraff-Witkin membrane and the quadratic bending energy
COTTON_FBW = Material(young=2e6, poisson=0.243, thickness=3.18e-4, density=472.6, membrane="fbw",
                      bending="quadratic", shear_ratio=0.5)  # fmt: skip


def _perturbed(rest, rng, amplitude):
    return rest.with_nodal(rest.nodal + amplitude * rng.normal(size=rest.nodal.shape))


@pytest.fixture(params=["hermite", "bspline2"])
def cloth_model(request, comm, rng):
    rest = (
        S.flat_rectangle(0.3, 0.2, 3, 2) if request.param == "hermite" else B.flat_rectangle(0.3, 0.2, 4, 3, degree=2)
    )
    return ShellModel(rest, COTTON_FBW, hessian="exact", comm=comm, initial=_perturbed(rest, rng, 0.01)), rest


def test_gradient_and_hessian_match_central_differences(cloth_model, rng):
    model, _ = cloth_model
    q0 = open_state_global(model)
    gradient, hessian = residual_open(model), jacobian_dense(model)
    for _ in range(3):
        d = rng.normal(size=q0.shape)
        fd_energy = central_difference(model, q0, d, 1e-7, potential)
        assert abs(fd_energy - gradient @ d) < 1e-6 * abs(gradient @ d)
        fd_gradient = central_difference(model, q0, d, 1e-7, residual_open)
        assert np.linalg.norm(fd_gradient - hessian @ d) < 1e-5 * np.linalg.norm(hessian @ d)


def test_rigid_motions_have_zero_energy_and_residual(cloth_model, rng):
    model, rest = cloth_model
    reference_energy = potential(model)
    reference_residual = np.linalg.norm(residual_open(model))
    assert reference_energy > 0
    for _ in range(3):
        model.set_state(rest.transformed(random_rotation(rng), rng.normal(size=3)))
        assert abs(potential(model)) < 1e-12 * reference_energy
        assert np.linalg.norm(residual_open(model)) < 1e-9 * reference_residual


def test_projected_baraff_witkin_hessian_is_positive_semidefinite_and_exact_in_tension(comm, rng):
    rest = S.flat_rectangle(0.2, 0.2, 3, 3)
    compressed = rest.nodal.copy()
    compressed[..., 0, 0] *= 0.9
    compressed[..., 1, :] *= 0.9
    state = S.HermiteSurface(rest.grid, compressed + 1e-3 * rng.normal(size=compressed.shape))
    material = Material(young=2e6, poisson=0.243, thickness=3.18e-4, membrane="fbw", shear_ratio=1.0)
    exact = jacobian_dense(ShellModel(rest, material, hessian="exact", comm=comm, initial=state))
    projected = jacobian_dense(ShellModel(rest, material, hessian="projected", comm=comm, initial=state))
    scale = np.abs(exact).max()
    assert np.linalg.eigvalsh(0.5 * (exact + exact.T)).min() < -1e-4 * scale
    assert np.linalg.eigvalsh(0.5 * (projected + projected.T)).min() > -1e-12 * scale


def _plate_deflection(comm, spans: int) -> float:
    """Quadratic bending alone (membrane of a negligible stiffness), simply supported square plate,
    uniform load: the centre deflection over the closed form ``0.00406235 q a^4 / D``."""
    side, load = 1.0, 1e-5  # a deflection of 4e-4 thicknesses: the linear plate
    material = Material(young=1e5, poisson=0.3, thickness=1e-2, bending="quadratic")
    rest = B.flat_rectangle(side, side, spans, spans, degree=2)
    supports = [bcs.support_edge(rest, edge) for edge in bcs.EDGES]
    model = ShellModel(rest, material, Loads(area_loads=(AreaLoad((0.0, 0.0, -load)),)), supports, comm=comm)
    with ShellSolver(model, prefix="plate_") as solver:
        solver.solve()
    reference = 0.00406235 * load * side**4 / material.bending_stiffness
    return -model.displacement(0.5 * side, 0.5 * side)[2] / reference


def test_quadratic_bending_converges_to_the_simply_supported_plate(comm):
    ratios = {spans: _plate_deflection(comm, spans) for spans in (8, 16, 32)}
    errors = {spans: abs(r - 1) for spans, r in ratios.items()}
    assert errors[32] < 1e-3  # measured: 4.7e-3, 1.2e-3, 2.9e-4
    assert errors[8] / errors[16] > 3 and errors[16] / errors[32] > 3  # second order


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"membrane": "fbw"}, "material.shear_ratio is required"),
        ({"shear_ratio": 0.5}, "material.shear_ratio = 0.5 applies only to material.membrane = 'fbw'"),
        ({"membrane": "fbw", "shear_ratio": -1.0}, r"material.shear_ratio = -1.0 is invalid"),
        ({"membrane": "neo"}, "material.membrane = 'neo' is invalid"),
        ({"bending": "hinge"}, "material.bending = 'hinge' is invalid"),
    ],
)
def test_energy_models_that_do_not_apply_are_refused(kwargs, message):
    with pytest.raises(MaterialError, match=message):
        Material(young=2e6, poisson=0.243, thickness=3.18e-4, **kwargs)


def test_quadratic_bending_on_a_curved_rest_surface_is_refused(comm):
    rest = S.cylinder(1.0, 1.0, 3, 3, closed=False, angle=np.pi / 2)
    with pytest.raises(ModelError, match="material.bending = 'quadratic' needs a flat rest surface"):
        ShellModel(rest, Material(young=1e5, poisson=0.3, thickness=1e-2, bending="quadratic"), comm=comm)

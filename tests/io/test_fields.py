"""Output fields: their small-matrix algebra and energy densities (numpy only)."""

from __future__ import annotations

import numpy as np
import pytest

from bhem_hpc.geometry.grid import ParameterGrid
from bhem_hpc.geometry.surface import HermiteSurface
from bhem_hpc.io.fields import RestMetric, energy_densities, fundamental_forms, inverse_2x2, mean_curvature
from bhem_hpc.model.material import Material

pytestmark = pytest.mark.rank_free


def test_the_closed_form_2x2_inverse_is_lapacks(rng):
    """On 2000 seeded metrics (symmetric positive definite, condition numbers up to about 1e4) the
    adjugate inverse agrees with numpy's LAPACK inverse to 1e-10 relative, and undoes each matrix."""
    factors = rng.normal(size=(2000, 2, 2))
    metrics = factors @ factors.transpose(0, 2, 1) + 1e-4 * np.eye(2)
    inverse = inverse_2x2(metrics)
    np.testing.assert_allclose(inverse, np.linalg.inv(metrics), rtol=1e-10, atol=1e-10 * np.abs(inverse).max())
    np.testing.assert_allclose(inverse @ metrics, np.broadcast_to(np.eye(2), metrics.shape), atol=1e-8)


def _sheet(stretch: float = 1.0, wrinkle: float = 0.0, seed: int | None = None) -> HermiteSurface:
    """A unit square of 6 x 6 patches stretched by ``stretch`` along x, with seeded random nodal
    offsets of size ``wrinkle``."""
    grid = ParameterGrid(6, 6, (0.0, 1.0), (0.0, 1.0))
    x1, x2 = np.meshgrid(np.linspace(0, 1, 7), np.linspace(0, 1, 7), indexing="ij")
    nodal = np.zeros((7, 7, 4, 3))
    nodal[..., 0, 0], nodal[..., 0, 1], nodal[..., 1, 0], nodal[..., 2, 1] = stretch * x1, x2, stretch, 1.0
    if seed is not None:
        nodal += wrinkle * np.random.default_rng(seed).normal(size=nodal.shape)
    return HermiteSurface(grid, nodal)


def test_a_uniformly_stretched_sheet_has_the_saint_venant_membrane_density():
    """Stretched by 1.1 along x: Green strain e = (1.1^2 - 1) / 2 along x, membrane density
    h (lambda e^2 / 2 + mu e^2) with the plane-stress lambda, no bending, no curvature."""
    material = Material(young=2e6, poisson=0.243, thickness=3.18e-4, density=472.6)
    params = np.random.default_rng(3).uniform(0.0, 1.0, size=(50, 2))
    rest = _sheet().evaluate(params[:, 0], params[:, 1])
    current = _sheet(1.1).evaluate(params[:, 0], params[:, 1])
    membrane, bending = energy_densities(RestMetric(rest), current, material)
    e, nu, young = 0.5 * (1.1**2 - 1.0), material.poisson, material.young
    lmbda, mu = young * nu / (1 - nu**2), young / (2 * (1 + nu))
    np.testing.assert_allclose(membrane, material.thickness * (0.5 * lmbda + mu) * e**2, rtol=1e-12)
    np.testing.assert_allclose(bending, 0.0, atol=1e-12 * membrane.max())
    np.testing.assert_allclose(mean_curvature(current), 0.0, atol=1e-10)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_densities_are_saint_venants_of_the_metric_changes_with_or_without_given_forms(seed):
    """On seeded wrinkled sheets: the densities are h W(E) and h^3 / 3 W(K) of the changes of the first
    and second fundamental forms, W(S) = lambda tr(A^-1 S)^2 / 2 + mu tr((A^-1 S)^2) with the rest
    metric A, point by point with numpy's inverse; the forms an output frame passes (computed once
    for the curvature too) give the same densities and curvature."""
    material = Material(young=2e6, poisson=0.243, thickness=3.18e-4, density=472.6)
    params = np.random.default_rng(seed).uniform(0.0, 1.0, size=(200, 2))
    rest = _sheet(1.0, 0.01, seed).evaluate(params[:, 0], params[:, 1])
    current = _sheet(1.05, 0.02, seed + 10).evaluate(params[:, 0], params[:, 1])
    forms = fundamental_forms(current)
    membrane, bending = energy_densities(RestMetric(rest), current, material)
    (a0, b0), (a, b) = fundamental_forms(rest), forms
    nu, young, h = material.poisson, material.young, material.thickness
    lmbda, mu = young * nu / (1 - nu**2), young / (2 * (1 + nu))
    mixed = [np.linalg.inv(a0) @ (0.5 * (a - a0)), np.linalg.inv(a0) @ (0.5 * (b - b0))]
    w = [0.5 * lmbda * np.trace(m, axis1=1, axis2=2) ** 2 + mu * np.trace(m @ m, axis1=1, axis2=2) for m in mixed]
    np.testing.assert_allclose(membrane, h * w[0], rtol=1e-9, atol=1e-12 * np.abs(h * w[0]).max())
    np.testing.assert_allclose(bending, h**3 / 3 * w[1], rtol=1e-9, atol=1e-12 * np.abs(w[1]).max() * h**3)
    given = energy_densities(RestMetric(rest), current, material, forms)
    np.testing.assert_array_equal(given[0], membrane)
    np.testing.assert_array_equal(given[1], bending)
    np.testing.assert_array_equal(mean_curvature(current, forms), mean_curvature(current))
    assert np.abs(bending).max() > 0.0  # the wrinkles bend the sheet

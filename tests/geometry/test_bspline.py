"""B-spline surfaces of degree 2 and 3: basis, extraction, exact reproduction, continuity, Bezier nets, files."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import assert_imports_without

from bhem_hpc.collision.bezier import evaluate_many
from bhem_hpc.geometry import bspline as B
from bhem_hpc.geometry.surface import ParameterGrid, SurfaceError

pytestmark = pytest.mark.rank_free  # no communicator: the same computation on every rank

CASES = [(p, periodic) for p in B.DEGREES for periodic in (False, True)]


def test_bspline_module_imports_numpy_only():
    assert_imports_without("bhem_hpc.geometry.bspline")


@pytest.mark.parametrize(("degree", "periodic"), CASES)
def test_extracted_basis_is_a_nonnegative_partition_of_unity(degree, periodic, rng):
    spans = 6
    extraction = B._extraction(spans, degree, periodic)
    t = rng.random(50)
    for k in range(spans):
        values = np.einsum("ij,sj->si", extraction[k], B.bernstein(t, degree))
        np.testing.assert_allclose(values.sum(axis=1), 1.0, atol=1e-14)
        assert values.min() > -1e-14


@pytest.mark.parametrize("degree", B.DEGREES)
def test_extraction_equals_cox_de_boor_on_open_knots(degree, rng):
    spans = 5
    knots = B.open_knots(spans, degree)
    extraction = B._extraction(spans, degree, False)
    for k in range(spans):
        t = rng.random(20)
        direct = B.basis_functions(knots, degree, k + degree, k + t)
        np.testing.assert_allclose(np.einsum("ij,sj->si", extraction[k], B.bernstein(t, degree)), direct, atol=1e-14)


@pytest.mark.parametrize("degree", B.DEGREES)
def test_polynomials_of_the_degree_are_reproduced_exactly(degree, rng):
    """Interpolation reproduces every tensor polynomial of the space's degree, derivatives included."""
    coefficients = rng.normal(size=(degree + 1, degree + 1, 3))

    def poly(a, b, d1=0, d2=0):
        out = 0.0
        for i in range(d1, degree + 1):
            for j in range(d2, degree + 1):
                factor = math.perm(i, d1) * math.perm(j, d2)
                out = out + factor * coefficients[i, j] * (a[..., None] ** (i - d1)) * (b[..., None] ** (j - d2))
        return out

    grid = ParameterGrid(4, 3, (-0.5, 1.5), (0.0, 0.9))
    surface = B.from_callable(lambda a, b: poly(a, b), grid, degree=degree)
    a, b = np.meshgrid(rng.uniform(-0.5, 1.5, 13), rng.uniform(0.0, 0.9, 11), indexing="ij")
    point = surface.evaluate(a, b)
    for value, (d1, d2) in ((point.x, (0, 0)), (point.a1, (1, 0)), (point.a2, (0, 1)), (point.a11, (2, 0)),
                            (point.a12, (1, 1)), (point.a22, (0, 2))):  # fmt: skip
        np.testing.assert_allclose(value, poly(a, b, d1, d2), atol=1e-10)


@pytest.mark.parametrize(("degree", "periodic"), CASES)
def test_derivatives_match_central_differences(degree, periodic, rng):
    surface = B.torus(1.0, 0.3, 6, 5, degree=degree) if periodic else B.sphere_zone(0.7, 0.3, 2.2, 5, 8, degree=degree)
    g = surface.grid
    a = g.xi1_range[0] + (0.1 + 0.8 * rng.random(10)) * (g.xi1_range[1] - g.xi1_range[0])
    b = g.xi2_range[0] + (0.1 + 0.8 * rng.random(10)) * (g.xi2_range[1] - g.xi2_range[0])
    h = 1e-6
    point = surface.evaluate(a, b)

    def central(attribute: str, axis: int) -> np.ndarray:
        step = (h, 0.0) if axis == 0 else (0.0, h)
        plus = getattr(surface.evaluate(a + step[0], b + step[1]), attribute)
        minus = getattr(surface.evaluate(a - step[0], b - step[1]), attribute)
        return (plus - minus) / (2 * h)

    np.testing.assert_allclose(point.a1, central("x", 0), atol=1e-7)
    np.testing.assert_allclose(point.a2, central("x", 1), atol=1e-7)
    np.testing.assert_allclose(point.a11, central("a1", 0), atol=1e-6)
    np.testing.assert_allclose(point.a12, central("a2", 0), atol=1e-6)
    np.testing.assert_allclose(point.a22, central("a2", 1), atol=1e-6)


@pytest.mark.parametrize(("degree", "periodic"), CASES)
def test_smoothness_across_knots_and_the_seam(degree, periodic, rng):
    """C^(p-1): the derivatives up to p - 1 agree on both sides of every interior knot (and the seam)."""
    grid = ParameterGrid(5, 4, (0.0, 1.0), (0.0, 1.0), periodic, False)
    control = rng.normal(size=(*B.BSplineSurface.control_shape_of(grid, degree), 3))
    surface = B.BSplineSurface(grid, degree, control)
    eps = 1e-9
    knots = np.arange(1, 5) * grid.h1
    if periodic:
        knots = np.append(knots, 0.0)
    b = rng.random(len(knots))
    left, right = surface.evaluate(np.mod(knots - eps, 1.0), b), surface.evaluate(knots + eps, b)
    np.testing.assert_allclose(left.x, right.x, atol=1e-7)
    np.testing.assert_allclose(left.a1, right.a1, atol=1e-6)
    jump = np.abs(left.a11 - right.a11).max()
    if degree == 3:
        assert jump < 1e-5
    else:
        assert jump > 1e-3  # C1 only: the second derivative jumps at knots of random data


@pytest.mark.parametrize("degree", B.DEGREES)
def test_interpolation_converges_at_least_at_the_degree_plus_one_rate(degree):
    errors = []
    for n in (6, 12, 24):
        surface = B.cylinder(1.0, 1.0, 2, n, degree=degree)
        z, phi = np.meshgrid(np.linspace(0.0, 1.0, 5), np.linspace(0.0, 2 * np.pi, 401), indexing="ij")
        errors.append(np.abs(np.linalg.norm(surface.evaluate(z, phi).x[..., :2], axis=-1) - 1.0).max())
    rates = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(rates > degree + 0.8), (errors, rates)


@pytest.mark.parametrize(("degree", "periodic"), CASES)
def test_bezier_nets_are_exact_and_elevated_to_bicubic(degree, periodic, rng):
    surface = (
        B.torus(1.0, 0.3, 6, 5, degree=degree)
        if periodic
        else B.annulus_sector(0.2, 0.9, 0.0, 2.0, 4, 5, degree=degree)
    )
    g = surface.grid
    nets = surface.bezier_nets()
    assert nets.shape == (g.n1 * g.n2, 4, 4, 3)
    patch = rng.integers(0, g.n1 * g.n2, 40)
    u, v = rng.random(40), rng.random(40)
    xi1 = g.xi1_range[0] + (patch // g.n2 + u) * g.h1
    xi2 = g.xi2_range[0] + (patch % g.n2 + v) * g.h2
    np.testing.assert_allclose(evaluate_many(nets[patch], u, v), surface.evaluate(xi1, xi2).x, atol=1e-14)


def test_clamped_ends_depend_on_the_boundary_control_points_only(rng):
    grid = ParameterGrid(4, 3, (0.0, 1.0), (0.0, 1.0))
    for degree in B.DEGREES:
        control = rng.normal(size=(*B.BSplineSurface.control_shape_of(grid, degree), 3))
        moved = control.copy()
        moved[1:-1, 1:-1] += rng.normal(size=moved[1:-1, 1:-1].shape)
        s = np.linspace(0.0, 1.0, 11)
        for a, b in ((s * 0, s), (s * 0 + 1, s), (s, s * 0), (s, s * 0 + 1)):
            np.testing.assert_allclose(
                B.BSplineSurface(grid, degree, control).evaluate(a, b).x,
                B.BSplineSurface(grid, degree, moved).evaluate(a, b).x,
                atol=1e-14,
            )
        np.testing.assert_allclose(B.BSplineSurface(grid, degree, control).evaluate(0.0, 1.0).x, control[0, -1])


def test_files_round_trip_and_bad_input_is_refused(tmp_path):
    surface = B.torus(1.0, 0.3, 6, 5, degree=3)
    surface.save(tmp_path / "torus.npz")
    back = B.BSplineSurface.load(tmp_path / "torus.npz")
    assert back.grid == surface.grid and back.degree == 3
    np.testing.assert_array_equal(back.control, surface.control)
    grid = ParameterGrid(4, 3, (0.0, 1.0), (0.0, 1.0))
    with pytest.raises(SurfaceError, match="degree must be one of"):
        B.BSplineSurface(grid, 4, np.zeros((8, 7, 3)))
    with pytest.raises(SurfaceError, match=r"shape \(6, 5, 3\)"):
        B.BSplineSurface(grid, 2, np.zeros((6, 4, 3)))
    with pytest.raises(SurfaceError, match="needs at least 4 knot spans"):
        B.cylinder(1.0, 1.0, 2, 3, degree=3)
    data = dict(np.load(tmp_path / "torus.npz"))
    np.savez(tmp_path / "short.npz", **{**data, "control": data["control"][:-1]})
    with pytest.raises(SurfaceError, match="short.npz: key 'control'"):
        B.BSplineSurface.load(tmp_path / "short.npz")
    np.savez(tmp_path / "nodegree.npz", **{k: v for k, v in data.items() if k != "degree"})
    with pytest.raises(SurfaceError, match="missing key 'degree'"):
        B.BSplineSurface.load(tmp_path / "nodegree.npz")
    np.savez(tmp_path / "hermite.npz", **{**data, "format": np.array("bhem-hermite-surface")})
    with pytest.raises(SurfaceError, match="key 'format'"):
        B.BSplineSurface.load(tmp_path / "hermite.npz")

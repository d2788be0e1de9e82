"""The numpy surface model: constructors, evaluation, Bezier nets, tessellation, files."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import REPO, assert_imports_without

from bhem_hpc.geometry import hermite
from bhem_hpc.geometry import surface as S

pytestmark = pytest.mark.rank_free  # no communicator: the same computation on every rank


def test_surface_module_imports_numpy_only():
    modules = (
        "bhem_hpc.geometry.surface",
        "bhem_hpc.geometry.hermite",
        "bhem_hpc.model.bcs",
        "bhem_hpc.studies.references",
        "bhem_hpc.scene",
    )
    for module in modules:
        assert_imports_without(module)


def test_cylinder_interpolates_nodes_and_converges_at_fourth_order():
    errors = []
    for n in (4, 8, 16):
        cyl = S.cylinder(2.0, 3.0, 2, n)
        z, phi = np.meshgrid(np.linspace(0, 3, 7), np.linspace(0, 2 * np.pi, 41), indexing="ij")
        pt = cyl.evaluate(z, phi)
        radius = np.linalg.norm(pt.x[..., :2], axis=-1)
        errors.append(np.abs(radius - 2.0).max())
        np.testing.assert_allclose(pt.x[..., 2], z, atol=1e-14)
    rates = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(rates > 3.8), rates
    nodes = S.cylinder(2.0, 3.0, 2, 8)
    xi1, xi2 = nodes.grid.node_parameters()
    pt = nodes.evaluate(xi1, xi2)
    np.testing.assert_allclose(pt.x, nodes.nodal[:, :, 0], atol=1e-14)
    np.testing.assert_allclose(pt.a1, nodes.nodal[:, :, 1], atol=1e-14)
    np.testing.assert_allclose(pt.a2, nodes.nodal[:, :, 2], atol=1e-14)
    np.testing.assert_allclose(pt.a12, nodes.nodal[:, :, 3], atol=1e-14)


def test_periodic_evaluation_wraps():
    cyl = S.cylinder(1.0, 1.0, 2, 6, seam_angle=0.3)
    a = cyl.evaluate(np.array([0.4]), np.array([0.3 + 0.1]))
    b = cyl.evaluate(np.array([0.4]), np.array([0.3 + 0.1 + 2 * np.pi]))
    np.testing.assert_allclose(a.x, b.x, atol=1e-14)
    np.testing.assert_allclose(a.a2, b.a2, atol=1e-14)


def test_derivatives_match_finite_differences(rng):
    surface = S.HermiteSurface(S.ParameterGrid(3, 2, (0.0, 1.0), (0.0, 2.0)), rng.normal(size=(4, 3, 4, 3)))
    xi1, xi2 = rng.random(20) * 0.98 + 0.01, rng.random(20) * 1.9 + 0.05
    h = 1e-6
    pt = surface.evaluate(xi1, xi2)
    fd1 = (surface.evaluate(xi1 + h, xi2).x - surface.evaluate(xi1 - h, xi2).x) / (2 * h)
    fd2 = (surface.evaluate(xi1, xi2 + h).a2 - surface.evaluate(xi1, xi2 - h).a2) / (2 * h)
    fd12 = (surface.evaluate(xi1 + h, xi2).a2 - surface.evaluate(xi1 - h, xi2).a2) / (2 * h)
    scale = np.abs(surface.nodal).max() * 20
    np.testing.assert_allclose(pt.a1, fd1, atol=1e-7 * scale)
    np.testing.assert_allclose(pt.a22, fd2, atol=1e-6 * scale)
    np.testing.assert_allclose(pt.a12, fd12, atol=1e-6 * scale)


@pytest.mark.parametrize(("complex_ok", "first_tol", "mixed_tol"), [(True, 1e-14, 1e-12), (False, 1e-12, 1e-10)])
def test_numerical_derivatives_near_machine_precision(complex_ok, first_tol, mixed_tol):
    def position(a, b):
        if not complex_ok and np.iscomplexobj(a):
            raise TypeError("real only")
        return np.stack([np.cos(a) * np.exp(b), np.sin(a * b), a**2 * np.cos(b)], axis=-1)

    grid = S.ParameterGrid(3, 4, (0.1, 1.3), (-0.5, 0.5))
    numeric = S.from_callable(position, grid)
    a, b = grid.node_parameters()
    exact = np.stack(
        [
            np.stack([-np.sin(a) * np.exp(b), b * np.cos(a * b), 2 * a * np.cos(b)], -1),
            np.stack([np.cos(a) * np.exp(b), a * np.cos(a * b), -(a**2) * np.sin(b)], -1),
            np.stack([-np.sin(a) * np.exp(b), np.cos(a * b) - a * b * np.sin(a * b), -2 * a * np.sin(b)], -1),
        ],
        axis=2,
    )
    np.testing.assert_allclose(numeric.nodal[:, :, 1:3], exact[:, :, :2], atol=first_tol)
    np.testing.assert_allclose(numeric.nodal[:, :, 3], exact[:, :, 2], atol=mixed_tol)


def test_bezier_nets_reproduce_the_patches(rng):
    surface = S.torus(2.0, 0.5, 5, 4)
    nets = surface.bezier_control_points()
    assert nets.shape == (5, 4, 4, 4, 3)
    p1, p2 = rng.integers(0, 5, 30), rng.integers(0, 4, 30)
    t1, t2 = rng.random(30), rng.random(30)

    def bernstein(t):
        return np.stack([(1 - t) ** 3, 3 * t * (1 - t) ** 2, 3 * t**2 * (1 - t), t**3], -1)

    bez = np.einsum("nk,nl,nklc->nc", bernstein(t1), bernstein(t2), nets[p1, p2])
    g = surface.grid
    ref = surface.evaluate(g.xi1_range[0] + (p1 + t1) * g.h1, g.xi2_range[0] + (p2 + t2) * g.h2).x
    np.testing.assert_allclose(bez, ref, atol=1e-13)
    # the Hermite->Bezier map in one parameter
    v0, t0, v1, t1_ = rng.normal(size=4)
    b = hermite.HERMITE_TO_BEZIER @ np.array([v0, t0, v1, t1_])
    assert b[0] == v0 and b[3] == v1 and math.isclose(3 * (b[1] - b[0]), t0) and math.isclose(3 * (b[3] - b[2]), t1_)


def test_tessellation_closes_periodic_directions():
    surface = S.cylinder(1.0, 2.0, 3, 6)
    points, quads, params = surface.tessellate(4)
    assert points.shape == ((3 * 4 + 1) * 6 * 4, 3) and quads.shape == (3 * 4 * 6 * 4, 4)
    assert quads.max() == len(points) - 1 and params.shape == (len(points), 2)
    edge = np.linalg.norm(points[quads] - points[np.roll(quads, 1, axis=1)], axis=-1)
    assert edge.max() < 2 * np.pi / 24 * 1.01  # no quad spans the seam


def test_constructors_cover_the_shapes():
    zone = S.sphere_zone(1.5, 0.1, np.pi / 2, 4, 8)
    pt = zone.evaluate(*zone.grid.node_parameters())
    np.testing.assert_allclose(np.linalg.norm(pt.x, axis=-1), 1.5, atol=1e-14)
    annulus = S.annulus_sector(0.5, 1.0, 0.0, np.pi / 2, 2, 3)
    assert not annulus.grid.periodic2
    assert S.annulus_sector(0.5, 1.0, 0.0, 2 * np.pi, 2, 6).grid.periodic2
    flat = S.flat_rectangle(2.0, 1.0, 4, 2)
    assert flat.nodal.shape == (5, 3, 4, 3)
    open_cyl = S.cylinder(1.0, 1.0, 2, 4, closed=False, angle=np.pi / 2)
    assert open_cyl.nodal.shape == (3, 5, 4, 3)


def test_file_round_trip_and_errors(tmp_path):
    surface = S.cylinder(1.0, 2.0, 3, 5)
    path = tmp_path / "cyl.npz"
    surface.save(path)
    loaded = S.HermiteSurface.load(path)
    assert loaded.grid == surface.grid
    np.testing.assert_array_equal(loaded.nodal, surface.nodal)
    np.savez(tmp_path / "bad.npz", format=np.array("bhem-hermite-surface"), version=np.array(1))
    with pytest.raises(S.SurfaceError, match=r"bad\.npz: missing key 'patches'"):
        S.HermiteSurface.load(tmp_path / "bad.npz")
    with pytest.raises(S.SurfaceError, match="cannot read"):
        S.HermiteSurface.load(tmp_path / "missing.npz")


def test_bad_surfaces_are_rejected():
    grid = S.ParameterGrid(2, 2, (0.0, 1.0), (0.0, 1.0))
    nodal = np.zeros((3, 3, 4, 3))
    nodal[1, 2, 3, 1] = np.nan
    with pytest.raises(S.SurfaceError, match=r"NaN/Inf: value nan at node \(1, 2\), kind d12, component 1"):
        S.HermiteSurface(grid, nodal)
    with pytest.raises(S.SurfaceError, match=r"degenerate: \|a1 x a2\| = 0"):
        S.HermiteSurface(grid, np.zeros((3, 3, 4, 3))).check_regular()
    with pytest.raises(S.SurfaceError, match="pole is a degenerate parameter point"):
        S.sphere_zone(1.0, 0.0, 1.0, 4, 8)  # touches the pole
    with pytest.raises(S.SurfaceError, match="n1 must be a positive integer"):
        S.ParameterGrid(0, 2, (0.0, 1.0), (0.0, 1.0))
    with pytest.raises(S.SurfaceError, match="xi1=1.5 lies outside"):
        S.flat_rectangle(1.0, 1.0, 2, 2).evaluate(np.array(1.5), np.array(0.5))


def test_shipped_nodal_files_load():
    root = REPO / "meshes"
    zone = S.HermiteSurface.load(root / "hemisphere_zone_8x24.npz")
    assert zone.grid.periodic2 and not zone.grid.periodic1
    np.testing.assert_allclose(np.linalg.norm(zone.nodal[:, :, 0], axis=-1), 0.5, rtol=1e-14)
    cyl = S.HermiteSurface.load(root / "cylinder_12x24.npz")
    assert cyl.grid.node_shape == (13, 24)


def test_constructor_options_are_keywords_and_edge_helpers_take_the_surface():
    """A B-spline constructor's degree and options, and a Hermite one's options, are keyword-only (a
    flag in the degree's place is refused at the call); every edge helper takes the surface."""
    from bhem_hpc.geometry import bspline as B
    from bhem_hpc.model import bcs

    with pytest.raises(TypeError, match="positional argument"):
        B.cylinder(1.0, 1.0, 4, 4, False, 1.0)
    with pytest.raises(TypeError, match="positional argument"):
        S.cylinder(1.0, 1.0, 4, 4, False, 1.0)
    roof = B.cylinder(1.0, 1.0, 4, 4, degree=3, closed=False, angle=1.0)
    assert roof.degree == 3 and not roof.grid.periodic2
    hermite = S.flat_rectangle(1.0, 1.0, 2, 2)
    supported, reference = bcs.simply_supported(hermite, "xi1_min"), bcs.support_edge(hermite, "xi1_min")
    assert np.array_equal(supported.nodes, reference.nodes) and supported.kinds == reference.kinds == (0, 2)
    with pytest.raises(TypeError, match="takes the surface"):
        bcs.simply_supported(hermite.grid, "xi1_min")

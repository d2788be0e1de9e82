"""The compiled line crossings against the numpy search they compile, and against exact shapes."""

from __future__ import annotations

import numpy as np
import pytest

from bhem_hpc.compiled import line_crossings as compiled
from bhem_hpc.compiled import patch_kernels as kernels
from bhem_hpc.geometry import nurbs
from bhem_hpc.geometry import rational_bezier as rb
from bhem_hpc.geometry.bspline import bernstein
from bhem_hpc.solids.quadrature import _line_grid, model_bounds
from bhem_hpc.studies import sem_models, sem_table


def _random_nets(rng, count: int, degrees: tuple[int, int]) -> np.ndarray:
    """Wavy rational patches over the unit square: ``(count, p + 1, q + 1, 4)``, weights in [0.5, 2]."""
    p, q = degrees
    s, t = np.meshgrid(np.linspace(0, 1, p + 1), np.linspace(0, 1, q + 1), indexing="ij")
    points = np.stack([s, t, np.zeros_like(s)], axis=-1)[None] + 0.3 * rng.standard_normal((count, p + 1, q + 1, 3))
    points[..., :2] += rng.uniform(-1, 1, (count, 1, 1, 2))
    weights = rng.uniform(0.5, 2.0, (count, p + 1, q + 1, 1))
    return np.concatenate([points * weights, weights], axis=-1)


def _assert_same_crossings(expected: rb.LineCrossings, found: rb.LineCrossings, size: float) -> None:
    np.testing.assert_array_equal(found.line, expected.line)
    np.testing.assert_array_equal(found.direction, expected.direction)
    # both solve to the Newton tolerance of the residual (1e-10 of the size); a crossing at a
    # slant moves along the line by that over the cosine
    np.testing.assert_allclose(found.position, expected.position, atol=1e-7 * size)


@pytest.mark.parametrize("degrees", [(1, 1), (2, 1), (2, 2), (3, 2), (3, 3), (4, 2)])
def test_compiled_crossings_equal_the_numpy_search_on_random_rational_patches(rng, degrees):
    nets = _random_nets(rng, 12, degrees)
    lines = np.linspace(-1.2, 2.2, 37)
    for axis in range(3):
        expected = rb.axis_line_crossings(nets, axis, lines, lines)
        found = compiled.axis_line_crossings(nets, axis, lines, lines)
        assert len(expected.line) > 50
        _assert_same_crossings(expected, found, 3.0)
        # the crossing lies on its patch, on its line
        point = rb.evaluate(nets[found.patch], found.s, found.t)[0]
        across = [a for a in range(3) if a != axis]
        np.testing.assert_allclose(point[:, across[0]], lines[found.line // len(lines)], atol=1e-8)
        np.testing.assert_allclose(point[:, axis], found.position, atol=1e-6)


@pytest.mark.parametrize("model", ["sphere", "torus", "rocket", "mug"])
def test_compiled_crossings_equal_the_numpy_search_on_models(model):
    parts = {"sphere": lambda: [nurbs.sphere(1.0)], "torus": lambda: [nurbs.torus(1.0, 0.3)],
             "rocket": sem_models.rocket, "mug": sem_models.mug}[model]()  # fmt: skip
    lo, hi = model_bounds(parts)
    for axis in range(3):
        _, _, (first, second) = _line_grid(lo, hi, axis, 24)
        for nets, _ in nurbs.bezier_nets_by_degree(parts):
            expected = rb.axis_line_crossings(nets, axis, first, second)
            _assert_same_crossings(expected, compiled.axis_line_crossings(nets, axis, first, second), np.ptp(hi - lo))


def test_compiled_crossings_on_a_seam_near_the_pole_are_found_once():
    """The refined mug's cup at 16 lines along z: a line 1e-17 m off the seam plane y = 0 meets the
    bottom near the axis on the edge of two patches, where a crossing converged to the residual's
    tolerance lands up to 1e-8 beyond the edge of either; it must be found once, as the numpy
    search finds it."""
    parts = sem_models.refined(sem_models.mug(), sem_table.MUG_REFINEMENT)
    lo, hi = model_bounds(parts)
    _, _, (first, second) = _line_grid(lo, hi, 2, 16)
    nets = parts[0].bezier_patches.nets
    expected = rb.axis_line_crossings(nets, 2, first, second)
    found = compiled.axis_line_crossings(nets, 2, first, second)
    assert len(expected.line) == 176
    _assert_same_crossings(expected, found, np.ptp(hi - lo))
    # every line through the cup leaves it as often as it enters
    winding = np.bincount(found.line, weights=found.direction, minlength=len(first) * len(second))
    np.testing.assert_array_equal(winding, 0)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_compiled_axis_lines_cross_the_sphere_exactly_twice(axis):
    radius, count = 1.5, 48
    # an odd count puts lines through the seams between patches (they must count once)
    coordinates = -radius + (np.arange(count + 1) + 0.5) * 2 * radius / (count + 1)
    crossings = compiled.axis_line_crossings(nurbs.sphere(radius).bezier_patches.nets, axis, coordinates, coordinates)
    a, b = coordinates[crossings.line // len(coordinates)], coordinates[crossings.line % len(coordinates)]
    np.testing.assert_allclose(np.abs(crossings.position), np.sqrt(radius**2 - a**2 - b**2), atol=1e-8)
    np.testing.assert_array_equal(crossings.direction, np.sign(crossings.position))
    inside = (coordinates[:, None] ** 2 + coordinates[None, :] ** 2 < radius**2).ravel()
    np.testing.assert_array_equal(np.bincount(crossings.line, minlength=inside.size), 2 * inside)


def test_patch_kernels_evaluate_and_split_as_the_numpy_patches(rng):
    nets = _random_nets(rng, 6, (3, 2))
    s, t = rng.random(6), rng.random(6)
    point, x_s, x_t = rb.evaluate(nets, s, t)
    basis, out = np.empty((4, 4)), np.empty((3, 3))
    for k in range(6):
        kernels.evaluate(nets[k], s[k], t[k], basis, out)
        np.testing.assert_allclose(out, np.stack([point[k], x_s[k], x_t[k]]), rtol=1e-12, atol=1e-12)
    scratch, quarters = np.empty((2, 4, 3, 4)), np.empty((4, 4, 3, 4))
    kernels.quarters(nets[0], scratch, quarters, 0)
    boxes = np.array(kernels.QUARTERS)
    np.testing.assert_allclose(quarters, rb.subpatches(np.repeat(nets[:1], 4, axis=0), boxes), atol=1e-14)
    value, slope = np.empty(5), np.empty(5)
    kernels.bernstein(0.3, 4, value, slope)
    np.testing.assert_allclose(value, bernstein(np.array([0.3]), 4)[0], atol=1e-15)
    np.testing.assert_allclose(slope, bernstein(np.array([0.3]), 4, 1)[0], atol=1e-14)


def test_ruled_patches_are_crossed_exactly_and_on_their_axis_at_the_apexes():
    """A can of revolution (degree (2, 1) rational patches): lines along x cross its wall at
    +-sqrt(r^2 - y^2) to round-off; lines along z cross the bottom and the top once each, the one
    on the axis through the collapsed edges of all four quarters."""
    radius, height = 0.3, 0.4
    profile = np.array([(0.0, 0.0), (radius, 0.0), (radius, height), (0.0, height)])
    can = nurbs.revolve(profile, np.ones(4), np.array([0.0, 0.0, 1 / 3, 2 / 3, 1.0, 1.0]), 1, "can")
    nets = can.bezier_patches.nets
    across = np.linspace(-0.34, 0.34, 15)  # through the axis (0) and outside the can, none tangent
    along_x = compiled.axis_line_crossings(nets, 0, across, np.linspace(0.01, 0.39, 7))
    y = across[along_x.line // 7]
    np.testing.assert_allclose(np.abs(along_x.position), np.sqrt(radius**2 - y**2), rtol=1e-13, atol=1e-15)
    np.testing.assert_array_equal(along_x.direction, np.sign(along_x.position))
    along_z = compiled.axis_line_crossings(nets, 2, across, across)
    a, b = across[along_z.line // 15], across[along_z.line % 15]
    inside = np.hypot(across[:, None], across[None, :]).ravel() < radius
    np.testing.assert_array_equal(np.bincount(along_z.line, minlength=225), 2 * inside)
    np.testing.assert_allclose(along_z.position, np.where(along_z.direction > 0, height, 0.0), atol=1e-15)
    assert np.all(np.hypot(a, b) < radius)

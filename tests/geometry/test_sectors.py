"""Open sectors of cylinders, spheres and annuli by angle ranges, and full turns cut along one line
(a slit: two separate edges at the same place)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bhem_hpc.geometry import bspline as B
from bhem_hpc.geometry import surface as S
from bhem_hpc.model import bcs

pytestmark = pytest.mark.rank_free  # no communicator: the same computation on every rank


@pytest.mark.parametrize("shapes", [S, B])
def test_a_slit_full_turn_has_two_edges_at_the_same_place(shapes):
    spline = {} if shapes is S else {"degree": 3}
    annulus = shapes.annulus_sector(0.5, 1.0, 0.0, 2 * math.pi, 2, 12, **spline, closed=False)
    sphere = shapes.sphere_zone(1.0, 0.3, 1.2, 3, 12, **spline, closed=False)
    for surface in (annulus, sphere):
        assert not surface.grid.periodic2
        low, high = bcs.edge_nodes(surface.grid, "xi2_min", surface.node_shape), bcs.edge_nodes(
            surface.grid, "xi2_max", surface.node_shape
        )
        assert not set(map(tuple, low)) & set(map(tuple, high))  # separate DOFs
        t = np.linspace(*surface.grid.xi1_range, 7)
        start = surface.evaluate(t, np.full_like(t, surface.grid.xi2_range[0])).x
        end = surface.evaluate(t, np.full_like(t, surface.grid.xi2_range[1])).x
        np.testing.assert_allclose(start, end, atol=1e-12)  # ... at the same place


def test_sectors_by_angle_ranges():
    sector = S.sphere_zone(2.0, 0.4, 1.4, 4, 6, azimuth=(0.5, 1.5))
    assert not sector.grid.periodic2 and sector.grid.xi2_range == (0.5, 1.5)
    point = sector.evaluate(np.array(1.4), np.array(1.5)).x  # a node: exact
    np.testing.assert_allclose(point, 2.0 * np.array([math.sin(1.4) * math.cos(1.5), math.sin(1.4) * math.sin(1.5),
                                                      math.cos(1.4)]), atol=1e-12)  # fmt: skip
    roof = S.cylinder(25.0, 50.0, 4, 4, closed=False, angle=math.radians(80), seam_angle=math.radians(50))
    np.testing.assert_allclose(roof.evaluate(np.array(0.0), np.array(math.radians(90))).x, [0, 25, 0], atol=1e-12)
    assert S.annulus_sector(0.5, 1.0, 0.0, 2 * math.pi, 2, 8).grid.periodic2  # a full turn closes by default


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: S.annulus_sector(0.5, 1.0, 0.0, 1.0, 2, 4, closed=True), r"a closed annulus sector needs a full turn"),
        (lambda: S.sphere_zone(1.0, 0.3, 1.2, 2, 4, azimuth=(0.0, 7.0)), r"angle range of \(0, 2\*pi\]"),
        (lambda: B.sphere_zone(1.0, 0.3, 1.2, 2, 4, degree=2, azimuth=(1.0, 1.0)), r"angle range of \(0, 2\*pi\]"),
    ],
)
def test_bad_angle_ranges_are_refused(make, message):
    with pytest.raises(S.SurfaceError, match=message):
        make()

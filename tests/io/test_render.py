"""The patch ray tracer against a rasterized fine tessellation; the ray benchmark's numbers."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import ray_triangle_distances

from bhem_hpc.benchmarks.timing import ray_benchmark
from bhem_hpc.geometry import surface as S
from bhem_hpc.geometry.nurbs import cylinder_panel
from bhem_hpc.geometry.rational_bspline import RationalBSplineSurface, on_uniform_knots
from bhem_hpc.io import SurfaceTimeSeries, read_frame
from bhem_hpc.io.render import TrimmedSurface, camera_rays, render
from bhem_hpc.model.material import Material

pytestmark = pytest.mark.rank_free  # no communicator: the same computation on every rank


def _tessellation_coverage(surface, eye, directions, density=24):
    """Which rays hit a fine triangle tessellation (Moller-Trumbore, vectorized over triangles)."""
    points, quads, _ = surface.tessellate(density)
    triangles = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    p0, p1, p2 = points[triangles[:, 0]], points[triangles[:, 1]], points[triangles[:, 2]]
    covered = np.array([np.isfinite(ray_triangle_distances(eye, d, p0, p1, p2)).any() for d in directions])
    return covered


def test_render_matches_rasterized_tessellation(tmp_path):
    rest = S.cylinder(0.5, 1.0, 2, 6, closed=False, angle=np.pi)
    bumped = S.HermiteSurface(rest.grid, rest.nodal.copy())
    bumped.nodal[1, 3, 0] += [0.1, 0.1, 0.0]
    series = SurfaceTimeSeries(tmp_path / "s.xdmf", rest, Material(1e4, 0.3, 1e-3, 200.0), 2)
    series.write(0.25, bumped)
    series.close()
    frame, time = read_frame(tmp_path / "s.h5")
    assert time == 0.25
    np.testing.assert_array_equal(frame.nodal, bumped.nodal)
    width, height = 48, 36
    image, mask = render(frame, width, height)
    eye, directions = camera_rays(frame, width, height)
    reference = _tessellation_coverage(frame, eye, directions).reshape(height, width)
    assert 0.15 < mask.mean() < 0.9  # the surface fills a good part of the picture
    mismatch = np.mean(mask != reference)
    assert mismatch < 0.01, mismatch  # only silhouette pixels may differ
    assert np.all(image[~mask] == 1.0) and np.all(image[mask].max(axis=-1) < 1.0)


def test_ray_benchmark_reports_both_strategies_with_the_same_hits():
    row = ray_benchmark(patches=3, resolution=6)
    assert row["rays"] == 36 and row["hits"] > 20
    assert row["midpoint_rays_per_s"] > 0 and row["newton_rays_per_s"] > 0
    assert row["max_tau_difference"] < 1e-9


def test_rational_shells_render_as_their_tessellation_and_their_trims_cut_them():
    """A rational cubic panel (a perturbed exact cylinder) is traced on its rational Bezier spans:
    the picture covers what its fine tessellation covers but for silhouette pixels; trimmed by an
    elliptic hole, it loses the pixels behind the hole (254 of 350 left)."""
    panel = on_uniform_knots(cylinder_panel(0.5, (0.0, 1.0), (0.3, 2.8)), (3, 4), 3)
    control = panel.control.copy()
    control[2, 3] += [0.05, 0.05, 0.1]
    shell = RationalBSplineSurface(panel.grid, 3, control, panel.weights)
    width, height = 48, 36
    image, mask = render(shell, width, height)
    eye, directions = camera_rays(shell, width, height)
    reference = _tessellation_coverage(shell, eye, directions).reshape(height, width)
    assert 0.15 < mask.mean() < 0.9 and np.mean(mask != reference) < 0.01
    angle = np.linspace(0.0, 2 * np.pi, 49)
    hole = np.stack([0.5 + 0.25 * np.cos(angle), 0.5 + 0.3 * np.sin(angle)], 1)[::-1]
    outer = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [0.0, 0.0]])
    _, whole = render(TrimmedSurface(shell, (outer,)), width, height)  # framed as the trimmed one
    _, trimmed = render(TrimmedSurface(shell, (outer, hole)), width, height)
    # the picture frames the kept region, so a few silhouette pixels may move (measured: 2 of 1728)
    assert np.mean(trimmed & ~whole) < 0.005 and 0.5 * whole.sum() < trimmed.sum() < 0.9 * whole.sum()

"""The patch ray tracer against a rasterized fine tessellation; the ray benchmark's numbers."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import ray_triangle_distances

from bhem_hpc.benchmarks.timing import ray_benchmark
from bhem_hpc.geometry import surface as S
from bhem_hpc.io import SurfaceTimeSeries, read_frame
from bhem_hpc.io.render import camera_rays, render
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

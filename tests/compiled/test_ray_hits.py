"""The compiled first hits of rays against the numpy search they compile."""

from __future__ import annotations

import numpy as np
import pytest

from bhem_hpc.compiled import ray_hits as compiled
from bhem_hpc.geometry import nurbs
from bhem_hpc.geometry import rational_bezier as rb
from bhem_hpc.studies import sem_models


def _random_rays(rng, parts, count: int):
    """Rays from points in the parts' box in random directions, every third searched only 0.3 of
    the box's diagonal far: origins, unit directions ``(count, 3)``, stretches ``(count,)``."""
    control = np.concatenate([p.control.reshape(-1, 3) for p in parts])
    lo, hi = control.min(axis=0), control.max(axis=0)
    origins = lo + rng.random((count, 3)) * (hi - lo)
    directions = rng.standard_normal((count, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    tau_max = np.full(count, np.inf)
    tau_max[::3] = 0.3 * np.linalg.norm(hi - lo)
    return origins, directions, np.zeros(count), tau_max


@pytest.mark.parametrize("model", ["sphere", "torus", "rocket", "castle"])
def test_compiled_first_hits_equal_the_numpy_search(rng, model):
    parts = {"sphere": lambda: [nurbs.sphere(1.0)], "torus": lambda: [nurbs.torus(1.0, 0.3)],
             "rocket": sem_models.rocket, "castle": sem_models.castle}[model]()  # fmt: skip
    origins, directions, tau_min, tau_max = _random_rays(rng, parts, 800)
    for nets, _ in nurbs.bezier_nets_by_degree(parts):
        expected = rb.first_hits(nets, origins, directions, tau_min, tau_max)
        found = compiled.first_hits(nets, origins, directions, tau_min, tau_max)
        assert np.isfinite(expected.tau).sum() > 50
        np.testing.assert_array_equal(np.isfinite(found.tau), np.isfinite(expected.tau))
        hit = np.isfinite(found.tau)
        np.testing.assert_allclose(found.tau[hit], expected.tau[hit], atol=1e-9)
        # the hit lies on its patch, on its ray
        point = rb.evaluate(nets[found.patch[hit]], found.s[hit], found.t[hit])[0]
        np.testing.assert_allclose(point, origins[hit] + found.tau[hit, None] * directions[hit], atol=1e-9)


@pytest.mark.parametrize("model", ["torus", "rocket", "mug"])
def test_kept_pieces_give_the_hits_of_the_splitting_search(rng, model):
    """The curved patches' pieces kept for all rays (bounding spheres, divided control points) and
    the pieces each ray splits itself: the same hits, bit for bit."""
    parts = {"torus": lambda: [nurbs.torus(1.0, 0.3)], "rocket": sem_models.rocket, "mug": sem_models.mug}[model]()
    origins, directions, tau_min, tau_max = _random_rays(rng, parts, 2000)
    for nets, _ in nurbs.bezier_nets_by_degree(parts):
        kept = compiled.first_hits(nets, origins, directions, tau_min, tau_max)
        split = compiled.first_hits(nets, origins, directions, tau_min, tau_max, tree_bytes=0.0)
        assert np.isfinite(kept.tau).sum() > 100
        for key in ("tau", "patch", "s", "t"):
            np.testing.assert_array_equal(getattr(kept, key), getattr(split, key))


def test_compiled_first_hits_respect_the_stretch():
    """A ray through the unit sphere's centre from outside: the near side's hit, the far side's
    once the stretch starts past the near one, none once it ends before it."""
    nets = nurbs.sphere(1.0).bezier_patches.nets
    origins, directions = np.array([[-3.0, 0.1, 0.2]] * 3), np.array([[1.0, 0.0, 0.0]] * 3)
    hits = compiled.first_hits(nets, origins, directions, np.array([0.0, 3.0, 0.0]), np.array([np.inf, np.inf, 1.5]))
    depth = np.sqrt(1.0 - 0.1**2 - 0.2**2)
    np.testing.assert_allclose(hits.tau[:2], [3.0 - depth, 3.0 + depth], atol=1e-10)
    assert hits.tau[2] == np.inf and hits.patch[2] == -1


def _can(radius: float, height: float) -> nurbs.NurbsSurface:
    """A closed can of revolution about z: bottom disc, wall, top disc (ruled, degree (2, 1))."""
    profile = np.array([(0.0, 0.0), (radius, 0.0), (radius, height), (0.0, height)])
    return nurbs.revolve(profile, np.ones(4), np.array([0.0, 0.0, 1 / 3, 2 / 3, 1.0, 1.0]), 1, "can")


def test_rays_meet_a_ruled_can_exactly_and_a_tangent_ray_meets_nothing(rng):
    """Rays from the can's axis outward meet the wall at the radius to round-off (the search to
    a tolerance, 1e-10 of the size); a ray leaving the wall along its tangent meets nothing beyond
    its start, and a ray up the axis meets the top at the apex of its patches."""
    radius, height = 0.3, 0.4
    nets = _can(radius, height).bezier_patches.nets
    count = 200
    angles, heights = rng.uniform(0, 2 * np.pi, count), rng.uniform(0.05, 0.35, count)
    slopes = rng.uniform(-0.1, 0.1, count)
    directions = np.stack([np.cos(angles), np.sin(angles), slopes], axis=1)
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    origins = np.stack([np.zeros(count), np.zeros(count), heights], axis=1)
    hits = compiled.first_hits(nets, origins, directions, np.zeros(count), np.full(count, np.inf))
    horizontal = np.linalg.norm(directions[:, :2], axis=1)
    np.testing.assert_allclose(hits.tau, radius / horizontal, rtol=1e-13)
    foot = np.array([[radius, 0.0, 0.2]])
    tangent = compiled.first_hits(nets, foot, np.array([[0.0, 1.0, 0.0]]), np.array([1e-7]), np.array([np.inf]))
    assert tangent.tau[0] == np.inf
    up = compiled.first_hits(nets, np.array([[0.0, 0.0, 0.1]]), np.array([[0.0, 0.0, 1.0]]), np.zeros(1),
                             np.full(1, np.inf))  # fmt: skip
    np.testing.assert_allclose(up.tau, [height - 0.1], rtol=1e-14)

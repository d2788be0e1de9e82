"""The bounding volume hierarchy's candidates against testing every box."""

from __future__ import annotations

import numpy as np

from bhem_hpc.compiled import bvh


def test_candidates_are_the_boxes_the_stretch_meets_nearest_first(rng):
    low = rng.uniform(-1.0, 1.0, (300, 3))
    high = low + rng.uniform(0.0, 0.3, (300, 3))
    high[:20, 2] = low[:20, 2]  # flat boxes, as a face's along an axis
    hierarchy = bvh.build(low, high)
    found, entries, stack = np.empty(300, dtype=np.int64), np.empty(300), np.empty(len(hierarchy[0]), dtype=np.int64)
    for _ in range(200):
        origin = rng.uniform(-1.5, 1.5, 3)
        direction = rng.standard_normal(3)
        direction[rng.integers(3)] = 0.0 if rng.random() < 0.3 else direction[0]  # rays parallel to slabs too
        direction /= np.linalg.norm(direction)
        tau_max = rng.uniform(0.1, 3.0)
        count = bvh.candidates(hierarchy, low, high, origin, direction, 0.0, tau_max, found, entries, stack)
        # every box by the slab test directly, with the points of the stretch sampled finely
        tau = np.linspace(0.0, tau_max, 4001)
        points = origin + tau[:, None] * direction
        inside = np.all((points[:, None] >= low - 1e-12) & (points[:, None] <= high + 1e-12), axis=2)
        sampled = set(np.flatnonzero(inside.any(axis=0)))
        assert sampled <= set(found[:count])
        assert np.all(np.diff(entries[:count]) >= 0.0)
        for box, entry in zip(found[:count], entries[:count], strict=True):
            at = origin + entry * direction
            assert np.all(at >= low[box] - 1e-9) and np.all(at <= high[box] + 1e-9)

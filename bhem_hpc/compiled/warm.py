"""Compile (or load from numba's cache) every compiled function by running it once on small inputs."""

from __future__ import annotations

import time

import numpy as np


def load_all() -> float:
    """Run the extraction, the line search, the volume rule, the closest points, the first hits and
    the count of nonzero weights once; the seconds
    it took (a minute and a half compiling, a third of a second loading the cache)."""
    from bhem_hpc.geometry import nurbs  # the solids import this package: imported here, when called
    from bhem_hpc.solids.blending import ray_distances
    from bhem_hpc.solids.quadrature import ray_cast_quadrature

    clock = time.perf_counter()
    # a can: a ruled surface of revolution (its line crossings and ray hits are solved exactly)
    can = nurbs.revolve(np.array([(0.0, 0.0), (0.3, 0.0), (0.3, 0.4), (0.0, 0.4)]), np.ones(4),
                        np.array([0.0, 0.0, 1 / 3, 2 / 3, 1.0, 1.0]), 1, "can")  # fmt: skip
    parts = [nurbs.torus(1.0, 0.3), *nurbs.box_faces([-0.2, -0.2, -0.2], [0.2, 0.2, 0.2]), can]
    for part in (parts[0], can):
        quadrature = ray_cast_quadrature([part], 8)
    ray_distances(parts, quadrature.points[:20], 1.0).cutoff_for(0.5)
    return time.perf_counter() - clock

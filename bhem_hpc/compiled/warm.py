"""Compile (or load from numba's cache) every compiled function by running it once on small inputs."""

from __future__ import annotations

import time


def load_all() -> float:
    """Run the extraction, the line search, the volume rule, the closest points, the first hits and
    the count of nonzero weights once; the seconds
    it took (a minute and a half compiling, a third of a second loading the cache)."""
    from bhem_hpc.geometry import nurbs  # the solids import this package: imported here, when called
    from bhem_hpc.solids.blending import ray_distances
    from bhem_hpc.solids.quadrature import ray_cast_quadrature

    clock = time.perf_counter()
    parts = [nurbs.torus(1.0, 0.3), *nurbs.box_faces([-0.2, -0.2, -0.2], [0.2, 0.2, 0.2])]
    quadrature = ray_cast_quadrature(parts[:1], 8)
    ray_distances(parts, quadrature.points[:20], 1.0).cutoff_for(0.5)
    return time.perf_counter() - clock

"""``python -m bhem_hpc.compiled``: compile every compiled function once and cache it (``make setup``
runs it, so that the test processes load them instead of each compiling them for a minute)."""

from __future__ import annotations

import time

from bhem_hpc.geometry import nurbs
from bhem_hpc.solids.blending import ray_distances
from bhem_hpc.solids.quadrature import ray_cast_quadrature


def main() -> None:
    clock = time.perf_counter()
    parts = [nurbs.torus(1.0, 0.3), *nurbs.box_faces([-0.2, -0.2, -0.2], [0.2, 0.2, 0.2])]
    quadrature = ray_cast_quadrature(parts[:1], 8)
    ray_distances(parts, quadrature.points[:20], 1.0)
    print(f"bhem_hpc.compiled: compiled and cached in {time.perf_counter() - clock:.0f} s", flush=True)


if __name__ == "__main__":
    main()

"""Regenerate the shipped geometry files (all made by this project). Run: .venv/bin/python meshes/make_meshes.py

- hemisphere_zone_8x24.npz, cylinder_12x24.npz: Hermite nodal data files (README: "Nodal data files").
- bumpy_dome.obj: a closed triangle mesh (a squashed, bumpy sphere) for triangle-mesh obstacles.
- torus_patches.npz: a torus as 12 x 8 bicubic Bezier patches, a parametric obstacle (PatchModel).
"""

from pathlib import Path

import meshio
import numpy as np

from bhem_hpc.collision import PatchModel, control_nets
from bhem_hpc.geometry import surface as S

here = Path(__file__).resolve().parent
S.sphere_zone(0.5, 0.15, np.pi / 2, 8, 24).save(here / "hemisphere_zone_8x24.npz")
S.cylinder(0.5, 1.0, 12, 24).save(here / "cylinder_12x24.npz")

# Bumpy dome: UV sphere with poles, radius modulated, flattened in z.
rings, segments = 16, 32
theta = np.linspace(0, np.pi, rings + 1)[1:-1]
phi = np.linspace(0, 2 * np.pi, segments, endpoint=False)
t, p = np.meshgrid(theta, phi, indexing="ij")
r = 0.3 * (1 + 0.08 * np.sin(3 * p) * np.sin(2 * t))
ring_points = np.stack([r * np.sin(t) * np.cos(p), r * np.sin(t) * np.sin(p), 0.6 * r * np.cos(t)], -1).reshape(-1, 3)
points = np.vstack([[0, 0, 0.18], ring_points, [0, 0, -0.18]])
triangles = []
for j in range(segments):
    k = (j + 1) % segments
    triangles.append([0, 1 + j, 1 + k])
    last = 1 + (rings - 2) * segments
    triangles.append([len(points) - 1, last + k, last + j])
for i in range(rings - 2):
    for j in range(segments):
        k = (j + 1) % segments
        a, b = 1 + i * segments + j, 1 + i * segments + k
        c, d = a + segments, b + segments
        triangles += [[a, c, b], [b, c, d]]
meshio.write(here / "bumpy_dome.obj", meshio.Mesh(points, [("triangle", np.array(triangles))]))

torus = S.torus(0.4, 0.12, 12, 8)
PatchModel(control_nets(torus.grid, torus.nodal)).save(here / "torus_patches.npz")

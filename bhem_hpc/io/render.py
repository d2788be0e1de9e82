"""Ray-traced pictures of bicubic patches (paper §6.3): exact intersections, exact normals.

Every pixel's ray is intersected with the surface's Bezier patches (:mod:`bhem_hpc.collision`),
no tessellation; shading uses the patch normal at the hit. numpy + matplotlib only.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bhem_hpc.collision import PatchBVH, trace_rays
from bhem_hpc.collision.bezier import evaluate_many
from bhem_hpc.geometry.surface import HermiteSurface

LIGHT = np.array([0.4, -0.6, 0.7]) / np.linalg.norm([0.4, -0.6, 0.7])
VIEW = np.array([1.0, -1.6, 1.1])


def camera_rays(surface: HermiteSurface, width: int, height: int, fov_degrees: float = 35.0):
    """Pinhole camera looking at the surface's bounding box from ``VIEW``.

    Returns:
        ``(origin (3,), directions (height * width, 3))``, rows top to bottom.
    """
    points = surface.nodal[..., 0, :].reshape(-1, 3)
    centre = 0.5 * (points.min(axis=0) + points.max(axis=0))
    radius = 0.5 * float(np.linalg.norm(points.max(axis=0) - points.min(axis=0))) or 1.0
    forward = -VIEW / np.linalg.norm(VIEW)
    eye = centre - forward * radius / np.tan(np.radians(fov_degrees) / 2) * 1.15
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    half = np.tan(np.radians(fov_degrees) / 2)
    xs = (np.arange(width) + 0.5) / width * 2 - 1
    ys = 1 - (np.arange(height) + 0.5) / height * 2
    gx, gy = np.meshgrid(xs * half * width / height, ys * half)
    directions = forward + gx[..., None] * right + gy[..., None] * up
    return eye, directions.reshape(-1, 3)


def render(surface: HermiteSurface, width: int = 160, height: int = 120) -> tuple[np.ndarray, np.ndarray]:
    """Shaded image ``(height, width, 3)`` in [0, 1] and the coverage mask ``(height, width)``."""
    nets = surface.bezier_nets()
    eye, directions = camera_rays(surface, width, height)
    hits = trace_rays(PatchBVH(nets), np.broadcast_to(eye, directions.shape), directions)
    mask = hits.patch >= 0
    hit_nets, u, v = nets[hits.patch[mask]], hits.u[mask], hits.v[mask]
    normal = np.cross(evaluate_many(hit_nets, u, v, du=1), evaluate_many(hit_nets, u, v, dv=1))
    normal /= np.maximum(np.linalg.norm(normal, axis=1), 1e-300)[:, None]
    diffuse = np.abs(normal @ LIGHT)[:, None]  # two-sided: shells have no inside
    image = np.ones((len(directions), 3))
    base = np.array([0.25, 0.45, 0.8])
    image[mask] = np.clip(base * (0.25 + 0.75 * diffuse) + 0.15 * diffuse**20, 0.0, 1.0)
    return image.reshape(height, width, 3), mask.reshape(height, width)


def write_png(path: str | Path, image: np.ndarray) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.imsave(path, np.clip(image, 0.0, 1.0))
    return Path(path)

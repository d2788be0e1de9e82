"""Ray-traced pictures of bicubic patches (paper §6.3): exact intersections, exact normals.

Every pixel's ray is intersected with the surface's Bezier patches (:mod:`bhem_hpc.collision`),
no tessellation; shading uses the patch normal at the hit. numpy + matplotlib only.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from bhem_hpc.collision import PatchBVH, trace_rays
from bhem_hpc.collision.bezier import evaluate_many
from bhem_hpc.geometry.surface import HermiteSurface

LIGHT = np.array([0.4, -0.6, 0.7]) / np.linalg.norm([0.4, -0.6, 0.7])
VIEW = np.array([1.0, -1.6, 1.1])


#: Base colours of the bodies of a picture, in turn (one body: the first).
BODY_COLOURS = np.array([[0.25, 0.45, 0.8], [0.85, 0.45, 0.2], [0.3, 0.65, 0.35], [0.7, 0.3, 0.6], [0.8, 0.7, 0.2]])


def camera_rays(surface: HermiteSurface | Sequence[HermiteSurface], width: int, height: int,
                fov_degrees: float = 35.0):  # fmt: skip
    """Pinhole camera looking at the bounding box of the surface (or surfaces) from ``VIEW``.

    Returns:
        ``(origin (3,), directions (height * width, 3))``, rows top to bottom.
    """
    surfaces = list(surface) if isinstance(surface, Sequence) else [surface]
    points = np.concatenate([s.nodal[..., 0, :].reshape(-1, 3) for s in surfaces])
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


def render(surface: HermiteSurface | Sequence[HermiteSurface], width: int = 160, height: int = 120
           ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Shaded image ``(height, width, 3)`` in [0, 1] and the coverage mask ``(height, width)`` of a
    surface, or of several (bodies, each in its colour of :data:`BODY_COLOURS`)."""
    surfaces = list(surface) if isinstance(surface, Sequence) else [surface]
    parts = [s.bezier_nets() for s in surfaces]
    nets = np.concatenate(parts)
    body = np.repeat(np.arange(len(parts)), [len(p) for p in parts])  # the body of each patch
    eye, directions = camera_rays(surfaces, width, height)
    hits = trace_rays(PatchBVH(nets), np.broadcast_to(eye, directions.shape), directions)
    mask = hits.patch >= 0
    hit_nets, u, v = nets[hits.patch[mask]], hits.u[mask], hits.v[mask]
    normal = np.cross(evaluate_many(hit_nets, u, v, du=1), evaluate_many(hit_nets, u, v, dv=1))
    normal /= np.maximum(np.linalg.norm(normal, axis=1), 1e-300)[:, None]
    diffuse = np.abs(normal @ LIGHT)[:, None]  # two-sided: shells have no inside
    image = np.ones((len(directions), 3))
    base = BODY_COLOURS[body[hits.patch[mask]] % len(BODY_COLOURS)]
    image[mask] = np.clip(base * (0.25 + 0.75 * diffuse) + 0.15 * diffuse**20, 0.0, 1.0)
    return image.reshape(height, width, 3), mask.reshape(height, width)


def write_png(path: str | Path, image: np.ndarray) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.imsave(path, np.clip(image, 0.0, 1.0))
    return Path(path)

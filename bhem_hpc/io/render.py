"""Ray-traced pictures of bicubic patches (paper §6.3) and of NURBS parts: exact intersections,
exact normals.

Every pixel's ray is intersected with a shell's Bezier patches (:mod:`bhem_hpc.collision`) or a
solid's rational Bezier patches (:func:`bhem_hpc.geometry.rational_bezier.first_hits`), no
tessellation; the nearest hit of all bodies is shaded with its patch normal. A trimmed shell
(:class:`TrimmedSurface`) lets its rays pass where the trim cuts the patch away: each such ray is
traced again from just beyond that hit, at most :data:`MAX_TRIM_PASSES` times. numpy + matplotlib only.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, Union, runtime_checkable

import numpy as np

from bhem_hpc.collision import PatchBVH, trace_rays
from bhem_hpc.collision.bezier import evaluate_many
from bhem_hpc.geometry import rational_bezier
from bhem_hpc.geometry.nurbs import NurbsSurface, bezier_nets_by_degree
from bhem_hpc.geometry.rational_bspline import RationalBSplineSurface
from bhem_hpc.geometry.surface import HermiteSurface
from bhem_hpc.geometry.trim import inside

LIGHT = np.array([0.4, -0.6, 0.7]) / np.linalg.norm([0.4, -0.6, 0.7])
VIEW = np.array([1.0, -1.6, 1.1])


@runtime_checkable
class NurbsParts(Protocol):
    """A body drawn by its NURBS parts (a solid's frame, :class:`~bhem_hpc.solids.model.SolidFrame`)."""

    parts: list[NurbsSurface]


@dataclass(frozen=True)
class TrimmedSurface:
    """A shell's surface drawn only where its trim loops keep it (:mod:`bhem_hpc.geometry.trim`).

    Attributes:
        surface: the whole surface (Hermite or B-spline).
        loops: closed polygons ``(n_k, 2)`` in the surface's parameters; the region inside an odd
            number of them is drawn.
    """

    surface: HermiteSurface
    loops: tuple[np.ndarray, ...]


#: A body of a picture: a shell's surface (Hermite or B-spline), a trimmed one, or a solid's parts.
Drawable = Union[HermiteSurface, TrimmedSurface, NurbsParts]  # noqa: UP007 (a runtime alias of a Protocol)
#: Times a ray of a trimmed shell is traced again beyond a hit the trim cuts away.
MAX_TRIM_PASSES = 8
#: How far beyond such a hit [relative to its distance] the ray starts again.
TRIM_PASS_OFFSET = 1e-9
#: Samples per parameter direction that frame a trimmed shell's picture (with its loops).
FRAMING_SAMPLES = 33


def _corner_points(body: Drawable) -> np.ndarray:
    """``(n, 3)`` points whose bounding box holds the body (nodes or control points)."""
    if isinstance(body, NurbsParts):
        return np.concatenate([part.control.reshape(-1, 3) for part in body.parts])
    if isinstance(body, TrimmedSurface):  # the kept region's points: its loops and a lattice inside
        grid = body.surface.grid
        along1, along2 = np.linspace(*grid.xi1_range, FRAMING_SAMPLES), np.linspace(*grid.xi2_range, FRAMING_SAMPLES)
        lattice = np.stack(np.meshgrid(along1, along2, indexing="ij"), axis=-1).reshape(-1, 2)
        xi = np.concatenate([*body.loops, lattice[inside(body.loops, lattice)]])
        lo, hi = np.array([grid.xi1_range[0], grid.xi2_range[0]]), np.array([grid.xi1_range[1], grid.xi2_range[1]])
        xi = np.clip(xi, lo, hi)
        return body.surface.evaluate(xi[:, 0], xi[:, 1]).x.reshape(-1, 3)
    return body.nodal[..., 0, :].reshape(-1, 3)


def _span_tracer(surface: HermiteSurface):
    """``trace(origins, directions) -> (span, u, v, tau, normal)``: each ray's first hit on the
    shell's spans (span -1: none), its local coordinates, its distance in units of the ray's
    direction and the (unnormalized) normal there. Polynomial shells: their bicubic nets in a BVH;
    rational ones: their rational Bezier patches, intersected exactly."""
    if isinstance(surface, RationalBSplineSurface):
        grid, width = surface.grid, surface.degree + 1
        nets = surface.homogeneous_nets().reshape(grid.n1 * grid.n2, width, width, 4)

        def trace_rational(origins: np.ndarray, directions: np.ndarray):
            length = np.linalg.norm(directions, axis=1)
            hits = rational_bezier.first_hits(nets, origins, directions / length[:, None], np.zeros(len(length)),
                                              np.full(len(length), np.inf))  # fmt: skip
            normal, hit = np.zeros((len(length), 3)), hits.patch >= 0
            _, x_s, x_t = rational_bezier.evaluate(nets[hits.patch[hit]], hits.s[hit], hits.t[hit])
            normal[hit] = np.cross(x_s, x_t)
            return hits.patch, hits.s, hits.t, np.where(hit, hits.tau / length, np.inf), normal

        return trace_rational
    nets = surface.bezier_nets()
    bvh = PatchBVH(nets)

    def trace_polynomial(origins: np.ndarray, directions: np.ndarray):
        hits = trace_rays(bvh, origins, directions)
        normal, hit = np.zeros((len(directions), 3)), hits.patch >= 0
        hit_nets, u, v = nets[hits.patch[hit]], hits.u[hit], hits.v[hit]
        normal[hit] = np.cross(evaluate_many(hit_nets, u, v, du=1), evaluate_many(hit_nets, u, v, dv=1))
        return hits.patch, hits.u, hits.v, hits.tau, normal

    return trace_polynomial


def _trace_shell(body: HermiteSurface | TrimmedSurface, eye: np.ndarray, directions: np.ndarray):
    """:func:`_trace` of a shell's spans; a trimmed shell's rays pass its trimmed-away hits."""
    surface, loops = (body.surface, body.loops) if isinstance(body, TrimmedSurface) else (body, None)
    tau, normal = np.full(len(directions), np.inf), np.zeros((len(directions), 3))
    grid, trace = surface.grid, _span_tracer(surface)
    origins = np.array(np.broadcast_to(eye, directions.shape), dtype=float)
    travelled = np.zeros(len(directions))  # along each ray's direction, to where it starts again
    pending = np.arange(len(directions))
    for _ in range(MAX_TRIM_PASSES if loops is not None else 1):
        span, u, v, hit_tau, hit_normal = trace(origins[pending], directions[pending])
        hit = span >= 0
        kept = hit.copy()
        if loops is not None and np.any(hit):
            p1, p2 = np.divmod(span[hit], grid.n2)
            xi = np.column_stack([grid.xi1_range[0] + (p1 + u[hit]) * grid.h1,
                                  grid.xi2_range[0] + (p2 + v[hit]) * grid.h2])  # fmt: skip
            kept[hit] = inside(loops, xi)
        rays = pending[kept]
        tau[rays] = (travelled[rays] + hit_tau[kept]) * np.linalg.norm(directions[rays], axis=1)
        normal[rays] = hit_normal[kept]
        passing = hit & ~kept
        pending, step = pending[passing], hit_tau[passing] * (1.0 + TRIM_PASS_OFFSET) + TRIM_PASS_OFFSET
        origins[pending] += step[:, None] * directions[pending]
        travelled[pending] += step
        if not len(pending):
            break
    return tau, normal


def _trace(body: Drawable, eye: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each ray's distance to its first hit on the body ``(R,)`` (inf: none) and the unit normal there ``(R, 3)``."""
    tau, normal = np.full(len(directions), np.inf), np.zeros((len(directions), 3))
    if not isinstance(body, NurbsParts):  # a shell's surface (Hermite or B-spline): bicubic nets
        tau, normal = _trace_shell(body, eye, directions)
    else:
        unit = directions / np.linalg.norm(directions, axis=1)[:, None]
        origins = np.broadcast_to(eye, directions.shape)
        for nets, _ in bezier_nets_by_degree(body.parts):  # one search per degree: nets of one shape
            hits = rational_bezier.first_hits(nets, origins, unit, np.zeros(len(unit)), np.full(len(unit), np.inf))
            nearer = (hits.patch >= 0) & (hits.tau < tau)
            _, x_s, x_t = rational_bezier.evaluate(nets[hits.patch[nearer]], hits.s[nearer], hits.t[nearer])
            tau[nearer], normal[nearer] = hits.tau[nearer], np.cross(x_s, x_t)
    normal /= np.maximum(np.linalg.norm(normal, axis=1), 1e-300)[:, None]
    return tau, normal


#: Base colours of the bodies of a picture, in turn (one body: the first).
BODY_COLOURS = np.array([[0.25, 0.45, 0.8], [0.85, 0.45, 0.2], [0.3, 0.65, 0.35], [0.7, 0.3, 0.6], [0.8, 0.7, 0.2]])


def camera_rays(surface: Drawable | Sequence[Drawable], width: int, height: int, fov_degrees: float = 35.0):
    """Pinhole camera looking at the bounding box of the surface (or bodies) from ``VIEW``.

    Returns:
        ``(origin (3,), directions (height * width, 3))``, rows top to bottom.
    """
    surfaces = list(surface) if isinstance(surface, Sequence) else [surface]
    points = np.concatenate([_corner_points(s) for s in surfaces])
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


def render(surface: Drawable | Sequence[Drawable], width: int = 160, height: int = 120
           ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Shaded image ``(height, width, 3)`` in [0, 1] and the coverage mask ``(height, width)`` of a
    surface, or of several bodies (shells' surfaces, solids' parts), each in its colour of
    :data:`BODY_COLOURS`."""
    surfaces = list(surface) if isinstance(surface, Sequence) else [surface]
    eye, directions = camera_rays(surfaces, width, height)
    nearest, normal = np.full(len(directions), np.inf), np.zeros((len(directions), 3))
    body = np.full(len(directions), -1)
    for k, item in enumerate(surfaces):
        tau, item_normal = _trace(item, eye, directions)
        nearer = tau < nearest
        nearest[nearer], normal[nearer], body[nearer] = tau[nearer], item_normal[nearer], k
    mask = body >= 0
    diffuse = np.abs(normal[mask] @ LIGHT)[:, None]  # two-sided: shells have no inside
    image = np.ones((len(directions), 3))
    base = BODY_COLOURS[body[mask] % len(BODY_COLOURS)]
    image[mask] = np.clip(base * (0.25 + 0.75 * diffuse) + 0.15 * diffuse**20, 0.0, 1.0)
    return image.reshape(height, width, 3), mask.reshape(height, width)


def write_png(path: str | Path, image: np.ndarray) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.imsave(path, np.clip(image, 0.0, 1.0))
    return Path(path)

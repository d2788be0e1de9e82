"""Triangle meshes on colliders that have none of their own: a cylinder over the part of its axis
the bodies can reach, and a Bezier patch model on a grid fine enough for a given chord error.
Barrier contact (ipc-toolkit) meets colliders as triangle meshes. numpy only.
"""

from __future__ import annotations

import math

import numpy as np

from bhem_hpc.collision.bezier import evaluate
from bhem_hpc.errors import UserError

#: Vertices around a cylinder's rings its triangles may take.
MAX_CYLINDER_AROUND = 1024
#: Rings along a cylinder's band its triangles may take.
MAX_CYLINDER_RINGS = 1024
#: A cylinder's band triangles are at most this many times longer (along the axis) than wide, so
#: that their bounding boxes (ipc-toolkit's broad phase) stay close to them.
BAND_ASPECT = 4.0
#: Grid cells per side a patch of a patch model may take.
MAX_PATCH_CELLS = 256
#: Vertices of a patch model's patches closer than this fraction of the model's size are one vertex
#: (adjacent patches evaluate their common edge at the same parameters).
WELD_TOLERANCE = 1e-10


class TessellationError(UserError, ValueError):
    """A collider cannot be meshed within the asked chord error and the mesh size limits
    (``collider``: its index in the list the barrier was given, where known)."""

    def __init__(self, message: str, collider: int | None = None):
        super().__init__(message)
        self.collider = collider


def ring_count(radius: float, max_sagitta: float) -> int:
    """The fewest vertices (at least 6) around a circle of ``radius`` whose chords lie at most
    ``max_sagitta`` inside it."""
    return max(6, math.ceil(math.pi / math.acos(1.0 - min(max_sagitta / radius, 1.0))))


def cylinder_mesh(point: np.ndarray, axis: np.ndarray, radius: float, max_sagitta: float,
                  cover: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """A closed triangle mesh on the infinite cylinder of ``radius`` about the line through ``point``
    along the unit ``axis``, capped where the box ``cover (2, 3)`` (min and max corners) projected on
    the axis ends, extended by the box's diagonal at either end (bodies move; the analytic cylinder
    has no end). The band's faces lie at most ``max_sagitta`` inside the cylinder; the caps are flat.

    Returns ``(vertices (V, 3), triangles (T, 3))``, outward (counter-clockwise seen from outside):
    ``rings`` rings of ``around`` vertices from the low end up, then the two cap centres.
    """
    point, w = np.asarray(point, dtype=float), np.asarray(axis, dtype=float)
    cover = np.asarray(cover, dtype=float)
    corners = np.array([[cover[i, 0], cover[j, 1], cover[k, 2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    along = (corners - point) @ w
    margin = float(np.linalg.norm(cover[1] - cover[0]))
    low, high = along.min() - margin, along.max() + margin
    if high - low <= 0.0:
        high, low = low + radius, low - radius  # a point-sized cover: a short cylinder about it
    around = ring_count(radius, max_sagitta)
    if around > MAX_CYLINDER_AROUND:
        raise TessellationError(f"a cylinder of radius {radius:g} needs more than {MAX_CYLINDER_AROUND} vertices "
                                f"around to lie within {max_sagitta:g} of its triangles")  # fmt: skip
    chord = 2.0 * radius * math.sin(math.pi / around)
    rings = min(MAX_CYLINDER_RINGS, max(2, math.ceil((high - low) / (BAND_ASPECT * chord)) + 1))
    u = np.cross(w, [1.0, 0.0, 0.0] if abs(w[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(w, u)
    theta = 2.0 * np.pi * np.arange(around) / around
    radial = radius * (np.cos(theta)[:, None] * u + np.sin(theta)[:, None] * v)  # (around, 3)
    levels = np.linspace(low, high, rings)
    vertices = np.concatenate([(point + s * w + radial) for s in levels] + [[point + low * w, point + high * w]])
    nxt = (np.arange(around) + 1) % around
    faces = []
    for k in range(rings - 1):
        bottom, top = k * around, (k + 1) * around
        faces += [np.stack([bottom + np.arange(around), bottom + nxt, top + nxt], axis=1),
                  np.stack([bottom + np.arange(around), top + nxt, top + np.arange(around)], axis=1)]  # fmt: skip
    south, north, last = rings * around, rings * around + 1, (rings - 1) * around
    faces += [np.stack([np.full(around, south), nxt, np.arange(around)], axis=1),
              np.stack([last + np.arange(around), last + nxt, np.full(around, north)], axis=1)]  # fmt: skip
    return vertices, np.concatenate(faces).astype(np.int64)


def bezier_second_derivative_bound(nets: np.ndarray) -> np.ndarray:
    """For bicubic Bezier ``nets (P, 4, 4, 3)``, a bound ``(P,)`` on ``|d^2 x / ds^2|`` along any unit
    direction ``s`` of the parameter square: ``|x_uu| + 2 |x_uv| + |x_vv|``, each bounded by its
    control net's differences (``x_uu = 6 sum D_u^2 b B B``, ``x_uv = 9 sum D_u D_v b B B``)."""
    d_uu = np.linalg.norm(nets[:, 2:] - 2 * nets[:, 1:-1] + nets[:, :-2], axis=-1).max(axis=(1, 2))
    d_vv = np.linalg.norm(nets[:, :, 2:] - 2 * nets[:, :, 1:-1] + nets[:, :, :-2], axis=-1).max(axis=(1, 2))
    d_uv = np.linalg.norm(nets[:, 1:, 1:] - nets[:, 1:, :-1] - nets[:, :-1, 1:] + nets[:, :-1, :-1],
                          axis=-1).max(axis=(1, 2))  # fmt: skip
    return 6.0 * d_uu + 18.0 * d_uv + 6.0 * d_vv


def patch_model_mesh(nets: np.ndarray, max_sagitta: float) -> tuple[np.ndarray, np.ndarray]:
    """A triangle mesh on bicubic Bezier patches ``nets (P, 4, 4, 3)``: every patch on one grid of
    ``k x k`` cells, each cell split along a diagonal, ``k`` the fewest with every point of every
    triangle within ``max_sagitta`` of the patch at the same parameters. (Linear interpolation on a
    right triangle of legs ``h`` errs by at most ``h^2 M / 4``, ``M`` the bound of
    :func:`bezier_second_derivative_bound`.) Vertices that adjacent patches share are welded.

    Returns ``(vertices (V, 3), triangles (T, 3))``, oriented as the patches' ``x_u x x_v``.
    """
    nets = np.asarray(nets, dtype=float)
    bound = float(bezier_second_derivative_bound(nets).max())
    cells = max(1, math.ceil(math.sqrt(bound / (4.0 * max_sagitta)))) if bound > 0 else 1
    if cells > MAX_PATCH_CELLS:
        raise TessellationError(f"a patch model needs more than {MAX_PATCH_CELLS} x {MAX_PATCH_CELLS} cells per patch "
                                f"to lie within {max_sagitta:g} of its triangles")  # fmt: skip
    g = np.linspace(0.0, 1.0, cells + 1)
    u, v = np.meshgrid(g, g, indexing="ij")
    points = np.concatenate([evaluate(net, u.ravel(), v.ravel()) for net in nets])  # patch by patch, u-major
    n = cells + 1
    i, j = np.meshgrid(np.arange(cells), np.arange(cells), indexing="ij")
    a, b = (i * n + j).ravel(), ((i + 1) * n + j).ravel()  # corners (u, v) and (u + h, v)
    one = np.concatenate([np.stack([a, b, b + 1], axis=1), np.stack([a, b + 1, a + 1], axis=1)])
    faces = np.concatenate([one + p * n * n for p in range(len(nets))])
    size = float(np.linalg.norm(np.ptp(points, axis=0)))
    keys = np.round(points / (WELD_TOLERANCE * max(size, 1e-300))).astype(np.int64)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    return points[first], inverse.ravel()[faces].astype(np.int64)

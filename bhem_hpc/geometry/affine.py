"""Surfaces that are affine maps of their parameters (the flat faces of boxes, blocks and fins),
numpy only: the test, and closest points in closed form.

A NURBS surface with equal weights whose control points lie at the affine map of their Greville
abscissae is that map (B-splines reproduce linear functions:
``sum_i xi_i N_i(u) = u``): ``x(u, v) = origin + u' along_u + v' along_v`` with ``u', v'`` the
parameters scaled to ``[0, 1]`` over the domain. Its closest point to a point is the minimum of a
convex quadratic over the unit square: the projection onto the plane where it falls inside, else
the nearest of the four edges' own minima.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

#: Control points within this much of the affine map (relative to the net's size) make a surface affine.
AFFINE_TOLERANCE = 1e-12


class AffineFrame(NamedTuple):
    """``x(u', v') = origin + u' along_u + v' along_v`` for ``u', v'`` in ``[0, 1]``, each ``(3,)``."""

    origin: np.ndarray
    along_u: np.ndarray
    along_v: np.ndarray


def greville(knots: np.ndarray, degree: int, count: int) -> np.ndarray:
    """The Greville abscissae ``(count,)``: each control point's mean of its ``degree`` inner knots."""
    if degree == 0:
        return 0.5 * (knots[:count] + knots[1 : count + 1])
    window = np.cumsum(np.r_[0.0, knots[1:]])
    return (window[degree : degree + count] - window[:count]) / degree


def affine_frame(degrees: tuple[int, int], knots: tuple[np.ndarray, np.ndarray], domains, control: np.ndarray,
                 weights: np.ndarray) -> AffineFrame | None:  # fmt: skip
    """The frame of a NURBS surface (``control (n, m, 3)``, ``weights (n, m)``, knot vectors and
    parameter ``domains ((u0, u1), (v0, v1))``) that is an affine map of its parameters, or ``None``
    (unequal weights, control points off the map, or a map that collapses the square)."""
    if np.ptp(weights) > AFFINE_TOLERANCE * float(np.max(weights)):
        return None
    n, m = control.shape[:2]
    (u0, u1), (v0, v1) = domains
    at_u = (greville(knots[0], degrees[0], n) - u0) / (u1 - u0)
    at_v = (greville(knots[1], degrees[1], m) - v0) / (v1 - v0)
    # the map through three control points far apart: first, last along u, last along v
    corner_u, corner_v = at_u[-1] - at_u[0], at_v[-1] - at_v[0]
    if corner_u <= 0.0 or corner_v <= 0.0:
        return None
    along_u = (control[-1, 0] - control[0, 0]) / corner_u
    along_v = (control[0, -1] - control[0, 0]) / corner_v
    origin = control[0, 0] - at_u[0] * along_u - at_v[0] * along_v
    mapped = origin + at_u[:, None, None] * along_u + at_v[None, :, None] * along_v
    size = float(np.ptp(control.reshape(-1, 3), axis=0).max())
    if np.abs(control - mapped).max() > AFFINE_TOLERANCE * size:
        return None
    normal = np.cross(along_u, along_v)
    if np.linalg.norm(normal) <= 1e-12 * np.linalg.norm(along_u) * np.linalg.norm(along_v):
        return None
    return AffineFrame(origin, along_u, along_v)


def closest_on_parallelogram(points: np.ndarray, frame: AffineFrame) -> tuple[np.ndarray, np.ndarray]:
    """Scaled parameters ``(Q, 2)`` in ``[0, 1]^2`` of the closest points of the parallelogram
    ``frame`` to ``points (Q, 3)``, and those points ``(Q, 3)``.

    The projection onto the plane where it lies in the square; else the nearest of the four edges'
    clamped projections (the squared distance is strictly convex: its minimum over the square is
    on the boundary where the plane's is outside, and unique)."""
    origin, a, b = frame
    relative = points - origin
    aa, ab, bb = a @ a, a @ b, b @ b
    ra, rb = relative @ a, relative @ b
    determinant = aa * bb - ab * ab
    inner = np.stack([(bb * ra - ab * rb) / determinant, (aa * rb - ab * ra) / determinant], axis=1)
    # each edge: one parameter fixed at 0 or 1, the other the clamped minimum along it
    edges = []
    for fixed in (0.0, 1.0):
        edges.append(np.stack([np.full(len(points), fixed), np.clip((rb - fixed * ab) / bb, 0.0, 1.0)], axis=1))
        edges.append(np.stack([np.clip((ra - fixed * ab) / aa, 0.0, 1.0), np.full(len(points), fixed)], axis=1))
    candidates = np.stack([inner, *edges])  # (5, Q, 2)
    located = origin + candidates[..., :1] * a + candidates[..., 1:] * b  # (5, Q, 3)
    squared = ((located - points) ** 2).sum(axis=2)
    inside = np.all((inner >= 0.0) & (inner <= 1.0), axis=1)
    squared[0, ~inside] = np.inf
    best = np.argmin(squared, axis=0)  # the projection first where it lies inside
    rows = np.arange(len(points))
    return candidates[best, rows], located[best, rows]

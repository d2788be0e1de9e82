"""Joints along trim curves (numpy only): where a trimmed CAD part's trim loop runs along another
part, the two are joined there, as patches are along their edges (:mod:`bhem_hpc.geometry.interfaces`).

A CAD model's trimmed faces meet along their trim curves, not along the edges of their surfaces'
parameter rectangles. Along each loop of a trimmed part (a polygon in its parameters), every
segment gets :data:`SEGMENT_POINTS` Gauss points, weighted by the segment's rest length there; each
point finds its partner on the other part by the closest point on that part's NURBS surface
(:func:`~bhem_hpc.geometry.projection.closest_points`). Points whose partner lies within ``tolerance``
and on the kept part of the other surface (inside its trim, or on its trim loop within
:data:`LOOP_FRACTION` of a knot span) form the joint; its quadrature carries each point's direction
along the loop, which the coupling's angle term takes as the interface's tangent. Loop segments on
an edge of the part's parameter rectangle that is joined as an edge already are left out.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.polynomial import legendre

from bhem_hpc.geometry.interfaces import EDGES, EdgeQuadrature, FoundJoint, Patch
from bhem_hpc.geometry.nurbs import NurbsSurface
from bhem_hpc.geometry.projection import closest_points
from bhem_hpc.geometry.trim import inside

#: Gauss points per loop segment.
SEGMENT_POINTS = 2
#: A partner on the other part's trim loop counts as kept within this fraction of its knot span.
LOOP_FRACTION = 1e-2
#: The fewest matched points that make a joint (fewer: the loop only touches the other part).
MIN_POINTS = 4
#: Name of the trim curve side of a joint (in reports, in place of an edge's name).
TRIM_CURVE = "trim curve"


def _on_boundary_edge(grid, points: np.ndarray) -> list[str | None]:
    """The edge of the parameter rectangle each segment ``(S, 2, 2)`` lies on, or None."""
    (a, b), (c, d) = grid.xi1_range, grid.xi2_range
    eps = 1e-9 * max(b - a, d - c)
    values = {"xi1_min": (0, a), "xi1_max": (0, b), "xi2_min": (1, c), "xi2_max": (1, d)}
    out: list[str | None] = [None] * len(points)
    for edge in EDGES:
        axis, value = values[edge]
        on = np.all(np.abs(points[:, :, axis] - value) <= eps, axis=1)
        for k in np.flatnonzero(on):
            out[k] = edge
    return out


def _distance_to_loops(loops: Sequence[np.ndarray], points: np.ndarray) -> np.ndarray:
    """Each point's ``(k, 2)`` distance to the nearest segment of the closed ``loops``."""
    best = np.full(len(points), np.inf)
    for loop in loops:
        a, b = loop, np.roll(loop, -1, axis=0)
        ab = b - a
        t = np.clip(np.einsum("psc,sc->ps", points[:, None] - a[None], ab) / np.maximum((ab * ab).sum(1), 1e-300),
                    0.0, 1.0)  # fmt: skip
        nearest = a[None] + t[..., None] * ab[None]
        best = np.minimum(best, np.linalg.norm(points[:, None] - nearest, axis=2).min(axis=1))
    return best


def curve_quadrature(first: Patch, loops: Sequence[np.ndarray], second_part: NurbsSurface, second: Patch,
                     second_loops: Sequence[np.ndarray] | None, tolerance: float,
                     joined_edges: set[str]) -> EdgeQuadrature | None:  # fmt: skip
    """The joint along ``first``'s trim ``loops`` (closed polygons, the first point repeated or not) with the part
    ``second_part`` (whose shell surface is ``second``, trimmed by ``second_loops`` or whole), or
    None where fewer than :data:`MIN_POINTS` points meet it; ``joined_edges``: ``first``'s edges
    joined as edges already (segments on them are left out)."""
    nodes, gauss = legendre.leggauss(SEGMENT_POINTS)
    nodes, gauss = 0.5 * (nodes + 1.0), 0.5 * gauss
    closed = [loop[:-1] if np.array_equal(loop[0], loop[-1]) else loop for loop in map(np.asarray, loops)]
    segments = np.concatenate([np.stack([loop, np.roll(loop, -1, axis=0)], axis=1) for loop in closed])  # (S, 2, 2)
    on_edge = _on_boundary_edge(first.grid, segments)
    keep = np.array([edge is None or edge not in joined_edges for edge in on_edge], dtype=bool)
    segments = segments[keep]
    if not len(segments):
        return None
    direction = segments[:, 1] - segments[:, 0]  # (S, 2)
    xi = segments[:, None, 0] + nodes[None, :, None] * direction[:, None]  # (S, g, 2)
    xi, direction = xi.reshape(-1, 2), np.repeat(direction, SEGMENT_POINTS, axis=0)
    point = first.evaluate(xi[:, 0], xi[:, 1])
    speed = np.linalg.norm(point.a1 * direction[:, :1] + point.a2 * direction[:, 1:], axis=1)
    weights = np.tile(gauss, len(segments)) * speed
    partners, _, distance = closest_points(second_part, point.x)  # in the part's parameters: to the shell's
    partners = np.column_stack(second.surface_parameters(partners[:, 0], partners[:, 1]))
    matched = distance <= tolerance
    if second_loops is not None:
        grid = second.grid
        near = _distance_to_loops(second_loops, partners) <= LOOP_FRACTION * min(grid.h1, grid.h2)
        matched &= inside(second_loops, partners) | near
    if matched.sum() < MIN_POINTS:
        return None
    on_second = second.evaluate(partners[matched, 0], partners[matched, 1]).x
    gap = float(np.linalg.norm(point.x[matched] - on_second, axis=1).max())
    return EdgeQuadrature(xi[matched], partners[matched], weights[matched], 0, gap, direction[matched])


def find_trim_joints(parts: Sequence[NurbsSurface], shells: Sequence[Patch],
                     loops: Sequence[Sequence[np.ndarray] | None], tolerance: float,
                     edge_joints: Sequence[FoundJoint]) -> list[FoundJoint]:  # fmt: skip
    """Every joint along a trimmed part's trim loops with another part (each pair once: two
    trimmed parts from the lower-numbered one's loops), after the edge joints ``edge_joints``.

    Args:
        parts: the model's NURBS parts; shells: their shell surfaces (over the parts' parameters);
        loops: each part's trim loops, or None (untrimmed); tolerance: [m], as for edges.
    """
    joined = {(j.first, j.first_edge) for j in edge_joints} | {(j.second, j.second_edge) for j in edge_joints}
    found = []
    for a, first_loops in enumerate(loops):
        if first_loops is None:
            continue
        edges = {edge for part, edge in joined if part == a}
        for b in range(len(parts)):
            if b == a or (loops[b] is not None and b < a):
                continue
            quadrature = curve_quadrature(shells[a], first_loops, parts[b], shells[b], loops[b], tolerance, edges)
            if quadrature is not None:
                found.append(FoundJoint(a, b, TRIM_CURVE, TRIM_CURVE if loops[b] is not None else "surface",
                                        quadrature, partial=True))  # fmt: skip
    return found


def edges_joined(joint: FoundJoint, shells: Sequence[Patch]) -> set[tuple[int, str]]:
    """The edges ``(part, edge)`` of both parts' parameter rectangles along which a trim-curve joint
    runs (at least :data:`MIN_POINTS` of its points on the edge): partly joined, so not free."""
    out = set()
    for part, points in ((joint.first, joint.quadrature.first), (joint.second, joint.quadrature.second)):
        on = _on_boundary_edge(shells[part].grid, np.repeat(points[:, None], 2, axis=1))
        for edge in EDGES:
            if sum(e == edge for e in on) >= MIN_POINTS:
                out.add((part, edge))
    return out

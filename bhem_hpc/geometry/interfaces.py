"""Interfaces between patches (numpy only): the quadrature along an edge of one surface that meets
an edge of another, with each quadrature point's parameters on both sides.

A multi-patch shell is joined where two patches' edges meet (:func:`pair_edges`): the quadrature
runs along the first side's edge, over the knot spans of both sides (the second side's span ends
found on the first edge), Gauss-Legendre points in each piece; each point finds its partner on the
second edge by the closest point at rest (a bounded Newton iteration on the edge's parameter). The
two edges must be the same curve at rest: every point's partner within ``tolerance``, and each
edge's ends on the other edge. A partial interface (a T-junction: a patch's edge along part of a
longer one, or two edges that overlap in part) is the part of the first edge between the ends of
either edge that lie on the other (:func:`edge_overlap`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from bhem_hpc.geometry.grid import ParameterGrid, SurfaceError
from bhem_hpc.geometry.surface import SurfacePoint

#: The edges of a patch's parameter rectangle, by name.
EDGES = ("xi1_min", "xi1_max", "xi2_min", "xi2_max")
#: Newton iterations for a point's partner on the other edge (each halves the error at worst).
MAX_PARTNER_ITERATIONS = 40
#: Samples per knot span of the other edge that start each partner's Newton iteration.
PARTNER_SAMPLES = 16


class InterfaceError(SurfaceError):
    """Two edges that do not meet as an interface says (the message names the edges and the gap)."""


class Patch(Protocol):
    """A surface as an interface sees it: its parameter grid and its evaluation."""

    grid: ParameterGrid

    def evaluate(self, xi1: np.ndarray, xi2: np.ndarray) -> SurfacePoint: ...


@dataclass(frozen=True)
class EdgeQuadrature:
    """Quadrature points along an interface, shape ``(k, ...)`` in the order along the first edge.

    Attributes:
        first, second: each point's parameters ``(k, 2)`` on the first and the second surface.
        weights: rest arc length ``(k,)`` [m] each point stands for (their sum: the edge's length).
        along: which parameter runs along the first edge (0: xi1, 1: xi2).
        gap: the largest rest distance [m] between a point and its partner.
        directions: along a curve (a trim curve), each point's direction in the first surface's
            parameters ``(k, 2)``; None: along the edge ``along``.
    """

    first: np.ndarray
    second: np.ndarray
    weights: np.ndarray
    along: int
    gap: float
    directions: np.ndarray | None = None


def edge_line(grid: ParameterGrid, edge: str) -> tuple[int, float, tuple[float, float], np.ndarray]:
    """``(along, fixed value, range, knots)`` of an edge: which parameter runs along it, the other
    parameter's value on it, the range of the one along it and its knots (span ends).

    Raises:
        InterfaceError: an unknown edge name, or an edge across a periodic direction (it has no edge).
    """
    if edge not in EDGES:
        raise InterfaceError(f"edge {edge!r} does not exist; expected one of {EDGES}")
    fixed_axis = 0 if edge.startswith("xi1") else 1
    along = 1 - fixed_axis
    ranges = (grid.xi1_range, grid.xi2_range)
    if (grid.periodic1, grid.periodic2)[fixed_axis]:
        raise InterfaceError(f"edge {edge!r} does not exist: the surface is closed in xi{fixed_axis + 1}")
    value = ranges[fixed_axis][0] if edge.endswith("min") else ranges[fixed_axis][1]
    lo, hi = ranges[along]
    spans = (grid.n1, grid.n2)[along]
    return along, float(value), (float(lo), float(hi)), np.linspace(lo, hi, spans + 1)


def _on_edge(along: int, value: float, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The parameters ``(xi1, xi2)`` of the points at ``s`` along an edge."""
    fixed = np.full_like(s, value)
    return (fixed, s) if along == 1 else (s, fixed)


def closest_on_edge(surface: Patch, edge: str, targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The points of ``edge`` of ``surface`` closest to ``targets`` ``(k, 3)``: their parameters along
    the edge ``(k,)`` and distances ``(k,)``. Starts at the nearest of :data:`PARTNER_SAMPLES` samples per
    span, then Newton on ``|x(s) - target|^2`` clipped to the edge's range, at most
    :data:`MAX_PARTNER_ITERATIONS` iterations (stops when a step is below 1e-14 of the range)."""
    along, value, (lo, hi), knots = edge_line(surface.grid, edge)
    targets = np.asarray(targets, dtype=float).reshape(-1, 3)
    samples = np.linspace(lo, hi, PARTNER_SAMPLES * (len(knots) - 1) + 1)
    sampled = surface.evaluate(*_on_edge(along, value, samples)).x
    distance = np.linalg.norm(sampled[None, :, :] - targets[:, None, :], axis=-1)
    s = samples[np.argmin(distance, axis=1)]
    for _ in range(MAX_PARTNER_ITERATIONS):
        point = surface.evaluate(*_on_edge(along, value, s))
        tangent = point.a2 if along == 1 else point.a1
        second = point.a22 if along == 1 else point.a11
        d = point.x - targets
        slope = np.einsum("kc,kc->k", d, tangent)
        curvature = np.einsum("kc,kc->k", tangent, tangent) + np.einsum("kc,kc->k", d, second)
        step = -slope / np.where(curvature > 0, curvature, np.einsum("kc,kc->k", tangent, tangent))
        s_new = np.clip(s + step, lo, hi)
        moved = np.abs(s_new - s).max(initial=0.0)
        s = s_new
        if moved <= 1e-14 * (hi - lo):
            break
    x = surface.evaluate(*_on_edge(along, value, s)).x
    return s, np.linalg.norm(x - targets, axis=-1)


def edge_overlap(first: Patch, first_edge: str, second: Patch, second_edge: str,
                 tolerance: float) -> tuple[float, float]:  # fmt: skip
    """``(s0, s1)``: the part of ``first_edge``'s parameter range that lies along ``second_edge`` at
    rest, between the ends of either edge that lie within ``tolerance`` [m] of the other edge.

    Raises:
        InterfaceError: no such part of positive length (edges apart, crossing, or meeting at a point).
    """
    along, value, (lo, hi), _ = edge_line(first.grid, first_edge)
    _, end_gaps = closest_on_edge(second, second_edge, _edge_ends(first, first_edge))
    found, other_gaps = closest_on_edge(first, first_edge, _edge_ends(second, second_edge))
    ends = [s for s, gap in zip((lo, hi), end_gaps, strict=True) if gap <= tolerance]
    ends += [float(s) for s, gap in zip(found, other_gaps, strict=True) if gap <= tolerance]
    if not ends or max(ends) - min(ends) <= 1e-9 * (hi - lo):
        closest = float(min(end_gaps.min(), other_gaps.min()))
        raise InterfaceError(f"edge {first_edge} of the first patch and edge {second_edge} of the second share no "
                             f"part of an edge: no end of one lies along the other but at a point, the closest "
                             f"{closest:.3g} m from it (tolerance {tolerance:.3g} m)")  # fmt: skip
    return min(ends), max(ends)


def pair_edges(first: Patch, first_edge: str, second: Patch, second_edge: str, tolerance: float,
               points_per_span: int = 4, partial: bool = False) -> EdgeQuadrature:  # fmt: skip
    """The quadrature of the interface where ``first_edge`` of ``first`` meets ``second_edge`` of
    ``second`` (whole edges, either orientation; with ``partial``, the part where they meet).

    Args:
        tolerance: the largest rest distance [m] between the two edges.
        points_per_span: Gauss-Legendre points in each piece between consecutive span ends.
        partial: join only the part the edges share (:func:`edge_overlap`).

    Raises:
        InterfaceError: an edge that does not exist, or edges farther apart than ``tolerance``
            (naming the edges, the gap and where).
    """
    along, value, (lo, hi), knots = edge_line(first.grid, first_edge)
    other_along, other_value, _, other_knots = edge_line(second.grid, second_edge)
    start, end = edge_overlap(first, first_edge, second, second_edge, tolerance) if partial else (lo, hi)
    # the second edge's span ends, found on the first edge: breaks of the quadrature
    other_ends = second.evaluate(*_on_edge(other_along, other_value, other_knots)).x
    found, gaps = closest_on_edge(first, first_edge, other_ends)
    if partial:
        found = found[(gaps <= tolerance) & (found > start) & (found < end)]
        knots = np.concatenate([[start], knots[(knots > start) & (knots < end)], [end]])
    else:
        _, end_gaps = closest_on_edge(second, second_edge, _edge_ends(first, first_edge))
        worst = max(float(gaps.max()), float(end_gaps.max()))
        if worst > tolerance:
            raise InterfaceError(f"edge {first_edge} of the first patch and edge {second_edge} of the second do "
                                 f"not meet: their ends lie {worst:.3g} m from the other edge "
                                 f"(tolerance {tolerance:.3g} m)")  # fmt: skip
    breaks = np.unique(np.concatenate([knots, found]))
    breaks = breaks[np.concatenate([[True], np.diff(breaks) > 1e-9 * (hi - lo)])]
    nodes, gauss_weights = np.polynomial.legendre.leggauss(points_per_span)
    left, width = breaks[:-1, None], np.diff(breaks)[:, None]
    s = (left + 0.5 * width * (nodes + 1)).ravel()
    ds = (0.5 * width * gauss_weights).ravel()
    point = first.evaluate(*_on_edge(along, value, s))
    speed = np.linalg.norm(point.a2 if along == 1 else point.a1, axis=-1)
    partner, distance = closest_on_edge(second, second_edge, point.x)
    gap = float(distance.max())
    if gap > tolerance:
        where = point.x[int(np.argmax(distance))]
        raise InterfaceError(f"edge {first_edge} of the first patch and edge {second_edge} of the second do not meet: "
                             f"{gap:.3g} m apart near {np.array2string(where, precision=4)} "
                             f"(tolerance {tolerance:.3g} m)")  # fmt: skip
    first_parameters = np.stack(_on_edge(along, value, s), axis=1)
    second_parameters = np.stack(_on_edge(other_along, other_value, partner), axis=1)
    return EdgeQuadrature(first_parameters, second_parameters, speed * ds, along, gap)


#: The most two sides of a seam may differ in rest length (the longer over the shorter).
MAX_SEAM_LENGTH_RATIO = 1.1


def edge_length(surface: Patch, edge: str, points_per_span: int = 4) -> float:
    """The rest length [m] of an edge (Gauss-Legendre in each span)."""
    along, value, _, knots = edge_line(surface.grid, edge)
    nodes, weights = np.polynomial.legendre.leggauss(points_per_span)
    width = np.diff(knots)[:, None]
    s = (knots[:-1, None] + 0.5 * width * (nodes + 1)).ravel()
    point = surface.evaluate(*_on_edge(along, value, s))
    speed = np.linalg.norm(point.a2 if along == 1 else point.a1, axis=-1)
    return float(np.sum(speed * (0.5 * width * weights).ravel()))


def pair_seam(first: Patch, first_edge: str, second: Patch, second_edge: str, reverse: bool = False,
              points_per_span: int = 4) -> EdgeQuadrature:  # fmt: skip
    """The quadrature of a seam that sews ``first_edge`` of ``first`` to ``second_edge`` of ``second``
    (apart at rest): the point at a fraction of the first edge's parameter range meets the point at
    the same fraction of the second's (from its other end with ``reverse``). ``gap``: the largest
    rest distance between partners.

    Raises:
        InterfaceError: an edge that does not exist, or sides whose rest lengths differ by more
            than :data:`MAX_SEAM_LENGTH_RATIO` (naming both lengths).
    """
    along, value, (lo, hi), knots = edge_line(first.grid, first_edge)
    other_along, other_value, (other_lo, other_hi), other_knots = edge_line(second.grid, second_edge)
    lengths = edge_length(first, first_edge), edge_length(second, second_edge)
    if max(lengths) > MAX_SEAM_LENGTH_RATIO * min(lengths):
        raise InterfaceError(f"the seam's sides differ in length: edge {first_edge} of the first panel is "
                             f"{lengths[0]:.4g} m, edge {second_edge} of the second {lengths[1]:.4g} m (at most "
                             f"{MAX_SEAM_LENGTH_RATIO:g} times the shorter)")  # fmt: skip
    fractions = np.unique(np.concatenate([(knots - lo) / (hi - lo), (other_knots - other_lo) / (other_hi - other_lo)]))
    fractions = fractions[np.concatenate([[True], np.diff(fractions) > 1e-9])]
    nodes, gauss_weights = np.polynomial.legendre.leggauss(points_per_span)
    width = np.diff(fractions)[:, None]
    f = (fractions[:-1, None] + 0.5 * width * (nodes + 1)).ravel()
    s = lo + f * (hi - lo)
    point = first.evaluate(*_on_edge(along, value, s))
    speed = np.linalg.norm(point.a2 if along == 1 else point.a1, axis=-1)
    partner = other_lo + (1.0 - f if reverse else f) * (other_hi - other_lo)
    partner_point = second.evaluate(*_on_edge(other_along, other_value, partner))
    return EdgeQuadrature(np.stack(_on_edge(along, value, s), axis=1),
                          np.stack(_on_edge(other_along, other_value, partner), axis=1),
                          speed * (0.5 * width * gauss_weights).ravel() * (hi - lo), along,
                          float(np.linalg.norm(point.x - partner_point.x, axis=-1).max()))  # fmt: skip


def element_across(surface: Patch, edge: str) -> float:
    """The rest width [m] of the patches along ``edge``, across it (the penalty rule's element size):
    the cross parameter's span width times the mean rest speed of that parameter on the edge."""
    along, value, _, knots = edge_line(surface.grid, edge)
    middle = 0.5 * (knots[:-1] + knots[1:])
    point = surface.evaluate(*_on_edge(along, value, middle))
    across = point.a1 if along == 1 else point.a2
    width = surface.grid.h1 if along == 1 else surface.grid.h2
    return float(width * np.linalg.norm(across, axis=-1).mean())


def element_size(surface: Patch, edge: str) -> float:
    """The penalty rule's element size [m] across a side of an interface: across ``edge``
    (:func:`element_across`), or, along a curve (a trim curve, any other name), the smaller rest
    width of the knot spans, averaged over their centres."""
    if edge in EDGES:
        return element_across(surface, edge)
    grid = surface.grid
    centre1 = grid.xi1_range[0] + (np.arange(grid.n1) + 0.5) * grid.h1
    centre2 = grid.xi2_range[0] + (np.arange(grid.n2) + 0.5) * grid.h2
    a, b = (v.ravel() for v in np.meshgrid(centre1, centre2, indexing="ij"))
    point = surface.evaluate(a, b)
    widths = np.minimum(grid.h1 * np.linalg.norm(point.a1, axis=-1), grid.h2 * np.linalg.norm(point.a2, axis=-1))
    return float(widths.mean())


@dataclass(frozen=True)
class FoundJoint:
    """Two patches' edges that meet along their whole length, or (``partial``) along a part of one
    or both (:func:`find_joints`)."""

    first: int
    second: int
    first_edge: str
    second_edge: str
    quadrature: EdgeQuadrature
    partial: bool = False


def _open_edges(surface: Patch) -> list[str]:
    grid = surface.grid
    return [e for e in EDGES if not (grid.periodic1 if e.startswith("xi1") else grid.periodic2)]


def _edge_ends(surface: Patch, edge: str) -> np.ndarray:
    along, value, (lo, hi), _ = edge_line(surface.grid, edge)
    return surface.evaluate(*_on_edge(along, value, np.array([lo, hi]))).x


#: Samples along an edge for the box that rules out partial joints cheaply.
EDGE_BOX_SAMPLES = 33


def _edge_box(surface: Patch, edge: str) -> np.ndarray:
    """``(2, 3)``: lower and upper corner of a box around an edge: the box of its samples, widened
    by their largest second difference. A curve bulges out of its chord between two samples by
    about ``h^2 |x''| / 8`` (``h`` the sample step), an eighth of that difference: a short edge that
    lies along a curved one near its extreme would otherwise fall outside its box."""
    along, value, (lo, hi), _ = edge_line(surface.grid, edge)
    x = surface.evaluate(*_on_edge(along, value, np.linspace(lo, hi, EDGE_BOX_SAMPLES))).x
    bulge = np.linalg.norm(x[2:] - 2.0 * x[1:-1] + x[:-2], axis=1).max()
    return np.stack([x.min(axis=0) - bulge, x.max(axis=0) + bulge])


def find_joints(surfaces: Sequence[Patch], tolerance: float) -> tuple[list[FoundJoint], list[tuple[int, str]]]:
    """Where patches of a model meet: every pair of whole edges, of two patches, whose ends meet
    within ``tolerance`` [m] (either orientation) and that :func:`pair_edges` finds within it all
    along; then, among the edges left, every pair that shares a part (``partial``: a T-junction, or
    edges that overlap in part; an edge may have several); and the edges that meet none.

    Returns:
        ``(joints, free)``: the joints in patch order (whole ones first), and ``(patch, edge)`` of
        every edge in none.
    """
    edges = [[(e, _edge_ends(s, e)) for e in _open_edges(s)] for s in surfaces]
    pairs = [(a, b, edge_a, ends_a, edge_b, ends_b) for a in range(len(surfaces)) for b in range(a + 1, len(surfaces))
             for edge_a, ends_a in edges[a] for edge_b, ends_b in edges[b]]  # fmt: skip
    joints, whole = [], set()
    for a, b, edge_a, ends_a, edge_b, ends_b in pairs:
        apart = min(np.abs(ends_a - ends_b).max(), np.abs(ends_a - ends_b[::-1]).max())
        if apart > tolerance or (a, edge_a) in whole or (b, edge_b) in whole:
            continue
        try:
            quadrature = pair_edges(surfaces[a], edge_a, surfaces[b], edge_b, tolerance)
        except InterfaceError:
            continue
        joints.append(FoundJoint(a, b, edge_a, edge_b, quadrature))
        whole |= {(a, edge_a), (b, edge_b)}
    boxes = {(k, e): _edge_box(s, e) for k, s in enumerate(surfaces) for e in _open_edges(s)}
    joined = set(whole)
    for a, b, edge_a, _, edge_b, _ in pairs:
        box_a, box_b = boxes[a, edge_a], boxes[b, edge_b]
        if (a, edge_a) in whole or (b, edge_b) in whole or np.any(box_a[0] > box_b[1] + tolerance) \
                or np.any(box_b[0] > box_a[1] + tolerance):  # fmt: skip
            continue
        try:
            quadrature = pair_edges(surfaces[a], edge_a, surfaces[b], edge_b, tolerance, partial=True)
        except InterfaceError:
            continue
        joints.append(FoundJoint(a, b, edge_a, edge_b, quadrature, partial=True))
        joined |= {(a, edge_a), (b, edge_b)}
    free = [(k, edge) for k, s in enumerate(surfaces) for edge in _open_edges(s) if (k, edge) not in joined]
    return joints, free

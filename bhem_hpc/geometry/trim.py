"""Trimmed parameter domains and their cut-cell quadrature (numpy and SciPy only).

A trimmed patch keeps the part of its parameter rectangle that its trim loops bound: closed
polygons in ``(xi1, xi2)`` (a CAD file's trim curves, sampled finely), the region inside an odd
number of them (outer loops and their holes, :func:`check_loops`).

Quadrature on such a region (:func:`cut_cell_rule`) keeps the tensor Gauss rule of each knot span
(cell): a cell wholly inside keeps its weights, a cell wholly outside gets none, and a cell the
trim cuts keeps the Gauss points with weights fitted to the region's moments (moment fitting,
Müller, Kummer & Oberlack 2013; Joulaian et al. 2016 for finite cells): the integrals over the
cell's inside part of the products ``P_a(s) P_b(t)`` of shifted Legendre polynomials up to the
rule's exactness (``a, b < n`` for ``n x n`` points), computed exactly by Green's theorem along
the loops clipped to the cell, and matched by non-negative weights (SciPy's NNLS), so that an
energy whose density is convex stays convex. The points stay where the full rule has them, so a
finite-element assembly with one rule per cell only needs a factor per point (``weights / full``).
Where non-negative weights on the fixed points cannot match every moment (a sliver of a cell), the
area is matched exactly and the other moments as well as they can be: the residual is reported.

A :class:`Trim` is a surface's checked loops with the rule on its knot spans: what a trimmed shell
model (:mod:`bhem_hpc.model.trimmed`) and a scene's ``[trim]`` table build on.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.optimize
from numpy.polynomial import legendre

from bhem_hpc.geometry.grid import ParameterGrid, SurfaceError

#: Points a patch's trim loops may have together (the self-intersection test compares every pair
#: of segments near each other).
MAX_TRIM_POINTS = 20_000
#: A cell whose inside part is less than this fraction of it counts as outside (and one within it
#: of whole as inside): a sliver's quadrature would be noise.
SLIVER_FRACTION = 1e-10
#: How much more the area equation weighs than the other moments in the fit.
AREA_EQUATION_WEIGHT = 1e3
#: How far [relative to the parameter domain's diagonal] a loop's ends may be apart and its points
#: outside the domain.
LOOP_TOLERANCE = 1e-9
#: Points sampled along each edge to decide whether the trim keeps it whole.
EDGE_SAMPLES = 257
#: Cell states in :class:`CutCellRule`.
OUTSIDE, INSIDE, CUT = 0, 1, 2


class TrimError(SurfaceError):
    """Trim loops that do not bound a region of the patch (the message names the loop and point)."""


def _signed_area(loop: np.ndarray) -> float:
    following = np.roll(loop, -1, axis=0)
    return 0.5 * float(np.sum(loop[:, 0] * following[:, 1] - following[:, 0] * loop[:, 1]))


def _segments(loops: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every loop's segments: starts ``(S, 2)``, ends ``(S, 2)`` and loop index ``(S,)``."""
    starts = np.concatenate(loops)
    ends = np.concatenate([np.roll(loop, -1, axis=0) for loop in loops])
    owner = np.concatenate([np.full(len(loop), k) for k, loop in enumerate(loops)])
    return starts, ends, owner


def _crossing_segments(loops: Sequence[np.ndarray]) -> tuple[int, int] | None:
    """Two segments (global indices) that cross or touch other than at a shared vertex of
    neighbours, or None. Segments are sorted by their lower x; each meets only those that start
    before it ends (a sweep, vectorized per segment)."""
    starts, ends, owner = _segments(loops)
    count = len(starts)
    low = np.minimum(starts, ends)
    high = np.maximum(starts, ends)
    order = np.argsort(low[:, 0], kind="stable")
    first = np.concatenate([[0], np.cumsum([len(loop) for loop in loops])])
    # a segment's neighbours along its loop share a vertex with it: they do not count
    local = np.arange(count) - first[owner]
    sizes = np.array([len(loop) for loop in loops])[owner]
    for rank, i in enumerate(order):
        later = order[rank + 1:]
        later = later[low[later, 0] <= high[i, 0]]
        later = later[(low[later, 1] <= high[i, 1]) & (high[later, 1] >= low[i, 1])]
        same = owner[later] == owner[i]
        gap = np.abs(local[later] - local[i])
        later = later[~(same & ((gap == 1) | (gap == sizes[i] - 1)))]
        meets = later[_segments_meet(starts[i], ends[i], starts[later], ends[later])] if len(later) else later
        if len(meets):
            return int(i), int(meets[0])
    return None


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _segments_meet(p: np.ndarray, q: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Whether segment ``p q`` meets each of ``starts ends`` ``(k, 2)`` (touching counts)."""
    d1 = _cross(q - p, starts - p)
    d2 = _cross(q - p, ends - p)
    d3 = _cross(ends - starts, p - starts)
    d4 = _cross(ends - starts, q - starts)
    proper = (d1 * d2 <= 0.0) & (d3 * d4 <= 0.0)
    collinear = (d1 == 0.0) & (d2 == 0.0)
    if not np.any(collinear):
        return proper
    # collinear segments meet where their projections overlap
    axis = int(np.argmax(np.abs(q - p)))
    lo, hi = min(p[axis], q[axis]), max(p[axis], q[axis])
    other_lo = np.minimum(starts[:, axis], ends[:, axis])
    other_hi = np.maximum(starts[:, axis], ends[:, axis])
    return np.where(collinear, (other_lo <= hi) & (other_hi >= lo), proper)


def close_loop(points: np.ndarray) -> np.ndarray:
    """A polygon ``(n, 2)`` as a loop is written: its first point repeated at its end (once)."""
    points = np.asarray(points, dtype=float)
    return points if np.array_equal(points[-1], points[0]) else np.concatenate([points, points[:1]])


def inside(loops: Sequence[np.ndarray], points: np.ndarray) -> np.ndarray:
    """Whether each of ``points`` ``(k, 2)`` lies inside an odd number of ``loops`` (the even-odd
    rule; a point on a loop counts either way)."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    starts, ends, _ = _segments(loops)
    crossings = np.zeros(len(points), dtype=np.int64)
    for chunk in range(0, len(starts), 2048):
        a, b = starts[chunk:chunk + 2048], ends[chunk:chunk + 2048]
        spans = (a[None, :, 1] > points[:, None, 1]) != (b[None, :, 1] > points[:, None, 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            x = a[None, :, 0] + (points[:, None, 1] - a[None, :, 1]) * (b[None, :, 0] - a[None, :, 0]) / (
                b[None, :, 1] - a[None, :, 1])
        crossings += np.sum(spans & (points[:, None, 0] < x), axis=1)
    return crossings % 2 == 1


def check_loops(loops: Sequence, domain: tuple[tuple[float, float], tuple[float, float]], tolerance: float,
                where: str = "trim") -> list[np.ndarray]:  # fmt: skip
    """Trim loops as :func:`cut_cell_rule` takes them, or :class:`TrimError` naming the loop.

    Args:
        loops: polygons ``(n_k, 2)`` in the patch's parameters, each closed: its last point repeats
            its first (within ``tolerance``).
        domain: the patch's parameter rectangle ``((xi1_min, xi1_max), (xi2_min, xi2_max))``.
        tolerance: how far [parameter units] a loop's ends may be apart and its points outside the
            domain (points within it are moved onto the domain).
        where: what the messages name (e.g. ``"patches[2].trim"``).

    Returns the loops without their repeated last points, outer loops (inside an even number of
    others) counterclockwise and holes clockwise. Refused: a loop with fewer than 3 distinct points,
    not closed, leaving the domain, of no area, crossing itself or another loop.
    """
    (a, b), (c, d) = domain
    lo, hi = np.array([a, c], dtype=float), np.array([b, d], dtype=float)
    checked = []
    for k, loop in enumerate(loops):
        loop = np.asarray(loop, dtype=float)
        if loop.ndim != 2 or loop.shape[1] != 2 or not np.all(np.isfinite(loop)):
            raise TrimError(f"{where}[{k}]: a loop is a list of finite (xi1, xi2) points, got shape {loop.shape}")
        gap = float(np.linalg.norm(loop[-1] - loop[0])) if len(loop) else 0.0
        if len(loop) < 4 or gap > tolerance:
            raise TrimError(f"{where}[{k}] is not closed: its last point {loop[-1].tolist() if len(loop) else None} "
                            f"is {gap:.3g} from its first (tolerance {tolerance:g}); a loop of at least 3 points "
                            "repeats its first point at its end")  # fmt: skip
        loop = loop[:-1]
        outside = np.flatnonzero(np.any((loop < lo - tolerance) | (loop > hi + tolerance), axis=1))
        if len(outside):
            raise TrimError(f"{where}[{k}] leaves the patch's parameter domain [{a:g}, {b:g}] x [{c:g}, {d:g}]: "
                            f"point {int(outside[0])} is {loop[outside[0]].tolist()}")  # fmt: skip
        loop = np.clip(loop, lo, hi)
        area = _signed_area(loop)
        if abs(area) <= tolerance * np.linalg.norm(hi - lo):
            raise TrimError(f"{where}[{k}] bounds no area ({abs(area):.3g})")
        checked.append(loop)
    if not checked:
        raise TrimError(f"{where}: no trim loop")
    if sum(len(loop) for loop in checked) > MAX_TRIM_POINTS:
        raise TrimError(f"{where}: {sum(len(loop) for loop in checked)} points in all, more than {MAX_TRIM_POINTS}")
    crossing = _crossing_segments(checked)
    if crossing is not None:
        starts, _, owner = _segments(checked)
        i, j = crossing
        raise TrimError(f"{where}: loop {owner[i]} crosses {'itself' if owner[i] == owner[j] else f'loop {owner[j]}'} "
                        f"near {starts[i].tolist()} and {starts[j].tolist()}")  # fmt: skip
    oriented = []
    for k, loop in enumerate(checked):
        others = [other for m, other in enumerate(checked) if m != k]
        depth = sum(bool(inside([other], loop[:1])[0]) for other in others)
        outer = depth % 2 == 0
        oriented.append(loop if (_signed_area(loop) > 0) == outer else loop[::-1].copy())
    return oriented


def _clip(polygon: np.ndarray, axis: int, bound: float, keep_below: bool) -> np.ndarray:
    """Sutherland-Hodgman against one half-plane ``x[axis] <= bound`` (or ``>=``), vectorized: the
    clipped polygon ``(m, 2)`` (a concave polygon may come out with edges along the boundary that
    cancel in pairs, which integrals do not see)."""
    if len(polygon) == 0:
        return polygon
    following = np.roll(polygon, -1, axis=0)
    side = polygon[:, axis] - bound if keep_below else bound - polygon[:, axis]
    side_next = np.roll(side, -1)
    here, there = side <= 0.0, side_next <= 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        fraction = np.where(here != there, side / (side - side_next), 0.0)
    crossing = polygon + fraction[:, None] * (following - polygon)
    crossing[:, axis] = np.where(here != there, bound, crossing[:, axis])
    # per edge: the crossing where the edge crosses, then its end where the end is kept
    out = np.stack([crossing, following], axis=1)  # (edges, 2, 2)
    keep = np.stack([here != there, there], axis=1)
    return out[keep]


def clip_to_box(polygon: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """``polygon`` ``(n, 2)`` clipped to the box ``[lo, hi]`` (Sutherland-Hodgman)."""
    for axis in (0, 1):
        polygon = _clip(polygon, axis, float(hi[axis]), keep_below=True)
        polygon = _clip(polygon, axis, float(lo[axis]), keep_below=False)
    return polygon


def legendre_moments(polygons: Sequence[np.ndarray], degree: int) -> np.ndarray:
    """``M[a, b] = int P_a(s) P_b(t) ds dt`` over the region the oriented ``polygons`` (in the unit
    square's coordinates ``(s, t)``) bound, ``a, b <= degree`` (``P`` the Legendre polynomials
    shifted to ``[0, 1]``), exactly: by Green's theorem, ``int f = oint F dt`` with ``F = Q_a(s)
    P_b(t)``, ``Q_a`` the antiderivative of ``P_a`` from 0, and Gauss-Legendre along each edge."""
    moments = np.zeros((degree + 1, degree + 1))
    nodes, weights = legendre.leggauss(degree + 2)
    tau = 0.5 * (nodes + 1.0)
    weights = 0.5 * weights
    basis = np.eye(degree + 1)
    antiderivatives = [0.5 * legendre.legint(basis[a], lbnd=-1) for a in range(degree + 1)]
    for polygon in polygons:
        if len(polygon) < 3:
            continue
        p0, p1 = polygon, np.roll(polygon, -1, axis=0)
        s = p0[:, None, 0] + tau[None, :] * (p1 - p0)[:, None, 0]  # (edges, points)
        t = p0[:, None, 1] + tau[None, :] * (p1 - p0)[:, None, 1]
        dt = (p1 - p0)[:, 1]
        q = np.stack([legendre.legval(2 * s - 1, antiderivatives[a]) for a in range(degree + 1)])  # (a, e, p)
        p = np.stack([legendre.legval(2 * t - 1, basis[b]) for b in range(degree + 1)])
        moments += np.einsum("aep,bep,p,e->ab", q, p, weights, dt)
    return moments


@dataclass(frozen=True)
class CutCellRule:
    """The quadrature of a trimmed region cell by cell, on each cell's ``n x n`` Gauss points.

    Attributes:
        points: the Gauss points in the unit cell ``(n * n, 2)`` (``s`` along xi1 outer, ``t`` inner).
        full: their weights in the unit cell ``(n * n,)`` (they sum to 1).
        weights: each cell's weights ``(cells, n * n)`` in the unit cell (sum: the cell's inside fraction).
        states: :data:`OUTSIDE`, :data:`INSIDE` or :data:`CUT` per cell ``(cells,)``.
        residuals: each cut cell's moment misfit relative to its area (0 elsewhere) ``(cells,)``.
    """

    points: np.ndarray
    full: np.ndarray
    weights: np.ndarray
    states: np.ndarray
    residuals: np.ndarray

    @property
    def factors(self) -> np.ndarray:
        """``weights / full`` ``(cells, n * n)``: what multiplies each point's integrand."""
        return self.weights / self.full[None, :]


def gauss_cell_points(n: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``n x n`` Gauss points ``(n * n, 2)`` of the unit square and their weights."""
    nodes, weights = legendre.leggauss(n)
    nodes, weights = 0.5 * (nodes + 1.0), 0.5 * weights
    points = np.array([(s, t) for s in nodes for t in nodes])
    return points, np.outer(weights, weights).ravel()


def cut_cell_rule(loops: Sequence[np.ndarray], lows: np.ndarray, highs: np.ndarray, n: int,
                  degree: int | None = None) -> CutCellRule:  # fmt: skip
    """The quadrature of the region ``loops`` bound (as :func:`check_loops` returns them) on the
    cells ``[lows[c], highs[c]]`` (``(cells, 2)`` each), ``n x n`` Gauss points per cell, cut cells'
    weights fitted to the moments ``P_a P_b``, ``a, b <= degree`` (default ``n - 1``: the Gauss
    rule's own exactness; fewer moments on as many points leave the fit more room)."""
    degree = n - 1 if degree is None else int(degree)
    if not 0 <= degree < n:
        raise ValueError(f"moments of degree {degree} need 0 <= degree < n = {n}")
    lows, highs = np.asarray(lows, dtype=float).reshape(-1, 2), np.asarray(highs, dtype=float).reshape(-1, 2)
    points, full = gauss_cell_points(n)
    cells = len(lows)
    weights = np.zeros((cells, n * n))
    states = np.full(cells, OUTSIDE, dtype=np.int8)
    residuals = np.zeros(cells)
    touched = _touched_cells(loops, lows, highs)
    untouched = np.flatnonzero(~touched)
    centres_inside = inside(loops, 0.5 * (lows[untouched] + highs[untouched]))
    states[untouched[centres_inside]] = INSIDE
    weights[untouched[centres_inside]] = full
    # the fit's matrix: Legendre products at the Gauss points, the area's row weighted up
    count = degree + 1
    basis = np.eye(count)
    along_s = np.stack([legendre.legval(2 * points[:, 0] - 1, basis[a]) for a in range(count)])  # (a, points)
    along_t = np.stack([legendre.legval(2 * points[:, 1] - 1, basis[b]) for b in range(count)])
    values = (along_s[:, None, :] * along_t[None, :, :]).reshape(count * count, n * n)  # row a * count + b
    row_weights = np.ones(count * count)
    row_weights[0] = AREA_EQUATION_WEIGHT
    for cell in np.flatnonzero(touched):
        size = highs[cell] - lows[cell]
        clipped = [(clip_to_box(loop, lows[cell], highs[cell]) - lows[cell]) / size for loop in loops]
        moments = legendre_moments(clipped, degree).ravel()
        area = moments[0]
        if area <= SLIVER_FRACTION:
            continue
        if area >= 1.0 - SLIVER_FRACTION and np.allclose(moments[1:], 0.0, atol=SLIVER_FRACTION):
            states[cell], weights[cell] = INSIDE, full
            continue
        fitted, _ = scipy.optimize.nnls(row_weights[:, None] * values, row_weights * moments)
        fitted *= area / fitted.sum()  # the area exactly (P_0 = 1: the area's row sums the weights)
        states[cell], weights[cell] = CUT, fitted
        residuals[cell] = float(np.linalg.norm(values @ fitted - moments)) / area
    return CutCellRule(points, full, weights, states, residuals)


def _touched_cells(loops: Sequence[np.ndarray], lows: np.ndarray, highs: np.ndarray) -> np.ndarray:
    """Cells ``(cells,)`` that some loop segment's bounding box overlaps (the others are wholly
    inside or wholly outside)."""
    starts, ends, _ = _segments(loops)
    seg_low, seg_high = np.minimum(starts, ends), np.maximum(starts, ends)
    touched = np.zeros(len(lows), dtype=bool)
    for chunk in range(0, len(starts), 1024):
        lo, hi = seg_low[chunk:chunk + 1024], seg_high[chunk:chunk + 1024]
        overlap = np.all((lo[None, :, :] <= highs[:, None, :]) & (hi[None, :, :] >= lows[:, None, :]), axis=2)
        touched |= overlap.any(axis=1)
    return touched


@dataclass(frozen=True)
class Trim:
    """A patch's trim: checked loops (:func:`~bhem_hpc.geometry.trim.check_loops`) and the rule on
    its knot spans.

    Attributes:
        loops: the loops ``(n_k, 2)`` in the patch's parameters, outer ones counterclockwise.
        rule: the cut-cell rule of the spans in the grid's order ``p1 * n2 + p2``.
        points: Gauss points per direction of the rule (the shell's quadrature).
    """

    loops: tuple[np.ndarray, ...]
    rule: CutCellRule
    points: int

    @classmethod
    def of(cls, grid: ParameterGrid, loops: Sequence, points: int, where: str = "trim") -> Trim:
        """Check ``loops`` on ``grid``'s parameter domain and fit the rule of ``points`` x ``points``
        Gauss points on its spans (:class:`~bhem_hpc.geometry.trim.TrimError` naming ``where``)."""
        domain = (grid.xi1_range, grid.xi2_range)
        diagonal = float(np.hypot(grid.xi1_range[1] - grid.xi1_range[0], grid.xi2_range[1] - grid.xi2_range[0]))
        if grid.periodic1 or grid.periodic2:
            raise TrimError(f"{where}: a surface closed in a direction (periodic) cannot be trimmed")
        checked = check_loops(loops, domain, LOOP_TOLERANCE * diagonal, where)
        p1, p2 = (a.ravel() for a in np.meshgrid(np.arange(grid.n1), np.arange(grid.n2), indexing="ij"))
        lows = np.column_stack([grid.xi1_range[0] + p1 * grid.h1, grid.xi2_range[0] + p2 * grid.h2])
        rule = cut_cell_rule(checked, lows, lows + [grid.h1, grid.h2], points)
        if np.all(rule.states == OUTSIDE):
            raise TrimError(f"{where}: the loops keep no knot span of the surface")
        return cls(tuple(checked), rule, points)

    def keeps_edge(self, grid: ParameterGrid, edge: str) -> bool:
        """Whether the whole ``edge`` (``"xi1_min"``, ...) lies in the kept region."""
        t = np.linspace(0.0, 1.0, EDGE_SAMPLES)
        (a, b), (c, d) = grid.xi1_range, grid.xi2_range
        # a hair inside the domain: a loop along the edge itself keeps it
        inset = 1e-9 * max(b - a, d - c)
        along1, along2 = a + inset + t * (b - a - 2 * inset), c + inset + t * (d - c - 2 * inset)
        points = {"xi1_min": (np.full_like(t, a + inset), along2), "xi1_max": (np.full_like(t, b - inset), along2),
                  "xi2_min": (along1, np.full_like(t, c + inset)),
                  "xi2_max": (along1, np.full_like(t, d - inset))}[edge]  # fmt: skip
        return bool(np.all(inside(self.loops, np.column_stack(points))))

    def keeps(self, xi: np.ndarray) -> np.ndarray:
        """Whether each parameter point ``(k, 2)`` lies in the kept region."""
        return inside(self.loops, np.asarray(xi, dtype=float).reshape(-1, 2))

    def kept_elements(self, parameters: np.ndarray, elements: np.ndarray) -> np.ndarray:
        """The ``elements`` ``(e, k)`` (vertex indices into ``parameters (v, 2)``) whose centre it keeps:
        a tessellation or collision mesh of the kept region, its edge within an element of the trim."""
        return elements[self.keeps(parameters[elements].mean(axis=1))]

    @property
    def kept_spans(self) -> np.ndarray:
        """Spans ``(k,)`` (order ``p1 * n2 + p2``) with some weight."""
        return np.flatnonzero(self.rule.states != OUTSIDE)


def check_trimmed(trim: Trim, grid: ParameterGrid, edge_loads: Sequence[tuple[str, str]],
                  points: Sequence[tuple[str, float, float]]) -> None:  # fmt: skip
    """What a trimmed shell refuses (:class:`~bhem_hpc.geometry.trim.TrimError`): an edge load (named,
    and its edge) on an edge the trim cuts, a point load or point constraint (named, and its
    parameters) outside the kept region."""
    for name, edge in edge_loads:
        if not trim.keeps_edge(grid, edge):
            raise TrimError(f"{name} acts on edge '{edge}', which the trim cuts: edge loads need an edge the trim "
                            "keeps whole")  # fmt: skip
    for name, xi1, xi2 in points:
        if not trim.keeps(np.array([xi1, xi2]))[0]:
            raise TrimError(f"{name} at (xi1, xi2) = ({xi1:g}, {xi2:g}) lies outside the trimmed surface")

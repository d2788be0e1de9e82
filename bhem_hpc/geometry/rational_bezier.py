"""Rational Bezier patches of any degree: evaluation, sub-patches, and the crossings of
axis-parallel lines, numpy only.

A net is ``(p + 1, q + 1, 4)`` in homogeneous coordinates ``(w x, w y, w z, w)`` (see
:class:`bhem_hpc.geometry.nurbs.RationalBezierPatches`); batches carry a leading patch axis.
With positive weights a patch lies in the convex hull of its Cartesian control points, so the
boxes of those points bound every sub-patch.

:func:`axis_line_crossings` finds every point where lines parallel to a coordinate axis cross the
patches: the ray-cast volume quadrature of solids needs all crossings along a line with the
direction in which the surface is crossed, not the first hit. Pieces of patches are split
(exactly, de Casteljau in homogeneous coordinates) while some line falls into their projected
box and their projection onto the plane across the lines folds (the normal's component along the
axis changes sign on the piece) or is larger than a set size and not affine (a flat face's
pieces need no split: one 2x2 linear solve gives a line's crossing with such a piece); Newton's
method from the centre of each remaining piece solves for the crossing of every line in its box.
Every loop is bounded.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import NamedTuple

import numpy as np

from bhem_hpc.geometry.bspline import bernstein

#: Newton iterations for one crossing (quadratic convergence from the centre of a small piece).
NEWTON_ITERATIONS = 30
#: Below this cosine between a ray and a piece's normal where Newton starts, the ray grazes the
#: piece (lies in its plane, for a flat one) and the piece is not searched further.
GRAZING_COSINE = 1e-9
#: Splitting levels of a patch (4^level pieces at most): bounds the search.
MAX_LEVEL = 14
#: Largest side, in a patch's local parameters, of a piece Newton starts from.
MAX_PIECE = 1.0 / 8.0
#: Samples per side of a piece where the sign of the normal's axis component is tested.
SIGN_SAMPLES = 4
#: A ray crossing a piece no larger than :data:`MAX_PIECE` at this cosine to its normal or more
#: crosses it once (to meet the ray again, the normal would have to turn by 30 degrees or more
#: within the piece, to lie across the ray); at shallower crossings the normal's sign along the
#: ray is tested on the piece.
ONE_CROSSING_COSINE = 0.5
#: Crossings closer than this (relative to the model's size) on one line, crossed the same way,
#: are one crossing found twice (a line through a seam between patches or pieces).
DUPLICATE_DISTANCE = 1e-9
#: How far outside its patch's parameter square a crossing may land and still count.
EDGE_SLACK = 1e-9


def evaluate(nets: np.ndarray, s: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One point per net with its two partial derivatives: nets ``(N, p+1, q+1, 4)``, local
    parameters ``s, t (N,)`` -> three ``(N, 3)`` arrays."""
    p, q = nets.shape[1] - 1, nets.shape[2] - 1
    bs, dbs = bernstein(s, p), bernstein(s, p, 1)
    bt, dbt = bernstein(t, q), bernstein(t, q, 1)
    # batched products, t first (numpy's einsum over three operands loops in C without BLAS: 2-4x slower)
    along = np.matmul(np.stack([bt, dbt], axis=1)[:, None], nets)  # (N, p + 1, 2, 4): the t sums and their slopes
    a = np.matmul(bs[:, None, :], along[:, :, 0])[:, 0]
    a_s = np.matmul(dbs[:, None, :], along[:, :, 0])[:, 0]
    a_t = np.matmul(bs[:, None, :], along[:, :, 1])[:, 0]
    point = a[:, :3] / a[:, 3:]
    return point, (a_s[:, :3] - point * a_s[:, 3:]) / a[:, 3:], (a_t[:, :3] - point * a_t[:, 3:]) / a[:, 3:]


def restriction_matrices(degree: int, t0: np.ndarray, t1: np.ndarray) -> np.ndarray:
    """``(N, p + 1, p + 1)`` matrices taking a degree-``p`` Bezier curve's control points to those
    of its piece on ``[t0, t1]`` (``0 <= t0 < t1 <= 1``): the Bernstein polynomials of the piece
    are those of the curve reparametrized by ``t0 + (t1 - t0) x``, a blossom evaluated at
    ``(t0, .., t0, t1, .., t1)``."""
    t0, t1 = np.asarray(t0, dtype=float), np.asarray(t1, dtype=float)
    count = len(t0)
    out = np.empty((count, degree + 1, degree + 1))
    for k in range(degree + 1):  # k-th control point of the piece: blossom at k copies of t1
        # de Casteljau with (p - k) steps at t0 and k steps at t1, applied to the identity
        points = np.broadcast_to(np.eye(degree + 1), (count, degree + 1, degree + 1))
        for step in range(degree):
            t = (t1 if step < k else t0)[:, None, None]
            points = (1.0 - t) * points[:, :-1] + t * points[:, 1:]
        out[:, k] = points[:, 0]
    return out


def _distinct_restrictions(degree: int, t0: np.ndarray, t1: np.ndarray) -> np.ndarray:
    """:func:`restriction_matrices` ``(N, p + 1, p + 1)``, each distinct interval's made once (the
    pieces of a split share few: a level of a quadtree has at most ``2^level`` per direction)."""
    intervals, inverse = np.unique(t0 + 1j * t1, return_inverse=True)
    if len(intervals) == len(t0):
        return restriction_matrices(degree, t0, t1)
    return restriction_matrices(degree, intervals.real, intervals.imag)[inverse.ravel()]


def subpatches(nets: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Nets of the local sub-rectangles ``boxes (N, 4)`` = ``(s0, s1, t0, t1)`` of ``nets (N, p+1, q+1, 4)``."""
    p, q = nets.shape[1] - 1, nets.shape[2] - 1
    along_s = _distinct_restrictions(p, boxes[:, 0], boxes[:, 1])
    along_t = _distinct_restrictions(q, boxes[:, 2], boxes[:, 3])
    rows = np.matmul(along_s, nets.reshape(len(nets), p + 1, -1)).reshape(len(nets), p + 1, q + 1, 4)
    return np.matmul(along_t[:, None], rows)  # (N, p + 1, q + 1, 4): [n, a, b, c]


def _shared_subpatches(nets: np.ndarray, patch: np.ndarray, rect: np.ndarray) -> np.ndarray:
    """:func:`subpatches` of ``nets[patch]`` on ``rect (K, 4)``, each distinct piece made once:
    neighbouring rays (a camera's pixels) keep the same pieces."""
    # at one level every piece is a square of one size: (patch, lower corner) in integers names it
    cells = np.rint(rect[:, [0, 2]] / np.maximum(rect[:, 1] - rect[:, 0], 1e-300)[:, None]).astype(np.int64)
    keys = (patch.astype(np.int64) * (1 << 20) + cells[:, 0]) * (1 << 20) + cells[:, 1]
    keys, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    if len(keys) == len(patch):
        return subpatches(nets[patch], rect)
    return subpatches(nets[patch[first]], rect[first])[inverse.ravel()]


@dataclass(frozen=True)
class LineCrossings:
    """Crossings of lines with patches, ``(K,)`` arrays sorted by line, then position.

    ``line`` indexes the lines, ``position`` is the coordinate along the axis, ``direction`` is
    ``+1`` where the surface's normal ``x_s x x_t`` points along the axis (the line leaves an
    outward-oriented solid) and ``-1`` where against it; ``patch``, ``s``, ``t`` locate the point.
    """

    line: np.ndarray
    position: np.ndarray
    direction: np.ndarray
    patch: np.ndarray
    s: np.ndarray
    t: np.ndarray


_QUARTERS = np.array([(0.0, 0.5, 0.0, 0.5), (0.5, 1.0, 0.0, 0.5), (0.0, 0.5, 0.5, 1.0), (0.5, 1.0, 0.5, 1.0)])


def _within(s: np.ndarray, t: np.ndarray, box: np.ndarray) -> np.ndarray:
    """Local parameters ``(K,)`` inside their pieces ``box (K, 4)`` up to :data:`EDGE_SLACK` (Newton
    lands a rounding error outside a piece whose edge holds the solution)."""
    return (
        (s >= box[:, 0] - EDGE_SLACK)
        & (s <= box[:, 1] + EDGE_SLACK)
        & (t >= box[:, 2] - EDGE_SLACK)
        & (t <= box[:, 3] + EDGE_SLACK)
    )


def _lines_in_box(lo: np.ndarray, hi: np.ndarray, first: np.ndarray, second: np.ndarray):
    """Index ranges of the sorted line coordinates inside each box ``lo, hi (N, 2)``: ``(N, 2)`` starts and stops."""
    start = np.stack([np.searchsorted(first, lo[:, 0], "left"), np.searchsorted(second, lo[:, 1], "left")], axis=1)
    stop = np.stack([np.searchsorted(first, hi[:, 0], "right"), np.searchsorted(second, hi[:, 1], "right")], axis=1)
    return start, stop


def _piece_boxes(nets: np.ndarray, across: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    points = nets[..., :3] / nets[..., 3:]
    flat = points[..., list(across)].reshape(len(nets), -1, 2)
    return flat.min(axis=1), flat.max(axis=1)


def grid_sums(nets: np.ndarray, along_s: np.ndarray, along_t: np.ndarray) -> np.ndarray:
    """``(N, A, B, 4)``: ``sum_ij along_s[a, i] along_t[b, j] nets[n, i, j]`` for nets ``(N, p+1, q+1,
    4)`` and rows of Bernstein values (or slopes) ``along_s (A, p+1)``, ``along_t (B, q+1)`` at fixed
    local parameters: the homogeneous points of every net on one grid, in two batched products."""
    rows = np.matmul(along_t, nets).reshape(len(nets), nets.shape[1], -1)  # the t sums: [n, i, (b, c)]
    return np.matmul(along_s, rows).reshape(len(nets), len(along_s), len(along_t), 4)


@lru_cache(maxsize=16)
def _sign_sample_bases(degree: int) -> np.ndarray:
    """``(2 G, degree + 1)``: the Bernstein polynomials at the ``G = SIGN_SAMPLES`` cell centres of
    the unit interval, then their slopes (read only)."""
    grid = (np.arange(SIGN_SAMPLES) + 0.5) / SIGN_SAMPLES
    bases = np.concatenate([bernstein(grid, degree), bernstein(grid, degree, 1)])
    bases.flags.writeable = False
    return bases


def _piece_normal_components(pieces: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Smallest and largest normal component along each piece's direction ``directions (N, 3)``
    over ``SIGN_SAMPLES^2`` points of each piece's own net ``pieces (N, p+1, q+1, 4)`` (the centres
    of a regular grid of its parameter square), each normalized by the piece's largest normal:
    where both have one sign, a line along the direction crosses the piece (small, no longer
    folded) at most once. A piece's parameters are its patch's scaled by the piece's positive
    widths, which the normalization cancels."""
    p, q = pieces.shape[1] - 1, pieces.shape[2] - 1
    count = SIGN_SAMPLES
    sums = grid_sums(pieces, _sign_sample_bases(p), _sign_sample_bases(q))  # [n, s sample, t sample, c]
    value, slope_s, slope_t = sums[:, :count, :count], sums[:, count:, :count], sums[:, :count, count:]
    point = value[..., :3] / value[..., 3:]
    x_s = (slope_s[..., :3] - point * slope_s[..., 3:]) / value[..., 3:]
    x_t = (slope_t[..., :3] - point * slope_t[..., 3:]) / value[..., 3:]
    normal = np.cross(x_s, x_t).reshape(len(pieces), -1, 3)
    size = np.linalg.norm(normal, axis=2).max(axis=1)
    component = np.einsum("nkc,nc->nk", normal, directions) / np.where(size > 0.0, size, 1.0)[:, None]
    return component.min(axis=1), component.max(axis=1)


def _split_rects(rect: np.ndarray) -> np.ndarray:
    """The four quarters ``(4 N, 4)`` of rectangles ``(N, 4)``, each parent's four in a row."""
    width = np.repeat(np.stack([rect[:, 1] - rect[:, 0], rect[:, 3] - rect[:, 2]], axis=1), 4, axis=0)
    parent, quarters = np.repeat(rect, 4, axis=0), np.tile(_QUARTERS, (len(rect), 1))
    return np.stack(
        [
            parent[:, 0] + quarters[:, 0] * width[:, 0],
            parent[:, 0] + quarters[:, 1] * width[:, 0],
            parent[:, 2] + quarters[:, 2] * width[:, 1],
            parent[:, 2] + quarters[:, 3] * width[:, 1],
        ],
        axis=1,
    )


@lru_cache(maxsize=16)
def _fractions(degree: int) -> np.ndarray:
    """``(degree + 1,)``: ``i / degree``, where an affine Bezier curve has its control points (read only)."""
    fractions = np.linspace(0.0, 1.0, degree + 1)
    fractions.flags.writeable = False
    return fractions


def _affine(pieces: np.ndarray, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """Mask ``(N,)`` of the pieces ``(N, p+1, q+1, 4)`` whose surface is an affine map of their
    parameters within ``tolerance`` [m], and their unit normals ``(N, 3)`` (zero where the map
    collapses; set where the mask holds): equal weights, and control points where the corners'
    affine map puts them (a flat face of a box or a fin, and its knot-refined pieces). A line or
    ray meets such a piece once, where its plane does (:func:`_affine_crossings`, :func:`_plane_hits`)."""
    p, q = pieces.shape[1] - 1, pieces.shape[2] - 1
    weights = pieces[..., 3]
    equal = np.abs(weights - weights[:, :1, :1]).max(axis=(1, 2), initial=0.0) <= 1e-12 * weights[:, 0, 0]
    points = pieces[..., :3] / pieces[..., 3:]
    origin, along_s, along_t = _corner_frames(pieces)
    fractions_s, fractions_t = _fractions(p)[:, None, None], _fractions(q)[:, None]
    affine = origin[:, None, None] + fractions_s * along_s[:, None, None] + fractions_t * along_t[:, None, None]
    mask = equal & (np.abs(points - affine).max(axis=(1, 2, 3), initial=0.0) <= tolerance)
    normal = np.cross(along_s[mask], along_t[mask])
    size = np.linalg.norm(normal, axis=1)
    normals = np.zeros((len(pieces), 3))
    normals[mask] = normal / np.where(size > 0.0, size, 1.0)[:, None]
    return mask, normals


def flat_share(nets: np.ndarray) -> float:
    """The share of the patches ``nets (P, p+1, q+1, 4)`` that are affine maps of their parameters
    (:func:`_affine`, to 1e-12 of their size): rays meet those in one solve."""
    points = nets[..., :3] / nets[..., 3:]
    size = max(float(np.ptp(points.reshape(-1, 3), axis=0).max()), 1e-300)
    return float(_affine(nets, 1e-12 * size)[0].mean()) if len(nets) else 1.0


def _split_until_simple(nets: np.ndarray, axis: int, first: np.ndarray, second: np.ndarray, tolerance: float):
    """Pieces ``(patch (M,), rect (M, 4), nets (M, p+1, q+1, 4), affine (M,))`` with lines in their
    boxes, each unfolded and small or affine (:func:`_affine`, the mask), or at :data:`MAX_LEVEL`;
    pieces whose projection has no area (a face along the axis) are dropped."""
    across = tuple(a for a in range(3) if a != axis)
    patch = np.arange(len(nets))
    rect = np.tile([0.0, 1.0, 0.0, 1.0], (len(nets), 1))
    kept_patch, kept_rect, kept_pieces, kept_affine = [], [], [], []
    for level in range(MAX_LEVEL + 1):
        pieces = nets if level == 0 else subpatches(nets[patch], rect)  # level 0: the whole patches
        lo, hi = _piece_boxes(pieces, across)
        start, stop = _lines_in_box(lo - tolerance, hi + tolerance, first, second)
        holds_lines = np.all(stop > start, axis=1)
        # the normals' signs only where lines pass
        patch, rect, pieces = patch[holds_lines], rect[holds_lines], pieces[holds_lines]
        # an affine piece's normal is one vector; the others' signs are sampled
        affine, normals = _affine(pieces, tolerance)
        low, high = normals[:, axis].copy(), normals[:, axis].copy()
        curved = np.flatnonzero(~affine)
        if len(curved):
            directions = np.eye(3)[np.full(len(curved), axis)]
            low[curved], high[curved] = _piece_normal_components(pieces[curved], directions)
        flat = np.maximum(np.abs(low), np.abs(high)) <= 1e-12  # projects onto a curve: no crossing of measure
        unfolded = (low > 0.0) | (high < 0.0)
        small = (rect[:, 1] - rect[:, 0] <= MAX_PIECE) & (rect[:, 3] - rect[:, 2] <= MAX_PIECE)
        simple = unfolded & (small | affine)
        done = ~flat & (simple | (level == MAX_LEVEL))
        kept_patch.append(patch[done])
        kept_rect.append(rect[done])
        kept_pieces.append(pieces[done])
        kept_affine.append(affine[done])
        split = ~flat & ~done
        if not split.any():
            break
        patch, rect = np.repeat(patch[split], 4), _split_rects(rect[split])
    return tuple(np.concatenate(kept) for kept in (kept_patch, kept_rect, kept_pieces, kept_affine))


def _candidate_pairs(pieces: np.ndarray, axis: int, first: np.ndarray, second: np.ndarray, tolerance: float):
    """``(piece (K,), line (K,))`` for every line inside each piece's projected box, ``pieces (M,
    p+1, q+1, 4)`` their nets."""
    across = tuple(a for a in range(3) if a != axis)
    lo, hi = _piece_boxes(pieces, across)
    start, stop = _lines_in_box(lo - tolerance, hi + tolerance, first, second)
    count_first, count_second = stop[:, 0] - start[:, 0], stop[:, 1] - start[:, 1]
    per_piece = count_first * count_second
    piece = np.repeat(np.arange(len(pieces)), per_piece)
    offset = np.arange(per_piece.sum()) - np.repeat(np.cumsum(per_piece) - per_piece, per_piece)
    i = start[piece, 0] + offset // count_second[piece]
    j = start[piece, 1] + offset % count_second[piece]
    return piece, i * len(second) + j


def _corner_frames(pieces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The corner ``(0, 0)`` of pieces ``(K, p+1, q+1, 4)`` and the edges from it to the corners
    ``(1, 0)`` and ``(0, 1)``, each ``(K, 3)``: an affine piece is ``origin + s along_s + t along_t``."""
    p, q = pieces.shape[1] - 1, pieces.shape[2] - 1
    corners = pieces[:, [0, p, 0], [0, 0, q]]
    corners = corners[..., :3] / corners[..., 3:]
    return corners[:, 0], corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]


def _affine_crossings(pieces: np.ndarray, rect: np.ndarray, target: np.ndarray, axis: int):
    """Where lines along ``axis`` through ``target (K, 2)`` (the other two coordinates) cross affine
    pieces ``pieces (K, p+1, q+1, 4)`` of their patches' rectangles ``rect (K, 4)``: the patches'
    local ``s, t (K,)``, the points and the derivatives along ``s, t`` ``(K, 3)``, from one 2x2 solve
    across the axis (the pieces are not flat: their normals have a component along it)."""
    origin, along_s, along_t = _corner_frames(pieces)
    across = [a for a in range(3) if a != axis]
    (a0, a1), (b0, b1) = along_s[:, across].T, along_t[:, across].T
    offset = target - origin[:, across]
    determinant = a0 * b1 - a1 * b0
    sigma = (offset[:, 0] * b1 - offset[:, 1] * b0) / determinant  # Cramer's rule
    rho = (a0 * offset[:, 1] - a1 * offset[:, 0]) / determinant
    point = origin + sigma[:, None] * along_s + rho[:, None] * along_t
    point[:, across] = target  # on the line
    width_s, width_t = rect[:, 1] - rect[:, 0], rect[:, 3] - rect[:, 2]
    return (rect[:, 0] + sigma * width_s, rect[:, 2] + rho * width_t, point, along_s / width_s[:, None],
            along_t / width_t[:, None])  # fmt: skip


def _axis_newton(nets: np.ndarray, rect: np.ndarray, target: np.ndarray, axis: int, tolerance: float) -> RayNewton:
    """:func:`_ray_newton` for lines along ``axis`` through ``target (K, 2)`` on the patches ``nets
    (K, p+1, q+1, 4)``, from the centres of their pieces ``rect (K, 4)``."""
    across = [a for a in range(3) if a != axis]
    # the line through target along the axis, as a ray from the plane through the origin
    origins = np.zeros((len(target), 3))
    origins[:, across] = target
    directions = np.zeros((len(target), 3))
    directions[:, axis] = 1.0
    # Newton's first step puts tau where the surface's linearization at (s0, t0) meets the line,
    # whatever tau starts at (the line's direction is a column of constants): any start will do
    s0, t0 = 0.5 * (rect[:, 0] + rect[:, 1]), 0.5 * (rect[:, 2] + rect[:, 3])
    return _ray_newton(nets, s0, t0, np.zeros(len(target)), origins, directions, 1e2 * tolerance)


def axis_line_crossings(nets: np.ndarray, axis: int, first: np.ndarray, second: np.ndarray) -> LineCrossings:
    """Every crossing of the lines parallel to coordinate ``axis`` with the patches ``nets``.

    Args:
        nets: ``(P, p + 1, q + 1, 4)`` homogeneous nets (positive weights).
        axis: 0, 1 or 2; the lines run along it.
        first, second: sorted coordinates ``(A,)`` and ``(B,)`` of the lines in the two other axes,
            in increasing axis order; line ``i * B + j`` passes through ``(first[i], second[j])``.

    A crossing in a piece's box (one linear solve on an affine piece, Newton's method from the
    piece's centre on the others) is accepted where it lies inside the piece (half-open
    pieces own their lower edges, so seams inside a patch count once; crossings found twice on a
    seam between patches are merged). A crossing can be missed only where a line grazes a fold
    closer than the last split can separate; the volume quadrature then finds its line unbalanced.
    """
    nets = np.asarray(nets, dtype=float)
    first, second = np.asarray(first, dtype=float), np.asarray(second, dtype=float)
    points = nets[..., :3] / nets[..., 3:]
    size = float(np.ptp(points.reshape(-1, 3), axis=0).max())
    tolerance = 1e-12 * max(size, 1e-300)
    patch, rect, pieces, affine = _split_until_simple(nets, axis, first, second, tolerance)
    if not len(patch):
        empty = np.zeros(0)
        return LineCrossings(empty.astype(int), empty, empty.astype(int), empty.astype(int), empty, empty)
    piece, line = _candidate_pairs(pieces, axis, first, second, tolerance)
    target = np.stack([first[line // len(second)], second[line % len(second)]], axis=1)
    converged = np.zeros(len(line), dtype=bool)
    crossing = [np.zeros(len(line)), np.zeros(len(line)), np.zeros((len(line), 3)), np.zeros((len(line), 3)),
                np.zeros((len(line), 3))]  # fmt: skip
    linear = np.flatnonzero(affine[piece])
    if len(linear):  # an affine piece: one linear solve
        converged[linear] = True
        solved = _affine_crossings(pieces[piece[linear]], rect[piece[linear]], target[linear], axis)
        for values, solution in zip(crossing, solved, strict=True):
            values[linear] = solution
    curved = np.flatnonzero(~affine[piece])
    if len(curved):
        newton = _axis_newton(nets[patch[piece[curved]]], rect[piece[curved]], target[curved], axis, tolerance)
        converged[curved] = newton.converged
        solved = (newton.s, newton.t, newton.point, newton.x_s, newton.x_t)
        for values, solution in zip(crossing, solved, strict=True):
            values[curved] = solution
    # a crossing may land a rounding error outside its piece when it is on the piece's edge: every
    # piece keeps crossings up to a slack beyond its edges, and the merge below counts once what two
    # pieces or two patches found
    own = converged & _within(crossing[0], crossing[1], rect[piece])
    piece, line = piece[own], line[own]
    solved_s, solved_t, point, x_s, x_t = (values[own] for values in crossing)
    s, t = np.clip(solved_s, 0.0, 1.0), np.clip(solved_t, 0.0, 1.0)
    # on the patch's edge instead of a rounding error beyond it: the point moved there to first order
    # (the second-order term is below round-off; the derivatives change by as little)
    point = point + x_s * (s - solved_s)[:, None] + x_t * (t - solved_t)[:, None]
    normal = np.cross(x_s, x_t)
    degenerate = (
        np.linalg.norm(normal, axis=1) <= 1e-12 * (np.linalg.norm(x_s, axis=1) + np.linalg.norm(x_t, axis=1)) ** 2
    )
    if degenerate.any():  # a pole or a collapsed edge: the side is that of the nearby surface
        nudge_s = s[degenerate] + 1e-6 * (0.5 - s[degenerate])
        nudge_t = t[degenerate] + 1e-6 * (0.5 - t[degenerate])
        _, n_s, n_t = evaluate(nets[patch[piece[degenerate]]], nudge_s, nudge_t)
        normal[degenerate] = np.cross(n_s, n_t)
    direction = np.sign(normal[:, axis])
    position = point[:, axis]
    order = np.lexsort((position, line))
    line, position, direction, piece, s, t = (a[order] for a in (line, position, direction, piece, s, t))
    keep = first_of_repeated(line, position, direction, DUPLICATE_DISTANCE * size) & (direction != 0.0)
    return LineCrossings(line[keep], position[keep], direction[keep].astype(int), patch[piece][keep], s[keep], t[keep])


def first_of_repeated(line: np.ndarray, position: np.ndarray, direction: np.ndarray, distance: float) -> np.ndarray:
    """Mask ``(K,)`` keeping one of each run of crossings (sorted by line, then position) on one
    line, crossed the same way, each within ``distance`` of the one before: one crossing found on
    a seam by both pieces or patches (or parts) that meet there."""
    repeated = np.zeros(len(line), dtype=bool)
    repeated[1:] = (
        (line[1:] == line[:-1]) & (direction[1:] == direction[:-1]) & (position[1:] - position[:-1] <= distance)
    )
    return ~repeated


@dataclass(frozen=True)
class RayHits:
    """First hits ``(R,)``: ray parameter ``tau`` (inf: none), ``patch`` (-1: none), local ``s, t``."""

    tau: np.ndarray
    patch: np.ndarray
    s: np.ndarray
    t: np.ndarray


def _ray_frames(directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors ``(R, 3)`` each, orthogonal to each other and to every unit direction."""
    helper = np.where(np.abs(directions[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    first = np.cross(directions, helper)
    first /= np.linalg.norm(first, axis=1)[:, None]
    return first, np.cross(directions, first)


class RayNewton(NamedTuple):
    """:func:`_ray_newton`'s result, ``(K,)`` or ``(K, 3)``: the solution ``s, t, tau``, its
    success, whether the ray grazes the surface where Newton started, and the surface's point and
    derivatives at the solution (where converged; the evaluation that found it converged)."""

    s: np.ndarray
    t: np.ndarray
    tau: np.ndarray
    converged: np.ndarray
    grazing: np.ndarray
    point: np.ndarray
    x_s: np.ndarray
    x_t: np.ndarray


def _ray_newton(nets, s, t, tau, origins, directions, tolerance, start=None) -> RayNewton:
    """Solve ``x(s, t) = origin + tau direction`` from ``(s, t, tau) (K,)``: the solution, its
    success, and whether the ray grazes the surface where Newton starts (the cosine between the
    ray and the surface normal below :data:`GRAZING_COSINE`: a ray in the plane of a flat piece).
    ``start``: :func:`evaluate` at the starting ``(s, t)``, where the caller has it."""
    converged, grazing = np.zeros(len(s), dtype=bool), np.zeros(len(s), dtype=bool)
    solution = np.zeros((3, len(s), 3))  # the point and its two derivatives where converged
    active = np.arange(len(s))
    for iteration in range(NEWTON_ITERATIONS):
        if not len(active):
            break
        if iteration == 0 and start is not None:
            point, x_s, x_t = start
        else:
            point, x_s, x_t = evaluate(nets[active], s[active], t[active])
        residual = point - origins[active] - tau[active, None] * directions[active]
        done = np.linalg.norm(residual, axis=1) <= tolerance
        converged[active[done]] = True
        solution[:, active[done]] = point[done], x_s[done], x_t[done]
        keep = ~done
        active, residual = active[keep], residual[keep]
        if not len(active):
            break
        jacobian = np.stack([x_s[keep], x_t[keep], -directions[active]], axis=2)
        determinant = np.abs(np.linalg.det(jacobian))
        if iteration == 0:  # |det| = |(x_s x x_t) . d|, d of unit length
            area = np.linalg.norm(np.cross(x_s[keep], x_t[keep]), axis=1)
            grazing[active] = determinant <= GRAZING_COSINE * area
        regular = determinant > 1e-300
        active, residual, jacobian = active[regular], residual[regular], jacobian[regular]
        step = np.linalg.solve(jacobian, residual[..., None])[..., 0]
        s[active] -= step[:, 0]
        t[active] -= step[:, 1]
        tau[active] -= step[:, 2]
        inside = (s[active] > -0.5) & (s[active] < 1.5) & (t[active] > -0.5) & (t[active] < 1.5)
        active = active[inside]
    return RayNewton(s, t, tau, converged, grazing, *solution)


#: Rays tested against every patch's bounding sphere at once (memory ~ 40 bytes x rays x patches).
SPHERE_CHUNK = 500_000


def _sphere_candidates(points, origins, directions, tau_min, tau_max, tolerance) -> tuple[np.ndarray, np.ndarray]:
    """The (ray, patch) pairs whose stretch ``tau_min < tau <= tau_max`` meets the patch's bounding
    sphere (about the mean of its control points ``points (P, n, 3)``, which hold the patch):
    ``(K,)`` ray and patch indices, ray-major."""
    centres = points.mean(axis=1)
    radii = np.linalg.norm(points - centres[:, None], axis=2).max(axis=1) + tolerance
    # the squares below expanded into matrix products (BLAS); about the centres' middle, whose
    # round-off the pad of the squared radii bounds
    middle = centres.mean(axis=0) if len(centres) else np.zeros(3)
    centres, origins = centres - middle, origins - middle
    centre_squares = (centres**2).sum(axis=1)
    rays, patches = [np.zeros(0, dtype=np.int64)], [np.zeros(0, dtype=np.int64)]  # no ray: no pair
    step = max(1, SPHERE_CHUNK // max(len(points), 1))
    for first in range(0, len(origins), step):
        last = min(first + step, len(origins))
        start, direction = origins[first:last], directions[first:last]
        start_squares = (start**2).sum(axis=1)
        along = direction @ centres.T - (start * direction).sum(axis=1)[:, None]  # (r, P): (c - o) . d
        across = start_squares[:, None] - 2.0 * (start @ centres.T) + centre_squares[None] - along**2
        pad = 16.0 * np.finfo(float).eps * (start_squares.max(initial=0.0) + centre_squares.max(initial=0.0))
        near = (
            (across <= radii**2 + pad)
            & (along + radii > tau_min[first:last, None])
            & (along - radii <= tau_max[first:last, None])
        )
        ray, patch = np.nonzero(near)
        rays.append(ray + first)
        patches.append(patch)
    return np.concatenate(rays), np.concatenate(patches)


def _frame_bounds(relative: np.ndarray, axes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The box ``(K, 3), (K, 3)`` of the points ``relative (K, n, 3)`` in the frames ``axes (3, K, 3)``
    (the coordinates along ``axes[0, k], axes[1, k], axes[2, k]``) of their rays: one batched
    product, then running minima and maxima over the ``n`` points (numpy's reductions over that
    axis take four times as long)."""
    frame = np.matmul(axes.transpose(1, 0, 2), relative.transpose(0, 2, 1))  # (K, 3, n)
    low, high = frame[..., 0].copy(), frame[..., 0].copy()
    for k in range(1, frame.shape[2]):
        np.minimum(low, frame[..., k], out=low)
        np.maximum(high, frame[..., k], out=high)
    return low, high


class _NearestHits:
    """The nearest hit so far of each of ``R`` rays: ``best (R,)`` (the stretch's end until a hit),
    and the hit's ``patch`` (-1: none) and local ``s, t``."""

    def __init__(self, tau_max: np.ndarray):
        self.best = np.asarray(tau_max, dtype=float).copy()
        self.patch = np.full(len(self.best), -1)
        self.s, self.t = np.zeros(len(self.best)), np.zeros(len(self.best))

    def keep(self, ray: np.ndarray, tau: np.ndarray, patch: np.ndarray, s: np.ndarray, t: np.ndarray) -> None:
        """Record hits ``(K,)`` within their rays' stretches (several per ray: the smallest tau wins)."""
        order = np.argsort(-tau)  # the smallest tau written last wins
        ray = ray[order]
        self.best[ray], self.patch[ray] = tau[order], patch[order]
        self.s[ray], self.t[ray] = np.clip(s[order], 0, 1), np.clip(t[order], 0, 1)


def _plane_hits(pieces: np.ndarray, origins: np.ndarray, directions: np.ndarray):
    """Where rays ``origins, directions (K, 3)`` meet the planes of affine pieces ``(K, p+1, q+1, 4)``:
    the pieces' local ``s, t`` and the rays' ``tau`` ``(K,)``, and whether a ray grazes its plane
    (the cosine to its normal below :data:`GRAZING_COSINE`; no crossing there)."""
    origin, along_s, along_t = _corner_frames(pieces)
    normal = np.cross(along_s, along_t)
    area = np.einsum("kc,kc->k", normal, normal)
    facing = np.einsum("kc,kc->k", normal, directions)
    grazing = np.abs(facing) <= GRAZING_COSINE * np.sqrt(area)
    tau = np.einsum("kc,kc->k", origin - origins, normal) / np.where(grazing, 1.0, facing)
    offset = origins + tau[:, None] * directions - origin  # = s along_s + t along_t
    s = np.einsum("kc,kc->k", np.cross(offset, along_t), normal) / np.where(area > 0.0, area, 1.0)
    t = np.einsum("kc,kc->k", np.cross(along_s, offset), normal) / np.where(area > 0.0, area, 1.0)
    return s, t, tau, grazing


def first_hits(
    nets: np.ndarray, origins: np.ndarray, directions: np.ndarray, tau_min: np.ndarray, tau_max: np.ndarray
) -> RayHits:
    """The first hit of each ray with ``tau_min < tau <= tau_max`` on the patches ``nets``.

    Args:
        nets: ``(P, p + 1, q + 1, 4)`` homogeneous nets (positive weights).
        origins, directions: ``(R, 3)`` rays, directions of unit length.
        tau_min, tau_max: ``(R,)`` the searched stretch of each ray.

    Pieces of (ray, patch) pairs are kept while the ray's two planes both cut the box of the
    piece's control points (in the ray's frame) within the stretch. A patch that is an affine map
    of its parameters (a flat face: :func:`_affine`) meets a ray where its plane does, in one
    solve. A piece no larger than :data:`MAX_PIECE` runs Newton's method from its centre, and a
    hit inside it shortens the ray's stretch; a piece is settled by the crossing Newton found
    where the ray crosses it once; other pieces split into quarters, down to :data:`MAX_LEVEL`
    levels.
    """
    nets = np.asarray(nets, dtype=float)
    origins, directions = np.asarray(origins, dtype=float), np.asarray(directions, dtype=float)
    hits = _NearestHits(tau_max)
    tau_min = np.asarray(tau_min, dtype=float)
    points = nets[..., :3] / nets[..., 3:]
    size = max(float(np.ptp(points.reshape(-1, 3), axis=0).max()), 1e-300)
    tolerance = 1e-12 * size
    # a ray passing a patch's edge within the edges' slack meets the patch (its crossing there is
    # accepted): the boxes it is tested against are that much wider. A ray through an edge (from a
    # round tower's foot through its axis, a box's corner) then hits it whatever side round-off puts it on
    across = EDGE_SLACK * size
    first_axis, second_axis = _ray_frames(directions)
    points = points.reshape(len(nets), -1, 3)
    ray, patch = _sphere_candidates(points, origins, directions, tau_min, hits.best, across)
    flat_patch = _affine(nets, tolerance)[0]
    rect = np.tile([0.0, 1.0, 0.0, 1.0], (len(ray), 1))
    for level in range(MAX_LEVEL + 1):
        if not len(ray):
            break
        piece = nets[patch] if level == 0 else _shared_subpatches(nets, patch, rect)  # level 0: the whole patches
        relative = (piece[..., :3] / piece[..., 3:]).reshape(len(ray), -1, 3) - origins[ray][:, None]
        # the control points' box in each ray's frame (across, across, along)
        frame_low, frame_high = _frame_bounds(relative, np.stack([first_axis[ray], second_axis[ray], directions[ray]]))
        cut = (
            (frame_low[:, 0] <= across)
            & (frame_high[:, 0] >= -across)
            & (frame_low[:, 1] <= across)
            & (frame_high[:, 1] >= -across)
            & (frame_high[:, 2] > tau_min[ray])
            & (frame_low[:, 2] <= hits.best[ray] + tolerance)
        )
        ray, patch, rect, piece = ray[cut], patch[cut], rect[cut], piece[cut]
        settled = np.zeros(len(ray), dtype=bool)
        if level == 0:  # a flat patch meets a ray once, where its plane does
            at = np.flatnonzero(flat_patch[patch])
            s, t, tau, grazing = _plane_hits(piece[at], origins[ray[at]], directions[ray[at]])
            inside = ~grazing & _within(s, t, rect[at]) & (tau > tau_min[ray[at]]) & (tau <= hits.best[ray[at]])
            hits.keep(ray[at[inside]], tau[inside], patch[at[inside]], s[inside], t[inside])
            settled[at] = True
        small = (rect[:, 1] - rect[:, 0] <= MAX_PIECE) & (rect[:, 3] - rect[:, 2] <= MAX_PIECE) & ~settled
        if small.any():
            at = np.flatnonzero(small)
            settled[at] = _small_piece_hits(nets, piece[at], patch[at], rect[at], ray[at], origins, directions,
                                            tau_min, hits, tolerance)  # fmt: skip
        split = ~settled & (level < MAX_LEVEL)
        ray, patch, rect = np.repeat(ray[split], 4), np.repeat(patch[split], 4), _split_rects(rect[split])
    tau = np.where(hits.patch >= 0, hits.best, np.inf)
    return RayHits(tau, hits.patch, hits.s, hits.t)


def _small_piece_hits(nets, piece, patch, rect, ray, origins, directions, tau_min, hits: _NearestHits,
                      tolerance: float) -> np.ndarray:  # fmt: skip
    """Newton's method from the centres of small pieces ``piece (K, p+1, q+1, 4)`` of the patches
    ``nets[patch]`` on their rectangles ``rect (K, 4)`` for the rays ``ray (K,)``: records the hits
    within the rays' stretches in ``hits`` and returns which pieces are settled ``(K,)``."""
    settled = np.zeros(len(ray), dtype=bool)
    s, t = 0.5 * (rect[:, 0] + rect[:, 1]), 0.5 * (rect[:, 2] + rect[:, 3])
    patch_nets = nets[patch]
    centre = evaluate(patch_nets, s, t)
    tau = np.einsum("kc,kc->k", centre[0] - origins[ray], directions[ray])
    newton = _ray_newton(patch_nets, s, t, tau, origins[ray], directions[ray], 1e2 * tolerance, centre)
    s, t, tau, converged, grazing = newton.s, newton.t, newton.tau, newton.converged, newton.grazing
    # a ray in the plane of a flat piece touches it along a line and crosses it nowhere: no hit
    # (where Newton's singular steps end on that line is round-off; a secondary ray along a box's
    # edge met the face beside it at random distances)
    found = np.flatnonzero(converged & ~grazing & _within(s, t, rect))
    inside = np.zeros(len(ray), dtype=bool)
    inside[found] = (tau[found] > tau_min[ray[found]]) & (tau[found] <= hits.best[ray[found]])
    # the crossing Newton found is a piece's only one where the ray crosses it one way only; else (a
    # ray grazing a sphere crosses one piece twice) the piece splits on, a hit found in it shortening
    # the ray's stretch. Where the ray meets the piece's surface steeply (ONE_CROSSING_COSINE) a
    # small piece's normal would have to turn that far within it.
    if len(found):
        normal = np.cross(newton.x_s[found], newton.x_t[found])
        cosine = np.abs(np.einsum("kc,kc->k", normal, directions[ray[found]])) / np.maximum(
            np.linalg.norm(normal, axis=1), 1e-300)  # fmt: skip
        steep = cosine >= ONE_CROSSING_COSINE
        settled[found[steep]] = True
        oblique = found[~steep]
        if len(oblique):
            low, high = _piece_normal_components(piece[oblique], directions[ray[oblique]])
            settled[oblique[(low > 0.0) | (high < 0.0)]] = True
    # a ray in the plane of a flat piece meets it nowhere transversally: splitting such a piece would
    # follow the ray through ever more pieces (twice as many per level)
    settled[grazing] = True
    hits.keep(ray[inside], tau[inside], patch[inside], s[inside], t[inside])
    return settled

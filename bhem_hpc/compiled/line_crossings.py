"""Every crossing of axis-parallel lines with rational Bezier patches, compiled.

A curved patch of degree 1 along one parameter (a ruled patch: cylinders, cones, extrusions and
the faces of most CAD solids) has its crossings with a line solved exactly, as the roots of one
polynomial (:mod:`~bhem_hpc.compiled.ruled_patches`).

Every other patch, and a flat parallelogram (in closed form at once), goes through the search of
:func:`bhem_hpc.geometry.rational_bezier.axis_line_crossings` (same pieces, same tests, same
Newton starts and tolerances), run depth first per patch in one compiled loop instead of level by
level in numpy calls; the crossings agree to round-off (the pieces are halved from their parents
here, restricted from the patch there)."""

from __future__ import annotations

import numpy as np
from numba import njit

from bhem_hpc.compiled.patch_kernels import (
    EDGE_SLACK,
    MAX_LEVEL,
    MAX_PIECE,
    NEWTON_ITERATIONS,
    STACK,
    affine_frame,
    cartesian_box,
    evaluate,
    model_size,
    normal_component_range,
    ray_newton,
    row_normal,
    sample_table,
    split_onto_stack,
    straight_along,
)
from bhem_hpc.compiled.ruled_patches import ruled_degree, ruled_net, ruled_solutions, ruled_work
from bhem_hpc.compiled.volume_points import merged_order
from bhem_hpc.geometry import rational_bezier as rb

DUPLICATE_DISTANCE = rb.DUPLICATE_DISTANCE
#: How far beyond its piece (in the patch's parameters) a converged crossing gets one more Newton step.
POLISH_MARGIN = 1e-6


@njit(cache=True, error_model="numpy")
def _grown(floats: np.ndarray, ints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The output arrays ``(K, 3)`` with twice the rows, the first ``K`` copied."""
    more_floats = np.empty((2 * len(floats), floats.shape[1]))
    more_ints = np.empty((2 * len(ints), ints.shape[1]), dtype=np.int64)
    more_floats[: len(floats)] = floats
    more_ints[: len(ints)] = ints
    return more_floats, more_ints


@njit(cache=True, error_model="numpy")
def _cross_axis(point: np.ndarray, axis: int) -> tuple[float, float]:
    """The component along ``axis`` of ``x_s x x_t`` (rows 1 and 2 of ``point``), and by how much the
    normal's length exceeds ``1e-12 (|x_s| + |x_t|)^2`` (not positive: a pole or a collapsed edge)."""
    nx, ny, nz = row_normal(point)
    length = np.sqrt(nx * nx + ny * ny + nz * nz)
    sides = np.sqrt(point[1, 0] ** 2 + point[1, 1] ** 2 + point[1, 2] ** 2) + np.sqrt(
        point[2, 0] ** 2 + point[2, 1] ** 2 + point[2, 2] ** 2)  # fmt: skip
    component = (nx, ny, nz)[axis]
    return component, length - 1e-12 * sides * sides


@njit(cache=True, error_model="numpy")
def _outside(rect: np.ndarray, s: float, t: float, slack: float) -> bool:
    """Whether ``(s, t)`` lies farther than ``slack`` outside ``rect`` (s0, s1, t0, t1)."""
    return not (rect[0] - slack <= s <= rect[1] + slack and rect[2] - slack <= t <= rect[3] + slack)


@njit(cache=True, error_model="numpy")
def _affine_crossing(frame: np.ndarray, rect: np.ndarray, target: tuple[float, float], axis: int, a0: int, a1: int,
                     point: np.ndarray) -> tuple[float, float]:  # fmt: skip
    """The patch's ``s, t`` where the line through ``target`` meets the affine piece ``frame``
    (corner, edge along s, edge along t) of the rectangle ``rect``; the point and the patch's
    derivatives into ``point (3, 3)`` (:func:`~bhem_hpc.geometry.rational_bezier._affine_crossings`)."""
    e0, e1 = target[0] - frame[0, a0], target[1] - frame[0, a1]
    det = frame[1, a0] * frame[2, a1] - frame[1, a1] * frame[2, a0]
    sigma = (e0 * frame[2, a1] - e1 * frame[2, a0]) / det
    rho = (frame[1, a0] * e1 - frame[1, a1] * e0) / det
    width_s, width_t = rect[1] - rect[0], rect[3] - rect[2]
    for c in range(3):
        point[0, c] = frame[0, c] + sigma * frame[1, c] + rho * frame[2, c]
        point[1, c] = frame[1, c] / width_s
        point[2, c] = frame[2, c] / width_t
    point[0, a0], point[0, a1] = target[0], target[1]
    return rect[0] + sigma * width_s, rect[2] + rho * width_t


@njit(cache=True, error_model="numpy")
def _append(net, s, t, axis, line, patch, transposed, basis, point, floats, ints, count):  # noqa: PLR0913
    """Write the crossing of ``line`` with ``net`` at ``(s, t)`` (at most a slack beyond the patch;
    ``point (3, 3)`` its point and derivatives) into row ``count`` (the caller made room) of ``floats
    (K, 3)`` (position, ``s``, ``t``) and ``ints (K, 3)`` (line, direction, patch); the new count. A
    ``transposed`` net is the patch's with ``s`` and ``t`` swapped."""
    clipped_s, clipped_t = min(max(s, 0.0), 1.0), min(max(t, 0.0), 1.0)
    # on the patch's edge instead of a rounding error beyond it, to first order
    position = point[0, axis] + point[1, axis] * (clipped_s - s) + point[2, axis] * (clipped_t - t)
    component, regular = _cross_axis(point, axis)
    if regular <= 0.0:  # a pole or a collapsed edge: the side is that of the nearby surface
        evaluate(net, clipped_s + 1e-6 * (0.5 - clipped_s), clipped_t + 1e-6 * (0.5 - clipped_t), basis, point)
        component, _ = _cross_axis(point, axis)
    if transposed:  # x_t x x_s: the patch's normal reversed
        component, clipped_s, clipped_t = -component, clipped_t, clipped_s
    floats[count, 0], floats[count, 1], floats[count, 2] = position, clipped_s, clipped_t
    ints[count, 0] = line
    ints[count, 1] = 1 if component > 0.0 else (-1 if component < 0.0 else 0)
    ints[count, 2] = patch
    return count + 1


@njit(cache=True, error_model="numpy")
def _search_ruled_patch(net, patch, transposed, axis, first, second, tolerance, work, floats, ints, count):  # noqa: PLR0913
    """Append the crossings of the lines with the ruled patch ``net (p + 1, 2, 4)`` (degree 1 along
    ``t``; :mod:`~bhem_hpc.compiled.ruled_patches`, whose scratch ``work`` holds; then the basis
    ``(4, p + 1)``, the point ``(3, 3)`` and the box's ends) to ``floats``, ``ints`` from row
    ``count`` (as :func:`_append`); the arrays and the new count. The line through ``(c0, c1)``
    across ``axis`` is where the planes ``x_a0 = c0`` and ``x_a1 = c1`` meet."""
    a0, a1 = (1, 2) if axis == 0 else ((0, 2) if axis == 1 else (0, 1))
    rows, solutions, basis, point, low, high = work[0], work[6], work[7], work[8], work[9], work[10]
    p = net.shape[0] - 1
    cartesian_box(net, low, high)
    i0 = np.searchsorted(first, low[a0] - tolerance, side="left")
    i1 = np.searchsorted(first, high[a0] + tolerance, side="right")
    j0 = np.searchsorted(second, low[a1] - tolerance, side="left")
    j1 = np.searchsorted(second, high[a1] + tolerance, side="right")
    for i in range(i0, i1):
        for r in range(p + 1):
            rows[0, r] = net[r, 0, a0] - first[i] * net[r, 0, 3]
            rows[1, r] = net[r, 1, a0] - first[i] * net[r, 1, 3]
        for j in range(j0, j1):
            for r in range(p + 1):
                rows[2, r] = net[r, 0, a1] - second[j] * net[r, 0, 3]
                rows[3, r] = net[r, 1, a1] - second[j] * net[r, 1, 3]
            found = ruled_solutions(p, work[:7])
            if count + found > len(ints):
                floats, ints = _grown(floats, ints)
            for k in range(found):
                s, t = solutions[k, 0], solutions[k, 1]
                evaluate(net, s, t, basis, point)
                count = _append(net, s, t, axis, i * len(second) + j, patch, transposed, basis, point, floats, ints,
                                count)  # fmt: skip
    return floats, ints, count


@njit(cache=True, error_model="numpy")
def _search_patch(nets, patch, axis, first, second, tolerance, tables, work, floats, ints, count):  # noqa: C901, PLR0912, PLR0913, PLR0915
    """Append the crossings of the lines with ``nets[patch]`` to ``floats (K, 3)`` (position,
    ``s``, ``t``) and ``ints (K, 3)`` (line, direction, patch) from row ``count``; the arrays (grown
    when full) and the new count."""
    a0, a1 = (1, 2) if axis == 0 else ((0, 2) if axis == 1 else (0, 1))
    net = nets[patch]
    stack, rects, levels, scratch, rows, basis, point, frame, low, high, along, origin = work
    along[:] = 0.0
    along[axis] = 1.0
    origin[:] = 0.0
    stack[0] = net
    # a direction in which the patch is straight needs no split for Newton's sake (a tower's height)
    straight_s, straight_t = straight_along(net, True), straight_along(net, False)
    rects[0, 0], rects[0, 1], rects[0, 2], rects[0, 3] = 0.0, 1.0, 0.0, 1.0
    levels[0] = 0
    top = 1
    while top > 0:
        top -= 1
        piece, rect, level = stack[top], rects[top].copy(), levels[top]
        cartesian_box(piece, low, high)
        i0 = np.searchsorted(first, low[a0] - tolerance, side="left")
        i1 = np.searchsorted(first, high[a0] + tolerance, side="right")
        j0 = np.searchsorted(second, low[a1] - tolerance, side="left")
        j1 = np.searchsorted(second, high[a1] + tolerance, side="right")
        if i1 <= i0 or j1 <= j0:
            continue
        affine = affine_frame(piece, tolerance, frame)
        large_s = rect[1] - rect[0] > MAX_PIECE and not straight_s
        large_t = rect[3] - rect[2] > MAX_PIECE and not straight_t
        small = not (large_s or large_t)
        if level > 0 and not (affine or small or level == MAX_LEVEL):
            # split whatever its normal: the sign test decides only for small or affine pieces (a
            # piece without crossings of measure, tested on its patch, is dropped in its quarters)
            top = split_onto_stack(piece, rect, level, large_s, large_t, scratch, stack, rects, levels, top)
            continue
        if affine:
            nx, ny, nz = row_normal(frame)
            size = np.sqrt(nx * nx + ny * ny + nz * nz)
            component = (nx, ny, nz)[axis] / (size if size > 0.0 else 1.0)
            smallest = largest = component
        else:
            smallest, largest = normal_component_range(piece, along, tables[0], tables[1], rows)
        if max(abs(smallest), abs(largest)) <= 1e-12:  # projects onto a curve: no crossing of measure
            continue
        unfolded = smallest > 0.0 or largest < 0.0
        if not ((unfolded and (small or affine)) or level == MAX_LEVEL):
            # a fold splits both ways; an unfolded piece only where it is large
            top = split_onto_stack(piece, rect, level, large_s or not unfolded, large_t or not unfolded, scratch, stack,
                         rects, levels, top)  # fmt: skip
            continue
        for i in range(i0, i1):
            for j in range(j0, j1):
                if affine:
                    s, t = _affine_crossing(frame, rect, (first[i], second[j]), axis, a0, a1, point)
                else:
                    origin[a0], origin[a1] = first[i], second[j]
                    centre_s, centre_t = 0.5 * (rect[0] + rect[1]), 0.5 * (rect[2] + rect[3])
                    converged, s, t, tau = ray_newton(net, centre_s, centre_t, 0.0, origin, along, 1e2 * tolerance,
                                                      NEWTON_ITERATIONS, basis, point)  # fmt: skip
                    if not converged:
                        continue
                    if _outside(rect, s, t, EDGE_SLACK) and not _outside(rect, s, t, POLISH_MARGIN):
                        # converged to the residual's tolerance just beyond the piece: a crossing on
                        # its edge where the surface's derivatives are small (near a pole) lands
                        # there, and the neighbour's search may land beyond its edge as well; one
                        # more step settles which piece holds it
                        _, s, t, _ = ray_newton(net, s, t, tau, origin, along, 0.0, 1, basis, point)
                        evaluate(net, s, t, basis, point)
                if _outside(rect, s, t, EDGE_SLACK):
                    continue
                if count == len(ints):
                    floats, ints = _grown(floats, ints)
                count = _append(net, s, t, axis, i * len(second) + j, patch, False, basis, point, floats, ints, count)
    return floats, ints, count


@njit(cache=True, error_model="numpy")
def _all_crossings(nets, axis, first, second):
    """The crossings of every patch, sorted by line then position, repeats and tangencies dropped:
    ``floats (K, 3)`` (position, s, t) and ``ints (K, 3)`` (line, direction, patch)."""
    floats, ints = raw_crossings(nets, axis, first, second)
    order = merged_order(ints[:, 0], floats[:, 0], ints[:, 1], DUPLICATE_DISTANCE * model_size(nets))
    return floats[order], ints[order]


@njit(cache=True, error_model="numpy")
def raw_crossings(nets, axis, first, second):
    """The crossings of every patch ``nets (P, p + 1, q + 1, 4)`` with the lines along ``axis``
    through ``(first[i], second[j])`` (sorted), patch by patch, a crossing on a seam once per
    side: ``floats (K, 3)`` (position, s, t) and ``ints (K, 3)`` (line ``i * len(second) + j``,
    direction, patch)."""
    size = model_size(nets)
    tolerance = 1e-12 * max(size, 1e-300)
    floats, ints = np.empty((256, 3)), np.empty((256, 3), dtype=np.int64)
    count = 0
    shape = nets.shape
    tables = (sample_table(nets.shape[1] - 1), sample_table(nets.shape[2] - 1))
    work = (np.empty((STACK, shape[1], shape[2], 4)), np.empty((STACK, 4)), np.empty(STACK, dtype=np.int64),
            np.empty((2, shape[1], shape[2], 4)), np.empty((2, tables[0].shape[1], shape[2], 4)),
            np.empty((4, max(shape[1], shape[2]))), np.empty((3, 3)), np.empty((3, 3)), np.empty(3), np.empty(3),
            np.empty(3), np.empty(3))  # fmt: skip
    # a ruled patch is solved along its direction of higher degree (its net transposed when that is t)
    p = ruled_degree(shape[1], shape[2])
    transposed = shape[2] != 2
    net, ruled_work_ = np.empty((max(p, 1) + 1, 2, 4)), ruled_work(max(p, 1)) + (work[5], work[6], work[8], work[9])
    for patch in range(shape[0]):
        # a flat parallelogram's crossings are the affine search's, in closed form at once
        if p > 0 and not affine_frame(nets[patch], tolerance, work[7]):
            ruled_net(nets[patch], transposed, net)
            floats, ints, count = _search_ruled_patch(net, patch, transposed, axis, first, second, tolerance,
                                                      ruled_work_, floats, ints, count)  # fmt: skip
        else:
            floats, ints, count = _search_patch(nets, patch, axis, first, second, tolerance, tables, work, floats,
                                                ints, count)  # fmt: skip
    return floats[:count], ints[:count]


def axis_line_crossings(nets: np.ndarray, axis: int, first: np.ndarray, second: np.ndarray) -> rb.LineCrossings:
    """:func:`bhem_hpc.geometry.rational_bezier.axis_line_crossings`, compiled: the same arguments
    (``nets (P, p + 1, q + 1, 4)``, ``axis``, sorted line coordinates ``first (A,)``, ``second (B,)``)
    and the same crossings, sorted by line, then position."""
    nets = np.ascontiguousarray(nets, dtype=float)
    first, second = np.ascontiguousarray(first, dtype=float), np.ascontiguousarray(second, dtype=float)
    if not len(nets):
        empty = np.zeros(0)
        return rb.LineCrossings(empty.astype(int), empty, empty.astype(int), empty.astype(int), empty, empty)
    floats, ints = _all_crossings(nets, int(axis), first, second)
    return rb.LineCrossings(ints[:, 0], floats[:, 0], ints[:, 1], ints[:, 2], floats[:, 1], floats[:, 2])

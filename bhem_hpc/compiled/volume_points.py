"""The ray-cast volume rule's points from the lines' crossings, compiled: the merge of crossings
found twice, the inside intervals by the nonzero winding rule and the Gauss-Legendre points on
their segments (:func:`bhem_hpc.solids.quadrature.ray_cast_quadrature` describes the rule; the merge is
:func:`~bhem_hpc.geometry.rational_bezier.first_of_repeated`'s)."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def _sorted_by_line_then_position(line: np.ndarray, position: np.ndarray) -> np.ndarray:
    """Indices ``(K,)`` sorting the crossings by line, then position, stably (as two stable sorts,
    position then line, would): a counting sort by line, then insertion sorts of each line's few
    crossings."""
    lines = line.max() + 1 if len(line) else 0
    starts = np.zeros(lines + 1, dtype=np.int64)
    for k in range(len(line)):
        starts[line[k] + 1] += 1
    for m in range(lines):
        starts[m + 1] += starts[m]
    order, filled = np.empty(len(line), dtype=np.int64), starts[:-1].copy()
    for k in range(len(line)):
        order[filled[line[k]]] = k
        filled[line[k]] += 1
    for m in range(lines):
        for k in range(starts[m] + 1, starts[m + 1]):
            this = order[k]
            at = k
            while at > starts[m] and position[order[at - 1]] > position[this]:
                order[at] = order[at - 1]
                at -= 1
            order[at] = this
    return order


@njit(cache=True, error_model="numpy")
def merged_order(line: np.ndarray, position: np.ndarray, direction: np.ndarray, duplicate: float) -> np.ndarray:
    """Indices of crossings ``(K,)`` sorted by line, then position, each run on one line crossed the
    same way within ``duplicate`` of the one before kept once (a seam's crossing found by both
    sides), tangencies (direction 0: they cross nothing) dropped after the merge."""
    order = _sorted_by_line_then_position(line, position)
    keep = np.ones(len(order), dtype=np.bool_)
    for k in range(1, len(order)):
        this, last = order[k], order[k - 1]
        keep[k] = not (line[this] == line[last] and direction[this] == direction[last]
                       and position[this] - position[last] <= duplicate)  # fmt: skip
    order = order[keep]
    return order[direction[order] != 0]


@njit(cache=True, error_model="numpy")
def merged_crossings(line: np.ndarray, position: np.ndarray, direction: np.ndarray,
                     duplicate: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The crossings ``(K,)`` in :func:`merged_order`."""
    order = merged_order(line, position, direction, duplicate)
    return line[order], position[order], direction[order]


@njit(cache=True, error_model="numpy")
def volume_points(line: np.ndarray, position: np.ndarray, direction: np.ndarray, first: np.ndarray,
                  second: np.ndarray, axis: int, spacing: float, cell_area: float, nodes: np.ndarray,
                  node_weights: np.ndarray):  # noqa: PLR0913  # fmt: skip
    """The points ``(Q, 3)`` and weights ``(Q,)`` of the rule from merged crossings ``(K,)`` (sorted
    by line, then position) of the lines ``i * len(second) + j`` through ``(first[i], second[j])``
    along ``axis``; the mask ``(lines,)`` of open lines (whose crossings do not sum to zero: they
    carry no points), and the number of lines with crossings.

    Inside is where the winding number, stepping by ``-direction`` at each crossing, is nonzero;
    each inside interval is cut into segments no longer than ``spacing``, each carrying the
    ``nodes``/``node_weights`` Gauss-Legendre rule on ``[-1, 1]`` times ``cell_area``."""
    lines = len(first) * len(second)
    total = np.zeros(lines, dtype=np.int64)
    crossed = 0
    for k in range(len(line)):
        total[line[k]] -= direction[k]
        if k == 0 or line[k] != line[k - 1]:
            crossed += 1
    open_lines = total != 0
    # the intervals first (their segments size the output)
    starts, ends, at = np.empty(len(line)), np.empty(len(line)), np.empty(len(line), dtype=np.int64)
    intervals, winding, segments = 0, 0, 0
    for k in range(len(line)):
        if open_lines[line[k]]:
            continue
        before = winding
        winding -= direction[k]
        if before == 0 and winding != 0:
            starts[intervals], at[intervals] = position[k], line[k]
        elif before != 0 and winding == 0:
            ends[intervals] = position[k]
            segments += max(1, int(np.ceil((ends[intervals] - starts[intervals]) / spacing - 1e-9)))
            intervals += 1
    order = len(nodes)
    points, weights = np.empty((segments * order, 3)), np.empty(segments * order)
    a0, a1 = (1, 2) if axis == 0 else ((0, 2) if axis == 1 else (0, 1))
    count = 0
    for interval in range(intervals):
        length = ends[interval] - starts[interval]
        pieces = max(1, int(np.ceil(length / spacing - 1e-9)))
        width = length / pieces
        across0, across1 = first[at[interval] // len(second)], second[at[interval] % len(second)]
        for piece in range(pieces):
            left = starts[interval] + piece * width
            for node in range(order):
                points[count, axis] = left + 0.5 * width * (nodes[node] + 1.0)
                points[count, a0], points[count, a1] = across0, across1
                weights[count] = 0.5 * width * node_weights[node] * cell_area
                count += 1
    return points, weights, open_lines, crossed, intervals

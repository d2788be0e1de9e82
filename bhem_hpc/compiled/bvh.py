"""A bounding volume hierarchy of boxes, compiled: which boxes a ray's stretch meets, with where it
enters each, in time logarithmic in the number of boxes (the rays of a solid's blending weights
meet a few of its hundreds of patches)."""

from __future__ import annotations

import numpy as np
from numba import njit

#: Boxes per leaf.
LEAF_SIZE = 4


@njit(cache=True, error_model="numpy")
def build(low: np.ndarray, high: np.ndarray):
    """The hierarchy of the boxes ``low, high (B, 3)``: node boxes ``(N, 3)`` twice, each node's
    first child (-1: a leaf; the second child follows it), each leaf's range into ``order (B,)``
    (start, count). Nodes split at the median of their boxes' centres along their longest side."""
    count = len(low)
    order = np.arange(count)
    centres = 0.5 * (low + high)
    capacity = max(2 * count, 1)
    node_low, node_high = np.empty((capacity, 3)), np.empty((capacity, 3))
    child, start, size = np.full(capacity, -1), np.zeros(capacity, dtype=np.int64), np.zeros(capacity, dtype=np.int64)
    pending = np.empty((capacity, 3), dtype=np.int64)  # node, first, last + 1
    pending[0] = (0, 0, count)
    top, nodes = 1, 1
    while top > 0:
        top -= 1
        node, first, last = pending[top]
        node_low[node], node_high[node] = np.inf, -np.inf
        spread_low, spread_high = np.full(3, np.inf), np.full(3, -np.inf)
        for k in range(first, last):
            box = order[k]
            for c in range(3):
                node_low[node, c] = min(node_low[node, c], low[box, c])
                node_high[node, c] = max(node_high[node, c], high[box, c])
                spread_low[c] = min(spread_low[c], centres[box, c])
                spread_high[c] = max(spread_high[c], centres[box, c])
        start[node], size[node] = first, last - first
        if last - first <= LEAF_SIZE:
            continue
        axis = np.argmax(spread_high - spread_low)
        segment = order[first:last]
        order[first:last] = segment[np.argsort(centres[segment, axis])]
        middle = (first + last) // 2
        child[node] = nodes
        pending[top] = (nodes, first, middle)
        pending[top + 1] = (nodes + 1, middle, last)
        top += 2
        nodes += 2
    return node_low[:nodes], node_high[:nodes], child[:nodes], start[:nodes], size[:nodes], order


@njit(cache=True, error_model="numpy")
def _entry(low: np.ndarray, high: np.ndarray, origin: np.ndarray, direction: np.ndarray, tau_min: float,
           tau_max: float) -> float:  # fmt: skip
    """Where the ray enters the box within ``tau_min <= tau <= tau_max`` (inf: it misses it there)."""
    enter, leave = tau_min, tau_max
    for c in range(3):
        if abs(direction[c]) < 1e-300:  # parallel to the slab: inside it or never
            if origin[c] < low[c] or origin[c] > high[c]:
                return np.inf
            continue
        a, b = (low[c] - origin[c]) / direction[c], (high[c] - origin[c]) / direction[c]
        enter, leave = max(enter, min(a, b)), min(leave, max(a, b))
        if enter > leave:
            return np.inf
    return enter


@njit(cache=True, error_model="numpy")
def candidates(hierarchy, low, high, origin, direction, tau_min, tau_max, found, entries, stack) -> int:  # noqa: PLR0913
    """The boxes ``low, high`` (the hierarchy's) the ray's stretch meets, into ``found`` sorted by
    where it enters them (``entries``); their number. ``stack`` scratch of the hierarchy's size."""
    node_low, node_high, child, start, size, order = hierarchy
    count = 0
    if _entry(node_low[0], node_high[0], origin, direction, tau_min, tau_max) == np.inf:
        return 0
    stack[0] = 0
    top = 1
    while top > 0:
        top -= 1
        node = stack[top]
        if child[node] < 0:
            for k in range(start[node], start[node] + size[node]):
                box = order[k]
                entry = _entry(low[box], high[box], origin, direction, tau_min, tau_max)
                if entry == np.inf:
                    continue
                slot = count  # insertion by entry
                while slot > 0 and entries[slot - 1] > entry:
                    entries[slot], found[slot] = entries[slot - 1], found[slot - 1]
                    slot -= 1
                entries[slot], found[slot] = entry, box
                count += 1
            continue
        for kid in (child[node], child[node] + 1):
            if _entry(node_low[kid], node_high[kid], origin, direction, tau_min, tau_max) < np.inf:
                stack[top] = kid
                top += 1
    return count

"""Broad phase: swept boxes and a uniform hash grid that pairs overlapping boxes (never all pairs)."""

from __future__ import annotations

import numpy as np


def overlapping_pairs(boxes_a: np.ndarray, boxes_b: np.ndarray, max_cells: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of overlapping axis-aligned boxes through a uniform hash grid (not all pairs).

    Args:
        boxes_a, boxes_b: ``(A, 2, 3)`` and ``(B, 2, 3)`` boxes ``[min, max]``.
        max_cells: bound on grid cells one box may cover; larger boxes are tested against all of
            ``boxes_a`` directly.

    Returns:
        ``(ia, ib)`` index arrays of every overlapping pair, sorted by ``(ib, ia)``.
    """
    boxes_a = np.asarray(boxes_a, dtype=float).reshape(-1, 2, 3)
    boxes_b = np.asarray(boxes_b, dtype=float).reshape(-1, 2, 3)
    if not len(boxes_a) or not len(boxes_b):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    # cells about as large as the typical box of the coarser set: each box covers a few cells
    extent_a = (boxes_a[:, 1] - boxes_a[:, 0]).max(axis=1)
    extent_b = (boxes_b[:, 1] - boxes_b[:, 0]).max(axis=1)
    cell = max(float(np.median(extent_a)), float(np.median(extent_b)), 1e-12)
    origin = np.minimum(boxes_a[:, 0].min(axis=0), boxes_b[:, 0].min(axis=0))

    def cells_of(boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        lo = np.floor((boxes[:, 0] - origin) / cell).astype(np.int64)
        hi = np.floor((boxes[:, 1] - origin) / cell).astype(np.int64)
        count = np.prod(hi - lo + 1, axis=1)
        small = np.flatnonzero(count <= max_cells)
        owners, keys = [], []
        span = hi - lo + 1
        for offset in np.ndindex(*np.minimum(span[small].max(axis=0), max_cells) if len(small) else (0,)):
            off = np.asarray(offset)
            ok = small[np.all(off < span[small], axis=1)]
            c = lo[ok] + off
            owners.append(ok)
            keys.append((c[:, 0] * 73856093) ^ (c[:, 1] * 19349663) ^ (c[:, 2] * 83492791))
        owner = np.concatenate(owners) if owners else np.zeros(0, np.int64)
        key = np.concatenate(keys) if keys else np.zeros(0, np.int64)
        return owner, key, np.flatnonzero(count > max_cells)

    owner_a, key_a, big_a = cells_of(boxes_a)
    owner_b, key_b, big_b = cells_of(boxes_b)
    order = np.argsort(key_a, kind="stable")
    key_a, owner_a = key_a[order], owner_a[order]
    left = np.searchsorted(key_a, key_b, side="left")
    right = np.searchsorted(key_a, key_b, side="right")
    counts = right - left
    ib = np.repeat(owner_b, counts)
    starts = np.repeat(left, counts)
    within = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    ia = owner_a[starts + within]
    extra_a = [np.repeat(big_a, len(boxes_b)), np.repeat(np.arange(len(boxes_a)), len(big_b))]
    extra_b = [np.tile(np.arange(len(boxes_b)), len(big_a)), np.tile(big_b, len(boxes_a))]
    ia = np.concatenate([ia, *extra_a])
    ib = np.concatenate([ib, *extra_b])
    pairs = np.unique(ib * len(boxes_a) + ia)  # sorted by (ib, ia)
    ib, ia = pairs // len(boxes_a), pairs % len(boxes_a)
    overlap = np.all((boxes_a[ia, 0] <= boxes_b[ib, 1]) & (boxes_b[ib, 0] <= boxes_a[ia, 1]), axis=1)
    return ia[overlap], ib[overlap]


def box_distance(boxes_a: np.ndarray, boxes_b: np.ndarray) -> np.ndarray:
    """Euclidean distances ``(N,)`` between paired boxes ``(N, 2, 3)``: a lower bound on the distance
    between anything inside them."""
    apart = np.maximum(0.0, np.maximum(boxes_a[:, 0] - boxes_b[:, 1], boxes_b[:, 0] - boxes_a[:, 1]))
    return np.linalg.norm(apart, axis=1)


def swept_boxes(start: np.ndarray, end: np.ndarray, pad: float) -> np.ndarray:
    """Boxes ``(N, 2, 3)`` around point sets ``(N, P, 3)`` (or points ``(N, 3)``) at both ends."""
    start = np.asarray(start).reshape(len(start), -1, 3)
    end = np.asarray(end).reshape(len(end), -1, 3)
    lo = np.minimum(start.min(axis=1), end.min(axis=1)) - pad
    hi = np.maximum(start.max(axis=1), end.max(axis=1)) + pad
    return np.stack([lo, hi], axis=1)

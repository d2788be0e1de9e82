"""Continuous point-patch collision detection (paper §5.2, eqs. 25-28).

Control points move linearly, ``p_ij(t) = p_ij + t w_ij``, and so does the point,
``x(t) = x0 + t xv``, for ``t in [0, dt]``. The point can touch the patch at time t only if it is
inside the patch's moving bounding box then; per axis that set is a union of half-lines solved from
linear inequalities (eq. 28), and the feasible times form a few intervals. Sub-patches (in parameter
space and in time) wait in a min-heap keyed by their earliest feasible time, so the first sub-box
that shrinks below the tolerance gives a time of impact that is never later than the true first
contact (it may be earlier by at most the tolerance's travel time).
"""

from __future__ import annotations

import heapq
import math
import warnings

import numpy as np

from bhem_hpc.collision.bezier import subpatch
from bhem_hpc.collision.ray import BoundReached

MAX_BOXES = 50_000


def _below(a: np.ndarray, b: np.ndarray, t0: float, t1: float) -> list[tuple[float, float]]:
    """Union over entries of ``{t in [t0, t1] : a + b t <= 0}`` as disjoint intervals."""
    lo_end, hi_start = -math.inf, math.inf  # union of [t0, lo_end] and [hi_start, t1]
    for ai, bi in zip(a, b, strict=True):
        if bi == 0.0:
            if ai <= 0.0:
                return [(t0, t1)]
            continue
        root = -ai / bi
        if bi > 0.0:
            lo_end = max(lo_end, root)
        else:
            hi_start = min(hi_start, root)
    out = []
    if lo_end >= t0:
        out.append((t0, min(lo_end, t1)))
    if hi_start <= t1:
        out.append((max(hi_start, t0), t1))
    if len(out) == 2 and out[0][1] >= out[1][0]:
        out = [(t0, t1)]
    return out


def _intersect(a: list[tuple[float, float]], b: list[tuple[float, float]]) -> list[tuple[float, float]]:
    out = []
    for a0, a1 in a:
        for b0, b1 in b:
            lo, hi = max(a0, b0), min(a1, b1)
            if lo <= hi:
                out.append((lo, hi))
    return sorted(out)


def feasible_times(
    net: np.ndarray, velocity: np.ndarray, x0: np.ndarray, xv: np.ndarray, t0: float, t1: float, pad: float
) -> list[tuple[float, float]]:
    """Times in ``[t0, t1]`` at which the point is inside the moving control-point box (eq. 27)."""
    p = net.reshape(-1, 3) - x0
    w = velocity.reshape(-1, 3) - xv
    times = [(t0, t1)]
    for k in range(3):
        # some p_ij,k(t) <= x_k(t) + pad  and  some p_ij,k(t) >= x_k(t) - pad
        lower = _below(p[:, k] - pad, w[:, k], t0, t1)
        upper = _below(-p[:, k] - pad, -w[:, k], t0, t1)
        times = _intersect(times, _intersect(lower, upper))
        if not times:
            return []
    return times


def point_patch_toi(
    net: np.ndarray,
    velocity: np.ndarray,
    x0: np.ndarray,
    xv: np.ndarray,
    dt: float,
    tolerance: float = 1e-9,
    max_boxes: int = MAX_BOXES,
) -> tuple[float, float, float] | None:
    """Earliest time of impact of a moving point on a moving patch in ``[0, dt]``.

    Args:
        net, velocity: ``(4, 4, 3)`` control points at t = 0 and their velocities.
        x0, xv: the point's position at t = 0 and velocity, ``(3,)``.
        dt: the time step.
        tolerance: spatial tolerance (a sub-patch smaller than this at a feasible time is a contact).
        max_boxes: bound on popped sub-boxes (a :class:`BoundReached` warning when hit).

    Returns:
        ``(t, u, v)`` of the earliest contact (local patch parameters), or None.
    """
    net = np.asarray(net, dtype=float)
    velocity = np.asarray(velocity, dtype=float)
    x0 = np.asarray(x0, dtype=float).reshape(3)
    xv = np.asarray(xv, dtype=float).reshape(3)
    if not (dt > 0 and math.isfinite(dt)):
        raise ValueError(f"dt must be a finite number > 0, got {dt!r}")
    if not (
        np.all(np.isfinite(net))
        and np.all(np.isfinite(velocity))
        and np.all(np.isfinite(x0))
        and np.all(np.isfinite(xv))
    ):
        raise ValueError("CCD input contains NaN/Inf")
    speed = float(np.abs(velocity).max() + np.abs(xv).max())
    time_tolerance = tolerance / speed if speed > 0 else dt
    heap = []
    counter = 0
    for a, b in feasible_times(net, velocity, x0, xv, 0.0, dt, tolerance):
        heap.append((a, counter, net, velocity, (0.0, 1.0, 0.0, 1.0), (a, b)))
        counter += 1
    heapq.heapify(heap)
    popped = 0
    while heap:
        t_start, _, sub, sub_velocity, (u0, u1, v0, v1), (a, b) = heapq.heappop(heap)
        popped += 1
        if popped > max_boxes:
            warnings.warn(
                f"CCD stopped after {max_boxes} sub-boxes; reporting the earliest open box", BoundReached, stacklevel=2
            )
            return t_start, 0.5 * (u0 + u1), 0.5 * (v0 + v1)
        at_start = sub + t_start * sub_velocity
        extent = float(np.linalg.norm(at_start.reshape(-1, 3).max(axis=0) - at_start.reshape(-1, 3).min(axis=0)))
        if extent <= tolerance and b - a <= time_tolerance:
            return t_start, 0.5 * (u0 + u1), 0.5 * (v0 + v1)
        if extent > tolerance:
            pieces = [(0.0, 0.5, 0.0, 0.5), (0.5, 1.0, 0.0, 0.5), (0.0, 0.5, 0.5, 1.0), (0.5, 1.0, 0.5, 1.0)]
            spans = [(a, b)]
        else:
            pieces = [(0.0, 1.0, 0.0, 1.0)]
            spans = [(a, 0.5 * (a + b)), (0.5 * (a + b), b)]
        for c0, c1, d0, d1 in pieces:
            piece = sub if (c0, c1, d0, d1) == (0.0, 1.0, 0.0, 1.0) else subpatch(sub, c0, c1, d0, d1)
            piece_velocity = sub_velocity if piece is sub else subpatch(sub_velocity, c0, c1, d0, d1)
            bounds = (u0 + c0 * (u1 - u0), u0 + c1 * (u1 - u0), v0 + d0 * (v1 - v0), v0 + d1 * (v1 - v0))
            for s0, s1 in spans:
                for f0, f1 in feasible_times(piece, piece_velocity, x0, xv, s0, s1, tolerance):
                    heapq.heappush(heap, (f0, counter, piece, piece_velocity, bounds, (f0, f1)))
                    counter += 1
    return None

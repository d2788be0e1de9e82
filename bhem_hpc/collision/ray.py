"""Static ray-patch intersection (paper §5.1), stateless functions in the style of pbrt-v4 shapes.

A ray is ``x(tau) = origin + tau * direction``, ``tau >= 0``. :func:`intersect_patch` finds the
first hit on one Bezier net: sub-patches wait in a min-heap keyed by the entry ``tau`` of their
bounding box; each popped sub-patch first tries Newton's method from its centre and, when Newton
lands inside, records the hit and discards only a small neighbourhood of it (Fig. 10b; smaller for
grazing rays, which can cross twice close together); otherwise it
splits at the midpoint (Fig. 10a). The search stops when no box can hold an earlier hit. Every loop
has an explicit bound; reaching it emits a :class:`BoundReached` warning and returns the best hit so
far. :class:`PatchBVH` is the broad phase over many patches.
"""

from __future__ import annotations

import heapq
import math
import warnings
from dataclasses import dataclass

import numpy as np

from bhem_hpc.collision.bezier import aabb, evaluate, subpatch

# Relative tolerance of a hit, in units of the patch's size.
EPSILON = 1e-12
NEWTON_ITERATIONS = 20
MAX_SUBPATCHES = 20_000
# Hits are resolved to this relative accuracy in tau: boxes that could only improve the best hit by
# less are not searched (this ends the otherwise endless refinement next to a grazing hit).
TAU_TOLERANCE = 1e-10
# Half-width, in the popped sub-patch's local parameters, of the square discarded around a
# Newton hit: small enough that no second crossing fits inside it unless the ray is tangent.
NEIGHBOURHOOD = 1e-4


class BoundReached(RuntimeWarning):
    """A search loop hit its explicit bound; the returned result may be incomplete."""


@dataclass(frozen=True)
class Hit:
    """A ray-patch intersection: ray parameter, local patch parameters in [0, 1], patch index."""

    tau: float
    u: float
    v: float
    patch: int


def _check_ray(origin: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    origin = np.asarray(origin, dtype=float).reshape(3)
    direction = np.asarray(direction, dtype=float).reshape(3)
    if not (np.all(np.isfinite(origin)) and np.all(np.isfinite(direction))):
        raise ValueError(f"ray has a non-finite origin {origin.tolist()} or direction {direction.tolist()}")
    if not np.any(direction != 0.0):
        raise ValueError("ray direction is zero")
    return origin, direction


def ray_aabb(
    origin: np.ndarray, direction: np.ndarray, lo: np.ndarray, hi: np.ndarray, t_max: float = math.inf
) -> tuple[float, float] | None:
    """Slab test: the ``tau`` interval of the ray inside ``[lo, hi]`` within ``[0, t_max]``, or None."""
    t0, t1 = 0.0, t_max
    for k in range(3):
        if direction[k] == 0.0:
            if origin[k] < lo[k] or origin[k] > hi[k]:
                return None
            continue
        inverse = 1.0 / direction[k]
        near, far = (lo[k] - origin[k]) * inverse, (hi[k] - origin[k]) * inverse
        if near > far:
            near, far = far, near
        t0, t1 = max(t0, near), min(t1, far)
        if t0 > t1:
            return None
    return t0, t1


def _bounds_entry(
    net: np.ndarray, origin: np.ndarray, direction: np.ndarray, pad: float, t_max: float
) -> tuple[float, float] | None:
    """Ray interval inside the AABB of a net intersected with its slab along the centre normal.

    The normal slab is as thin as the piece is curved (~ curvature x size^2), far thinner than an
    AABB for a tilted, nearly flat piece: it separates a grazing ray from the surface much sooner.
    """
    lo, hi = aabb(net)
    span = ray_aabb(origin, direction, lo - pad, hi + pad, t_max)
    if span is None:
        return None
    normal = np.cross(evaluate(net, 0.5, 0.5, du=1), evaluate(net, 0.5, 0.5, dv=1))
    length = np.linalg.norm(normal)
    if length == 0.0 or not np.isfinite(length):
        return span
    normal /= length
    heights = net.reshape(-1, 3) @ normal
    start, speed = origin @ normal, direction @ normal
    low, high = heights.min() - pad, heights.max() + pad
    if speed == 0.0:
        return span if low <= start <= high else None
    near, far = sorted(((low - start) / speed, (high - start) / speed))
    t0, t1 = max(span[0], near), min(span[1], far)
    return (t0, t1) if t0 <= t1 else None


def _newton(net: np.ndarray, origin: np.ndarray, direction: np.ndarray, tau: float, tol: float):
    """Solve ``x(u, v) = origin + tau direction`` from the centre; ``(u, v, tau)`` or None."""
    u = v = 0.5
    for _ in range(NEWTON_ITERATIONS):
        residual = evaluate(net, u, v) - origin - tau * direction
        if np.linalg.norm(residual) <= tol:
            return u, v, tau
        jacobian = np.column_stack([evaluate(net, u, v, du=1), evaluate(net, u, v, dv=1), -direction])
        try:
            step = np.linalg.solve(jacobian, residual)
        except np.linalg.LinAlgError:
            return None
        u, v, tau = u - step[0], v - step[1], tau - step[2]
        if not (-0.5 < u < 1.5 and -0.5 < v < 1.5):
            return None
        if abs(step[0]) + abs(step[1]) < 1e-14:  # converged as far as the conditioning allows
            residual = evaluate(net, u, v) - origin - tau * direction
            return (u, v, tau) if np.linalg.norm(residual) <= 1e3 * tol else None
    return None


def _pieces_around(u: float, v: float, delta: float) -> list[tuple[float, float, float, float]]:
    """The sub-rectangles of [0, 1]^2 around the square of half-width ``delta`` at (u, v)."""
    us = sorted({0.0, min(max(u - delta, 0.0), 1.0), min(max(u + delta, 0.0), 1.0), 1.0})
    vs = sorted({0.0, min(max(v - delta, 0.0), 1.0), min(max(v + delta, 0.0), 1.0), 1.0})
    pieces = []
    for a, b in zip(us[:-1], us[1:], strict=True):
        for c, d in zip(vs[:-1], vs[1:], strict=True):
            if a <= u <= b and c <= v <= d and b - a <= 2 * delta + 1e-15 and d - c <= 2 * delta + 1e-15:
                continue  # the excluded neighbourhood
            pieces.append((a, b, c, d))
    return pieces


def intersect_patch(
    net: np.ndarray,
    origin: np.ndarray,
    direction: np.ndarray,
    patch: int = 0,
    t_max: float = math.inf,
    epsilon: float = EPSILON,
    max_subpatches: int = MAX_SUBPATCHES,
    newton: bool = True,
) -> Hit | None:
    """First intersection of a ray with one Bezier net, or None.

    Args:
        net: ``(4, 4, 3)`` control points.
        origin, direction: the ray (direction nonzero and finite; need not be unit).
        patch: index reported in the hit.
        t_max: only hits with ``tau < t_max`` count (e.g. the best hit on other patches).
        epsilon: hit tolerance relative to the patch's bounding-box diagonal.
        max_subpatches: bound on popped sub-patches (a :class:`BoundReached` warning when hit).
        newton: False = midpoint splitting only (the paper's plain subdivision, for comparison).
    """
    origin, direction = _check_ray(origin, direction)
    lo, hi = aabb(net)
    size = float(np.linalg.norm(hi - lo))
    if size == 0.0:
        raise ValueError("degenerate patch: all control points coincide")
    tol = epsilon * size
    best: Hit | None = None
    best_tau = t_max
    entry = _bounds_entry(net, origin, direction, tol, best_tau)
    if entry is None:
        return None
    heap: list = [(entry[0], 0, net, (0.0, 1.0, 0.0, 1.0))]
    counter = 1
    popped = 0
    while heap:
        t_enter, _, sub, (u0, u1, v0, v1) = heapq.heappop(heap)
        if t_enter > best_tau - TAU_TOLERANCE * max(1.0, best_tau):
            break  # nothing left can improve the hit by more than the tolerance
        popped += 1
        if popped > max_subpatches:
            warnings.warn(f"ray-patch search stopped after {max_subpatches} sub-patches", BoundReached, stacklevel=2)
            break
        sub_lo, sub_hi = aabb(sub)
        solution = _newton(sub, origin, direction, t_enter, tol) if newton else None
        if solution is not None and 0.0 <= solution[0] <= 1.0 and 0.0 <= solution[1] <= 1.0 and solution[2] >= 0:
            su, sv, tau = solution
            if tau < best_tau:
                best_tau = tau
                best = Hit(tau, u0 + su * (u1 - u0), v0 + sv * (v1 - v0), patch)
            # Discard a neighbourhood of the hit and split the rest (Fig. 10b). A grazing ray can
            # cross twice within a distance ~ (angle to the surface) / curvature, so the discarded
            # square shrinks with that angle.
            normal = np.cross(evaluate(sub, su, sv, du=1), evaluate(sub, su, sv, dv=1))
            sine = abs(normal @ direction) / max(np.linalg.norm(normal) * np.linalg.norm(direction), 1e-300)
            pieces = _pieces_around(su, sv, NEIGHBOURHOOD * min(1.0, 10.0 * sine) ** 2)
        elif np.linalg.norm(sub_hi - sub_lo) <= tol:
            # A box below the tolerance that the ray enters: a (grazing) hit at its entry.
            if t_enter < best_tau:
                best_tau = t_enter
                best = Hit(t_enter, 0.5 * (u0 + u1), 0.5 * (v0 + v1), patch)
            continue
        else:
            pieces = [(0.0, 0.5, 0.0, 0.5), (0.5, 1.0, 0.0, 0.5), (0.0, 0.5, 0.5, 1.0), (0.5, 1.0, 0.5, 1.0)]
        for a, b, c, d in pieces:
            piece = subpatch(sub, a, b, c, d)
            hit = _bounds_entry(piece, origin, direction, tol, best_tau)
            if hit is not None:
                bounds = (u0 + a * (u1 - u0), u0 + b * (u1 - u0), v0 + c * (v1 - v0), v0 + d * (v1 - v0))
                heapq.heappush(heap, (hit[0], counter, piece, bounds))
                counter += 1
    return best


class PatchBVH:
    """Bounding-volume hierarchy over patch AABBs (median split on the longest axis).

    Args:
        nets: ``(P, 4, 4, 3)`` Bezier nets.
        leaf_size: at most this many patches per leaf.
    """

    def __init__(self, nets: np.ndarray, leaf_size: int = 4):
        self.nets = np.asarray(nets, dtype=float)
        if self.nets.ndim != 4 or self.nets.shape[1:] != (4, 4, 3) or not len(self.nets):
            raise ValueError(f"nets must have shape (P, 4, 4, 3) with P >= 1, got {self.nets.shape}")
        if not np.all(np.isfinite(self.nets)):
            raise ValueError("nets contain NaN/Inf")
        points = self.nets.reshape(len(self.nets), -1, 3)
        self.patch_lo, self.patch_hi = points.min(axis=1), points.max(axis=1)
        self.lo: list[np.ndarray] = []
        self.hi: list[np.ndarray] = []
        self.children: list[tuple[int, int]] = []
        self.leaves: list[np.ndarray | None] = []
        self._build(np.arange(len(self.nets)), leaf_size)

    def _build(self, patches: np.ndarray, leaf_size: int) -> int:
        node = len(self.lo)
        self.lo.append(self.patch_lo[patches].min(axis=0))
        self.hi.append(self.patch_hi[patches].max(axis=0))
        self.children.append((-1, -1))
        self.leaves.append(None)
        if len(patches) <= leaf_size:
            self.leaves[node] = patches
            return node
        centres = 0.5 * (self.patch_lo[patches] + self.patch_hi[patches])
        axis = int(np.argmax(self.hi[node] - self.lo[node]))
        order = patches[np.argsort(centres[:, axis], kind="stable")]
        half = len(order) // 2
        left = self._build(order[:half], leaf_size)
        right = self._build(order[half:], leaf_size)
        self.children[node] = (left, right)
        return node

    def first_hit(self, origin: np.ndarray, direction: np.ndarray, newton: bool = True) -> Hit | None:
        """First hit of one ray on any patch, visiting boxes nearest first."""
        origin, direction = _check_ray(origin, direction)
        best: Hit | None = None
        best_tau = math.inf
        root = ray_aabb(origin, direction, self.lo[0], self.hi[0])
        heap = [(root[0], 0)] if root is not None else []
        visits = 0
        while heap:
            t_enter, node = heapq.heappop(heap)
            if t_enter > best_tau:
                break
            visits += 1
            if visits > 4 * len(self.lo):  # each node is pushed at most once
                warnings.warn("BVH traversal exceeded its node bound", BoundReached, stacklevel=2)
                break
            leaf = self.leaves[node]
            if leaf is not None:
                for patch in leaf:
                    hit = intersect_patch(self.nets[patch], origin, direction, int(patch), best_tau, newton=newton)
                    if hit is not None and hit.tau < best_tau:
                        best, best_tau = hit, hit.tau
                continue
            for child in self.children[node]:
                span = ray_aabb(origin, direction, self.lo[child], self.hi[child], best_tau)
                if span is not None:
                    heapq.heappush(heap, (span[0], child))
        return best


def intersect_rays(bvh: PatchBVH, origins: np.ndarray, directions: np.ndarray, newton: bool = True) -> list[Hit | None]:
    """First hits of many rays ``(R, 3)`` on the patches of ``bvh``; None where a ray misses."""
    origins = np.asarray(origins, dtype=float).reshape(-1, 3)
    directions = np.asarray(directions, dtype=float).reshape(-1, 3)
    if origins.shape != directions.shape:
        raise ValueError(f"{len(origins)} origins but {len(directions)} directions")
    return [bvh.first_hit(o, d, newton) for o, d in zip(origins, directions, strict=True)]

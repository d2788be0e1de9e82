"""Static ray-patch intersection (paper §5.1), stateless functions in the style of pbrt-v4 shapes.

A ray is ``x(tau) = origin + tau * direction``, ``tau >= 0``. :func:`intersect_patch` finds the
first hit on one Bezier net: sub-patches wait in a min-heap keyed by the entry ``tau`` of their
bounding box; each popped sub-patch first tries Newton's method from its centre and, when Newton
lands inside, records the hit and discards only a small neighbourhood of it (Fig. 10b; smaller for
grazing rays, which can cross twice close together); otherwise it
splits at the midpoint (Fig. 10a). The search stops when no box can hold an earlier hit. Every loop
has an explicit bound; reaching it emits a :class:`BoundReached` warning and returns the best hit so
far. :class:`PatchBVH` is the broad phase over many patches. :func:`trace_rays` runs the same search
for many rays at once in numpy (vectorized BVH traversal, then rounds that test each live ray's
``BATCH`` nearest pieces together): the renderer and the benchmarks use it; :func:`intersect_patch`
is the readable one-ray version the tests compare it with.
"""

from __future__ import annotations

import heapq
import math
import warnings
from dataclasses import dataclass

import numpy as np

from bhem_hpc.collision.bezier import aabb, bounds_many, evaluate, evaluate_many, subpatch, subpatch_many

# Relative tolerance of a hit, in units of the patch's size.
EPSILON = 1e-12
NEWTON_ITERATIONS = 20
MAX_SUBPATCHES = 20_000
# Bound on rounds of the vectorized search.
MAX_ROUNDS = MAX_SUBPATCHES
# Pieces per ray tested together in one round of the vectorized search, nearest first.
BATCH = 32
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


@dataclass(frozen=True)
class RayHits:
    """First hits of ``R`` rays as arrays: ``tau, u, v (R,)`` float and ``patch (R,)`` int, where
    a missed ray has ``tau = inf`` and ``patch = -1``."""

    tau: np.ndarray
    u: np.ndarray
    v: np.ndarray
    patch: np.ndarray

    def hit(self, ray: int) -> Hit | None:
        return (
            None
            if self.patch[ray] < 0
            else Hit(float(self.tau[ray]), float(self.u[ray]), float(self.v[ray]), int(self.patch[ray]))
        )


def _check_rays(origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    origins = np.asarray(origins, dtype=float).reshape(-1, 3)
    directions = np.asarray(directions, dtype=float).reshape(-1, 3)
    if origins.shape != directions.shape:
        raise ValueError(f"{len(origins)} origins but {len(directions)} directions")
    finite = np.all(np.isfinite(origins), axis=1) & np.all(np.isfinite(directions), axis=1)
    if not finite.all():
        bad = int(np.flatnonzero(~finite)[0])
        raise ValueError(
            f"ray {bad} has a non-finite origin {origins[bad].tolist()} or direction {directions[bad].tolist()}"
        )
    zero = ~np.any(directions != 0.0, axis=1)
    if zero.any():
        raise ValueError(f"ray direction is zero (ray {int(np.flatnonzero(zero)[0])})")
    return origins, directions


def _slabs(origins: np.ndarray, directions: np.ndarray, lo: np.ndarray, hi: np.ndarray, t_max: np.ndarray):
    """Vectorized :func:`ray_aabb` over rows ``(K, 3)``: entry and exit ``(K,)``, and a hit mask."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = 1.0 / directions
        near, far = (lo - origins) * inverse, (hi - origins) * inverse
    parallel = directions == 0.0
    inside = (origins >= lo) & (origins <= hi)
    near = np.where(parallel, np.where(inside, -np.inf, np.inf), near)
    far = np.where(parallel, np.where(inside, np.inf, -np.inf), far)
    t0 = np.maximum(np.minimum(near, far).max(axis=1), 0.0)
    t1 = np.minimum(np.maximum(near, far).min(axis=1), t_max)
    return t0, t1, t0 <= t1


def _bounds_entry_many(nets, origins, directions, pad, t_max):
    """Vectorized :func:`_bounds_entry`: entry ``tau (K,)`` and a mask of the boxes the ray enters."""
    points = nets.reshape(len(nets), 16, 3)
    lo, hi = bounds_many(points)
    t0, t1, ok = _slabs(origins, directions, lo - pad[:, None], hi + pad[:, None], t_max)
    half = np.full(len(nets), 0.5)
    normal = np.cross(evaluate_many(nets, half, half, du=1), evaluate_many(nets, half, half, dv=1))
    length = np.linalg.norm(normal, axis=1)
    usable = (length > 0.0) & np.isfinite(length)
    normal = normal / np.where(usable, length, 1.0)[:, None]
    heights = np.matmul(points, normal[:, :, None])
    start, speed = np.einsum("kc,kc->k", origins, normal), np.einsum("kc,kc->k", directions, normal)
    low, high = bounds_many(heights)
    low, high = low[:, 0] - pad, high[:, 0] + pad
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b = (low - start) / speed, (high - start) / speed
    flat_ok = (low <= start) & (start <= high)
    near = np.where(speed == 0.0, np.where(flat_ok, -np.inf, np.inf), np.minimum(a, b))
    far = np.where(speed == 0.0, np.where(flat_ok, np.inf, -np.inf), np.maximum(a, b))
    near = np.where(usable, near, -np.inf)
    far = np.where(usable, far, np.inf)
    t0, t1 = np.maximum(t0, near), np.minimum(t1, far)
    return t0, ok & (t0 <= t1)


def _newton_many(nets, origins, directions, tau, tol):
    """Vectorized :func:`_newton` from each net's centre: ``(u, v, tau)`` and a success mask."""
    count = len(nets)
    u, v, tau = np.full(count, 0.5), np.full(count, 0.5), tau.copy()
    active, success = np.ones(count, dtype=bool), np.zeros(count, dtype=bool)
    for _ in range(NEWTON_ITERATIONS):
        index = np.flatnonzero(active)
        if not len(index):
            break
        n, o, d = nets[index], origins[index], directions[index]
        residual = evaluate_many(n, u[index], v[index]) - o - tau[index, None] * d
        done = np.linalg.norm(residual, axis=1) <= tol[index]
        success[index[done]] = True
        active[index[done]] = False
        keep = ~done
        index, n, o, d, residual = index[keep], n[keep], o[keep], d[keep], residual[keep]
        jacobian = np.stack(
            [evaluate_many(n, u[index], v[index], du=1), evaluate_many(n, u[index], v[index], dv=1), -d], axis=2
        )
        regular = np.abs(np.linalg.det(jacobian)) > 0.0
        active[index[~regular]] = False
        index, n, o, d, residual, jacobian = (a[regular] for a in (index, n, o, d, residual, jacobian))
        step = np.linalg.solve(jacobian, residual[..., None])[..., 0]
        u[index] -= step[:, 0]
        v[index] -= step[:, 1]
        tau[index] -= step[:, 2]
        inside = (u[index] > -0.5) & (u[index] < 1.5) & (v[index] > -0.5) & (v[index] < 1.5)
        active[index[~inside]] = False
        stalled = inside & (np.abs(step[:, 0]) + np.abs(step[:, 1]) < 1e-14)
        if stalled.any():  # converged as far as the conditioning allows
            at = index[stalled]
            residual = evaluate_many(n[stalled], u[at], v[at]) - o[stalled] - tau[at, None] * d[stalled]
            success[at] = np.linalg.norm(residual, axis=1) <= 1e3 * tol[at]
            active[at] = False
    return u, v, tau, success


_QUARTERS = np.array([(0.0, 0.5, 0.0, 0.5), (0.5, 1.0, 0.0, 0.5), (0.0, 0.5, 0.5, 1.0), (0.5, 1.0, 0.5, 1.0)])


def _pieces_around_many(u: np.ndarray, v: np.ndarray, delta: np.ndarray):
    """Vectorized :func:`_pieces_around`: ``(item (M,), a, b, c, d (M,))`` of the up to 8
    sub-rectangles of ``[0, 1]^2`` around each excluded square."""
    cuts_u = np.stack([np.zeros_like(u), np.clip(u - delta, 0, 1), np.clip(u + delta, 0, 1), np.ones_like(u)], axis=1)
    cuts_v = np.stack([np.zeros_like(v), np.clip(v - delta, 0, 1), np.clip(v + delta, 0, 1), np.ones_like(v)], axis=1)
    items, bounds = [], []
    for i in range(3):
        for j in range(3):
            if i == 1 and j == 1:
                continue  # the excluded neighbourhood
            a, b, c, d = cuts_u[:, i], cuts_u[:, i + 1], cuts_v[:, j], cuts_v[:, j + 1]
            keep = (b > a) & (d > c)
            items.append(np.flatnonzero(keep))
            bounds.append(np.stack([a, b, c, d], axis=1)[keep])
    return np.concatenate(items), np.concatenate(bounds)


def _record(best: tuple, rays: np.ndarray, tau: np.ndarray, u: np.ndarray, v: np.ndarray, patch: np.ndarray) -> None:
    """Keep, per ray, the smallest ``tau`` among the candidates and the current best."""
    best_tau, best_u, best_v, best_patch = best
    order = np.lexsort((tau, rays))
    rays, tau, u, v, patch = rays[order], tau[order], u[order], v[order], patch[order]
    first = np.ones(len(rays), dtype=bool)
    first[1:] = rays[1:] != rays[:-1]
    rays, tau, u, v, patch = rays[first], tau[first], u[first], v[first], patch[first]
    better = tau < best_tau[rays]
    rays = rays[better]
    best_tau[rays], best_u[rays], best_v[rays], best_patch[rays] = tau[better], u[better], v[better], patch[better]


def _candidate_patches(bvh: PatchBVH, origins: np.ndarray, directions: np.ndarray):
    """Broad phase for all rays at once: ``(ray, patch)`` pairs whose BVH leaf boxes the ray enters."""
    lo, hi = np.asarray(bvh.lo), np.asarray(bvh.hi)
    children = np.asarray(bvh.children)
    rays, nodes = np.arange(len(origins)), np.zeros(len(origins), dtype=int)
    pair_rays, pair_patches = [], []
    for _ in range(len(lo) + 1):  # bound: the tree's depth is below its node count
        if not len(rays):
            break
        _, _, entered = _slabs(origins[rays], directions[rays], lo[nodes], hi[nodes], np.full(len(rays), np.inf))
        rays, nodes = rays[entered], nodes[entered]
        leaf = children[nodes, 0] < 0
        for node in np.unique(nodes[leaf]):
            at = rays[leaf & (nodes == node)]
            patches = bvh.leaves[node]
            pair_rays.append(np.repeat(at, len(patches)))
            pair_patches.append(np.tile(patches, len(at)))
        inner = ~leaf
        rays = np.concatenate([rays[inner], rays[inner]])
        nodes = np.concatenate([children[nodes[inner], 0], children[nodes[inner], 1]])
    if not pair_rays:
        return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
    return np.concatenate(pair_rays), np.concatenate(pair_patches)


def _nearest_pieces(pool: dict) -> tuple[dict, dict]:
    """Best first, in batches: each ray's ``BATCH`` nearest pieces (by entry ``tau``) and the rest
    (a min-heap per ray would take one; a whole level at a time explodes along grazing rays)."""
    order = np.lexsort((pool["tau"], pool["ray"]))
    sorted_rays = pool["ray"][order]
    group_start = np.flatnonzero(np.r_[True, sorted_rays[1:] != sorted_rays[:-1]])
    rank = np.arange(len(order)) - np.repeat(group_start, np.diff(np.r_[group_start, len(order)]))
    chosen = np.zeros(len(order), dtype=bool)
    chosen[order[rank < BATCH]] = True
    return {key: value[chosen] for key, value in pool.items()}, {key: value[~chosen] for key, value in pool.items()}


def _incidence_sine(nets: np.ndarray, su: np.ndarray, sv: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """``|sin|`` of the angle between rays ``directions (k, 3)`` and the patches' tangent planes at ``(su, sv)``."""
    normal = np.cross(evaluate_many(nets, su, sv, du=1), evaluate_many(nets, su, sv, dv=1))
    return np.abs(np.einsum("kc,kc->k", normal, directions)) / np.maximum(
        np.linalg.norm(normal, axis=1) * np.linalg.norm(directions, axis=1), 1e-300
    )


def _children(work: dict, item: np.ndarray, local: np.ndarray) -> dict:
    """Sub-pieces of the pieces ``work[...][item]``, each the local rectangle ``local (k, 4)`` of its
    parent, as a pool (ray, patch, Bezier net, rectangle in the patch's parameters)."""
    parent = work["rect"][item]
    width_u, width_v = parent[:, 1] - parent[:, 0], parent[:, 3] - parent[:, 2]
    return {
        "ray": work["ray"][item],
        "patch": work["patch"][item],
        "net": subpatch_many(work["net"][item], local[:, 0], local[:, 1], local[:, 2], local[:, 3]),
        "rect": np.stack(
            [
                parent[:, 0] + local[:, 0] * width_u,
                parent[:, 0] + local[:, 1] * width_u,
                parent[:, 2] + local[:, 2] * width_v,
                parent[:, 2] + local[:, 3] * width_v,
            ],
            axis=1,
        ),
    }


def trace_rays(
    bvh: PatchBVH,
    origins: np.ndarray,
    directions: np.ndarray,
    newton: bool = True,
    epsilon: float = EPSILON,
    max_rounds: int = MAX_ROUNDS,
    max_subpatches: int = MAX_SUBPATCHES,
    chunk: int = 4096,
    tau_tolerance: float = TAU_TOLERANCE,
) -> RayHits:
    """First hits of many rays on the patches of ``bvh``, vectorized over rays and sub-patches.

    The same search as :func:`intersect_patch` (bounds entry, Newton-guided splitting with
    neighbourhood exclusion or midpoint splitting, the same tolerances), run breadth first: every
    round tests all live sub-patches of all rays at once and drops those that cannot beat their
    ray's best hit.

    Args:
        bvh: the patches and their broad phase.
        origins, directions: ``(R, 3)`` rays (directions nonzero and finite).
        newton: False = midpoint splitting only.
        epsilon: hit tolerance relative to each patch's bounding-box diagonal.
        max_rounds: bound on splitting rounds; max_subpatches: bound on sub-patches tested per ray
            (a :class:`BoundReached` warning when either is hit; the best hits so far are kept).
        chunk: rays processed together (bounds memory).
        tau_tolerance: relative accuracy of the first hit's ``tau`` (a picture needs far less than
            the default, and pays for every digit near silhouettes).
    """
    origins, directions = _check_rays(origins, directions)
    count = len(origins)
    best = (np.full(count, np.inf), np.zeros(count), np.zeros(count), np.full(count, -1))
    points = bvh.nets.reshape(len(bvh.nets), 16, 3)
    patch_tol = epsilon * np.linalg.norm(points.max(axis=1) - points.min(axis=1), axis=1)
    if np.any(patch_tol == 0.0):
        raise ValueError(f"degenerate patch {int(np.flatnonzero(patch_tol == 0.0)[0])}: all control points coincide")
    pieces_tested = np.zeros(count, dtype=np.int64)
    warned = set()

    def entered(pool: dict) -> dict:
        """The pieces whose bounds the ray enters before its best hit, with their entry ``tau``."""
        limit = best[0][pool["ray"]]
        t_enter, inside = _bounds_entry_many(
            pool["net"], origins[pool["ray"]], directions[pool["ray"]], patch_tol[pool["patch"]], limit
        )
        return {key: value[inside] for key, value in pool.items()} | {"tau": t_enter[inside]}

    for first in range(0, count, chunk):
        rays, patches = _candidate_patches(bvh, origins[first : first + chunk], directions[first : first + chunk])
        rays += first
        pool = entered(
            {
                "ray": rays,
                "patch": patches,
                "net": bvh.nets[patches],
                "rect": np.tile([0.0, 1.0, 0.0, 1.0], (len(rays), 1)),
            }
        )
        for _ in range(max_rounds):
            # nothing left in a box can improve its ray's hit by more than the tolerance
            limit = best[0][pool["ray"]]
            alive = pool["tau"] <= limit - tau_tolerance * np.maximum(1.0, np.where(np.isfinite(limit), limit, 1.0))
            pool = {key: value[alive] for key, value in pool.items()}
            if not len(pool["ray"]):
                break
            work, pool = _nearest_pieces(pool)
            np.add.at(pieces_tested, work["ray"], 1)
            over = pieces_tested[work["ray"]] > max_subpatches
            if over.any():
                warned.add("subpatches")
                work = {key: value[~over] for key, value in work.items()}
            rays, patches, nets, rect, t_enter = (work[key] for key in ("ray", "patch", "net", "rect", "tau"))
            tol, o, d = patch_tol[patches], origins[rays], directions[rays]
            accepted = np.zeros(len(rays), dtype=bool)
            if newton and len(rays):
                su, sv, tau, converged = _newton_many(nets, o, d, t_enter, tol)
                accepted = converged & (su >= 0) & (su <= 1) & (sv >= 0) & (sv <= 1) & (tau >= 0)
            span_u, span_v = rect[:, 1] - rect[:, 0], rect[:, 3] - rect[:, 2]
            new_items, new_rects = [], []
            if accepted.any():
                at = np.flatnonzero(accepted)
                _record(
                    best,
                    rays[at],
                    tau[at],
                    rect[at, 0] + su[at] * span_u[at],
                    rect[at, 2] + sv[at] * span_v[at],
                    patches[at],
                )
                # Discard a neighbourhood of each hit and split the rest (Fig. 10b); a grazing ray
                # can cross twice close together, so the discarded square shrinks with its angle.
                sine = _incidence_sine(nets[at], su[at], sv[at], d[at])
                item, pieces = _pieces_around_many(su[at], sv[at], NEIGHBOURHOOD * np.minimum(1.0, 10.0 * sine) ** 2)
                new_items.append(at[item])
                new_rects.append(pieces)
            rest = np.flatnonzero(~accepted)
            points = nets[rest].reshape(-1, 16, 3)
            lo, hi = bounds_many(points)
            tiny = np.linalg.norm(hi - lo, axis=1) <= tol[rest]
            if tiny.any():  # a box below the tolerance that the ray enters: a grazing hit at its entry
                at = rest[tiny]
                _record(
                    best,
                    rays[at],
                    t_enter[at],
                    rect[at, 0] + 0.5 * span_u[at],
                    rect[at, 2] + 0.5 * span_v[at],
                    patches[at],
                )
            at = rest[~tiny]
            new_items.append(np.repeat(at, 4))
            new_rects.append(np.tile(_QUARTERS, (len(at), 1)))
            children = entered(_children(work, np.concatenate(new_items), np.concatenate(new_rects)))
            pool = {key: np.concatenate([pool[key], children[key]]) for key in pool}
        else:
            warned.update(["rounds"] if len(pool["ray"]) else [])
    if "subpatches" in warned:
        warnings.warn(
            f"ray-patch search stopped after {max_subpatches} sub-patches for some rays", BoundReached, stacklevel=2
        )
    if "rounds" in warned:
        warnings.warn(f"ray-patch search stopped after {max_rounds} splitting rounds", BoundReached, stacklevel=2)
    return RayHits(*best)


def intersect_rays(bvh: PatchBVH, origins: np.ndarray, directions: np.ndarray, newton: bool = True) -> list[Hit | None]:
    """First hits of many rays ``(R, 3)`` on the patches of ``bvh``; None where a ray misses
    (:func:`trace_rays` as a list of :class:`Hit`)."""
    hits = trace_rays(bvh, origins, directions, newton)
    return [hits.hit(k) for k in range(len(hits.tau))]

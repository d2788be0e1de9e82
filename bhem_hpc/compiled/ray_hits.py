"""First hits of rays on rational Bezier patches, compiled: the search of
:func:`bhem_hpc.geometry.rational_bezier.first_hits` (bounding spheres, pieces kept while the ray's
two planes cut their control points' box within the searched stretch, flat patches in one plane
solve, Newton's method from the centres of small pieces, a piece settled by a steep crossing or a
normal of one sign along the ray) run ray by ray, depth first, in one compiled loop instead of
level by level over all rays in numpy calls. Each curved patch's pieces down to the size Newton
starts from are split once for all rays of a search and kept with bounding spheres and divided
control points (where they fit in :data:`TREE_BYTES`): a ray then only tests them. The nearest
hit within the stretch does not depend on the order in which pieces are searched.

Curved ruled patches (degree 1 along one parameter: cylinders, cones, discs of revolution) are
not searched: the ray is where the two planes across it meet, and its hits with such a patch are
the roots of one polynomial (:mod:`~bhem_hpc.compiled.ruled_patches`), exact where the search
stops at a tolerance (a ray tangent to a wall where it leaves it meets nothing beyond)."""

from __future__ import annotations

import numpy as np
from numba import njit

from bhem_hpc.compiled import bvh
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
    push_quarters,
    quarter_rects,
    quarters,
    ray_newton,
    row_normal,
    sample_table,
)
from bhem_hpc.compiled.ruled_patches import ruled_degree, ruled_net, ruled_solutions, ruled_work
from bhem_hpc.geometry import rational_bezier as rb

GRAZING_COSINE = rb.GRAZING_COSINE
#: A patch's parameter square (s0, s1, t0, t1).
WHOLE = np.array([0.0, 1.0, 0.0, 1.0])
#: Levels of quarters kept per curved patch for all rays of a search, down to the pieces Newton
#: starts from (MAX_PIECE wide): ``TREE_NODES`` pieces, node ``n``'s quarters at ``4 n + 1 + k``.
TREE_LEVELS = round(-np.log2(MAX_PIECE))
TREE_NODES = (4 ** (TREE_LEVELS + 1) - 1) // 3
#: Largest memory [bytes] the kept pieces of one search may take; beyond it each ray splits the
#: pieces it meets itself (the same pieces: the kept ones save the splits and the divisions).
TREE_BYTES = 64e6
ONE_CROSSING_COSINE = rb.ONE_CROSSING_COSINE


@njit(cache=True, error_model="numpy")
def _ray_frame(direction: np.ndarray, frame: np.ndarray) -> None:
    """Rows 0 and 1 of ``frame (3, 3)``: unit vectors orthogonal to each other and to the unit
    ``direction``, row 2 the direction (as :func:`~bhem_hpc.geometry.rational_bezier._ray_frames`)."""
    hx, hy, hz = (1.0, 0.0, 0.0) if abs(direction[0]) < 0.9 else (0.0, 1.0, 0.0)
    dx, dy, dz = direction[0], direction[1], direction[2]
    ax, ay, az = dy * hz - dz * hy, dz * hx - dx * hz, dx * hy - dy * hx
    length = np.sqrt(ax * ax + ay * ay + az * az)
    ax, ay, az = ax / length, ay / length, az / length
    frame[0, 0], frame[0, 1], frame[0, 2] = ax, ay, az
    frame[1, 0], frame[1, 1], frame[1, 2] = dy * az - dz * ay, dz * ax - dx * az, dx * ay - dy * ax
    frame[2, 0], frame[2, 1], frame[2, 2] = dx, dy, dz


@njit(cache=True, error_model="numpy")
def _cut(piece: np.ndarray, origin: np.ndarray, frame: np.ndarray, across: float, tau_min: float, tau_max: float,
         homogeneous: bool = True) -> bool:  # fmt: skip
    """Whether the box of ``piece``'s control points in the ray's frame (across, across, along; the
    first two widened by ``across``) meets the ray's stretch ``tau_min < tau <= tau_max``; the
    points homogeneous ``(p + 1, q + 1, 4)``, or Cartesian ``(p + 1, q + 1, 3)`` (already divided
    by their weights, as here: the same box)."""
    low0 = low1 = low2 = np.inf
    high0 = high1 = high2 = -np.inf
    for i in range(piece.shape[0]):
        for j in range(piece.shape[1]):
            w = piece[i, j, 3] if homogeneous else 1.0
            x, y, z = piece[i, j, 0] / w - origin[0], piece[i, j, 1] / w - origin[1], piece[i, j, 2] / w - origin[2]
            c0 = x * frame[0, 0] + y * frame[0, 1] + z * frame[0, 2]
            c1 = x * frame[1, 0] + y * frame[1, 1] + z * frame[1, 2]
            c2 = x * frame[2, 0] + y * frame[2, 1] + z * frame[2, 2]
            low0, high0 = min(low0, c0), max(high0, c0)
            low1, high1 = min(low1, c1), max(high1, c1)
            low2, high2 = min(low2, c2), max(high2, c2)
    return low0 <= across and high0 >= -across and low1 <= across and high1 >= -across and high2 > tau_min and (
        low2 <= tau_max)  # fmt: skip


@njit(cache=True, error_model="numpy")
def _plane_hit(frame: np.ndarray, origin: np.ndarray, direction: np.ndarray) -> tuple[float, float, float, bool]:
    """Where the ray meets the plane of the affine piece ``frame`` (corner, edge along s, edge along
    t): local ``s, t``, ``tau`` and whether it grazes the plane (:func:`~bhem_hpc.geometry.
    rational_bezier._plane_hits`)."""
    sx, sy, sz = frame[1, 0], frame[1, 1], frame[1, 2]
    tx, ty, tz = frame[2, 0], frame[2, 1], frame[2, 2]
    nx, ny, nz = row_normal(frame)
    area = nx * nx + ny * ny + nz * nz
    facing = nx * direction[0] + ny * direction[1] + nz * direction[2]
    grazing = abs(facing) <= GRAZING_COSINE * np.sqrt(area)
    ox, oy, oz = frame[0, 0] - origin[0], frame[0, 1] - origin[1], frame[0, 2] - origin[2]
    tau = (ox * nx + oy * ny + oz * nz) / (1.0 if grazing else facing)
    # the offset from the corner: s along_s + t along_t
    ex = origin[0] + tau * direction[0] - frame[0, 0]
    ey = origin[1] + tau * direction[1] - frame[0, 1]
    ez = origin[2] + tau * direction[2] - frame[0, 2]
    scale = area if area > 0.0 else 1.0
    s = ((ey * tz - ez * ty) * nx + (ez * tx - ex * tz) * ny + (ex * ty - ey * tx) * nz) / scale
    t = ((sy * ez - sz * ey) * nx + (sz * ex - sx * ez) * ny + (sx * ey - sy * ex) * nz) / scale
    return s, t, tau, grazing


@njit(cache=True, error_model="numpy")
def _small_piece(net, piece, rect, origin, direction, tau_min, best, tolerance, tables, rows, basis, point):  # noqa: PLR0913
    """Newton's method from the centre of the small ``piece`` of ``net`` on ``rect`` (s0, s1, t0,
    t1): the hit ``(tau, s, t)`` within ``tau_min < tau <= best`` (``tau = inf``: none), and whether
    the piece is settled (the ray grazes it, crosses it steeply where Newton converged, or the
    normal has one sign along the ray on it: nothing more to find in it)."""
    s0, s1, t0, t1 = rect[0], rect[1], rect[2], rect[3]
    s, t = 0.5 * (s0 + s1), 0.5 * (t0 + t1)
    evaluate(net, s, t, basis, point)
    tau = ((point[0, 0] - origin[0]) * direction[0] + (point[0, 1] - origin[1]) * direction[1]
           + (point[0, 2] - origin[2]) * direction[2])  # fmt: skip
    r0 = point[0, 0] - origin[0] - tau * direction[0]
    r1 = point[0, 1] - origin[1] - tau * direction[1]
    r2 = point[0, 2] - origin[2] - tau * direction[2]
    if np.sqrt(r0 * r0 + r1 * r1 + r2 * r2) > 1e2 * tolerance:  # not already on the ray: the start's slope
        nx, ny, nz = row_normal(point)
        facing = abs(nx * direction[0] + ny * direction[1] + nz * direction[2])
        if facing <= GRAZING_COSINE * np.sqrt(nx * nx + ny * ny + nz * nz):
            return np.inf, 0.0, 0.0, True  # a ray in the plane of a flat piece meets it nowhere transversally
    converged, s, t, tau = ray_newton(net, s, t, tau, origin, direction, 1e2 * tolerance, NEWTON_ITERATIONS,
                                      basis, point)  # fmt: skip
    if not (converged and s0 - EDGE_SLACK <= s <= s1 + EDGE_SLACK and t0 - EDGE_SLACK <= t <= t1 + EDGE_SLACK):
        return np.inf, 0.0, 0.0, False
    hit_tau, hit_s, hit_t = np.inf, 0.0, 0.0
    if tau_min < tau <= best:
        hit_tau, hit_s, hit_t = tau, min(max(s, 0.0), 1.0), min(max(t, 0.0), 1.0)
    # the crossing found is the piece's only one where the ray crosses it steeply, or where the
    # normal has one sign along the ray on the piece
    nx, ny, nz = row_normal(point)
    size = max(np.sqrt(nx * nx + ny * ny + nz * nz), 1e-300)
    cosine = abs(nx * direction[0] + ny * direction[1] + nz * direction[2]) / size
    settled = cosine >= ONE_CROSSING_COSINE
    if not settled:
        low, high = normal_component_range(piece, direction, tables[0], tables[1], rows)
        settled = low > 0.0 or high < 0.0
    return hit_tau, hit_s, hit_t, settled


@njit(cache=True, error_model="numpy")
def _search_pieces(net, start, rect, level, origin, direction, frame, tau_min, best, tolerance, across, tables, work):  # noqa: PLR0913
    """The nearest hit of the ray with the piece ``start`` of the curved patch ``net`` (on ``rect``
    (s0, s1, t0, t1), at split ``level``) within ``tau_min < tau <= best``: ``(tau, s, t)``,
    ``tau = inf`` where there is none. Pieces are split on the fly, depth first."""
    stack, rects, levels, scratch, rows, basis, point = work
    hit_tau, hit_s, hit_t = np.inf, 0.0, 0.0
    stack[0] = start
    rects[0] = rect
    levels[0] = level
    top = 1
    while top > 0:
        top -= 1
        piece, level = stack[top], levels[top]
        s0, s1, t0, t1 = rects[top, 0], rects[top, 1], rects[top, 2], rects[top, 3]
        if not _cut(piece, origin, frame, across, tau_min, best + tolerance):
            continue
        settled = False
        if s1 - s0 <= MAX_PIECE and t1 - t0 <= MAX_PIECE:
            tau, s, t, settled = _small_piece(net, piece, rects[top], origin, direction, tau_min, best, tolerance,
                                              tables, rows, basis, point)  # fmt: skip
            if np.isfinite(tau):
                best, hit_tau, hit_s, hit_t = tau, tau, s, t
        if not (settled or level == MAX_LEVEL):
            top = push_quarters(piece, rects[top], level, scratch, stack, rects, levels, top)
    return hit_tau, hit_s, hit_t


@njit(cache=True, error_model="numpy")
def _tree_layout() -> tuple[np.ndarray, np.ndarray]:
    """The kept pieces' parameter rectangles ``(TREE_NODES, 4)`` (s0, s1, t0, t1) and levels
    ``(TREE_NODES,)``, computed as :func:`_search_pieces` computes them."""
    rects, levels = np.empty((TREE_NODES, 4)), np.zeros(TREE_NODES, dtype=np.int64)
    rects[0] = WHOLE
    for node in range((TREE_NODES - 1) // 4):
        quarter_rects(rects[node], levels[node], rects, levels, 4 * node + 1)
    return rects, levels


@njit(cache=True, error_model="numpy")
def _piece_tree(nets: np.ndarray):
    """Each patch's pieces down to :data:`TREE_LEVELS`: homogeneous nets ``(P, TREE_NODES, p + 1,
    q + 1, 4)``, their Cartesian control points ``(P, TREE_NODES, p + 1, q + 1, 3)`` and bounding
    spheres ``(P, TREE_NODES, 4)`` (centre, radius) of those points."""
    count, rows, columns = nets.shape[0], nets.shape[1], nets.shape[2]
    tree = np.empty((count, TREE_NODES, rows, columns, 4))
    points = np.empty((count, TREE_NODES, rows, columns, 3))
    spheres = np.empty((count, TREE_NODES, 4))
    scratch, low, high = np.empty((2, rows, columns, 4)), np.empty(3), np.empty(3)
    for n in range(count):
        tree[n, 0] = nets[n]
        for node in range((TREE_NODES - 1) // 4):
            quarters(tree[n, node], scratch, tree[n], 4 * node + 1)
        for node in range(TREE_NODES):
            piece = tree[n, node]
            for i in range(rows):
                for j in range(columns):
                    w = piece[i, j, 3]
                    for c in range(3):
                        points[n, node, i, j, c] = piece[i, j, c] / w  # as _cut divides
            cartesian_box(piece, low, high)
            for c in range(3):
                spheres[n, node, c] = 0.5 * (low[c] + high[c])
            radius = 0.0
            for i in range(rows):
                for j in range(columns):
                    squared = 0.0
                    for c in range(3):
                        squared += (points[n, node, i, j, c] - spheres[n, node, c]) ** 2
                    radius = max(radius, np.sqrt(squared))
            spheres[n, node, 3] = radius
    return tree, points, spheres


@njit(cache=True, error_model="numpy")
def _sphere_cut(sphere: np.ndarray, origin: np.ndarray, frame: np.ndarray, across: float, tau_min: float,
                tau_max: float) -> bool:  # fmt: skip
    """Whether a piece's bounding ``sphere`` (centre, radius) may meet what :func:`_cut` tests: false
    only where the box of its control points surely misses (the radius widened for round-off)."""
    x, y, z = sphere[0] - origin[0], sphere[1] - origin[1], sphere[2] - origin[2]
    d0 = x * frame[0, 0] + y * frame[0, 1] + z * frame[0, 2]
    d1 = x * frame[1, 0] + y * frame[1, 1] + z * frame[1, 2]
    d2 = x * frame[2, 0] + y * frame[2, 1] + z * frame[2, 2]
    radius = sphere[3] * (1.0 + 1e-9) + 1e-12 * (abs(x) + abs(y) + abs(z) + abs(origin[0]) + abs(origin[1])
                                                 + abs(origin[2]))  # fmt: skip
    return (d0 - radius <= across and d0 + radius >= -across and d1 - radius <= across and d1 + radius >= -across
            and d2 + radius >= tau_min and d2 - radius <= tau_max)  # fmt: skip


@njit(cache=True, error_model="numpy")
def _search_tree(net, tree, points, spheres, layout, origin, direction, frame, tau_min, best, tolerance, across,  # noqa: PLR0913
                 tables, work, nodes):  # fmt: skip
    """:func:`_search_pieces` on the whole patch ``net`` through its kept pieces (``tree``,
    ``points``, ``spheres`` of :func:`_piece_tree`, ``layout`` of :func:`_tree_layout`), in the same
    order; below the kept levels (a piece Newton did not settle) it splits on the fly."""
    rects, levels = layout
    rows, basis, point = work[4], work[5], work[6]
    hit_tau, hit_s, hit_t = np.inf, 0.0, 0.0
    nodes[0] = 0
    top = 1
    while top > 0:
        top -= 1
        node = nodes[top]
        limit = best + tolerance
        if not (_sphere_cut(spheres[node], origin, frame, across, tau_min, limit)
                and _cut(points[node], origin, frame, across, tau_min, limit, False)):  # fmt: skip
            continue
        if levels[node] < TREE_LEVELS:
            for k in range(4):  # popped last first, as the quarters on the splitting search's stack
                nodes[top + k] = 4 * node + 1 + k
            top += 4
            continue
        tau, s, t, settled = _small_piece(net, tree[node], rects[node], origin, direction, tau_min, best, tolerance,
                                          tables, rows, basis, point)  # fmt: skip
        if np.isfinite(tau):
            best, hit_tau, hit_s, hit_t = tau, tau, s, t
        if not settled and levels[node] < MAX_LEVEL:
            # the splitting search from this piece (it runs Newton on it once more, to the same end)
            tau, s, t = _search_pieces(net, tree[node], rects[node], levels[node], origin, direction, frame, tau_min,
                                       best, tolerance, across, tables, work)  # fmt: skip
            if np.isfinite(tau):
                best, hit_tau, hit_s, hit_t = tau, tau, s, t
    return hit_tau, hit_s, hit_t


@njit(cache=True, error_model="numpy")
def _ruled_hit(net, origin, direction, frame, tau_min, best, work) -> tuple[float, float, float]:  # noqa: PLR0913
    """The nearest hit ``(tau, s, t)`` within ``tau_min < tau <= best`` (``tau = inf``: none) of the
    ray with the ruled patch ``net (p + 1, 2, 4)`` (degree 1 along ``t``), the ray being where the
    planes across it (rows 0 and 1 of its ``frame``) meet (:mod:`~bhem_hpc.compiled.ruled_patches`;
    ``work``: its scratch, then the basis ``(4, p + 1)`` and the point ``(3, 3)``)."""
    rows, solutions, basis, point = work[0], work[6], work[7], work[8]
    p = net.shape[0] - 1
    for r in range(p + 1):
        for j in range(2):
            w = net[r, j, 3]
            x, y, z = net[r, j, 0] - origin[0] * w, net[r, j, 1] - origin[1] * w, net[r, j, 2] - origin[2] * w
            rows[j, r] = frame[0, 0] * x + frame[0, 1] * y + frame[0, 2] * z
            rows[2 + j, r] = frame[1, 0] * x + frame[1, 1] * y + frame[1, 2] * z
    hit_tau, hit_s, hit_t = np.inf, 0.0, 0.0
    for k in range(ruled_solutions(p, work[:7])):
        s, t = solutions[k, 0], solutions[k, 1]
        evaluate(net, s, t, basis, point)
        tau = ((point[0, 0] - origin[0]) * direction[0] + (point[0, 1] - origin[1]) * direction[1]
               + (point[0, 2] - origin[2]) * direction[2])  # fmt: skip
        if tau_min < tau <= best:
            best, hit_tau, hit_s, hit_t = tau, tau, min(max(s, 0.0), 1.0), min(max(t, 0.0), 1.0)
    return hit_tau, hit_s, hit_t


@njit(cache=True, error_model="numpy")
def _patch_boxes(nets: np.ndarray, pad: float) -> tuple[np.ndarray, np.ndarray]:
    """Boxes ``(P, 3), (P, 3)`` of the patches' control points (which hold them), widened by ``pad``."""
    low, high = np.empty((len(nets), 3)), np.empty((len(nets), 3))
    for n in range(len(nets)):
        cartesian_box(nets[n], low[n], high[n])
    return low - pad, high + pad


@njit(cache=True, error_model="numpy")
def _first_hits(nets, origins, directions, tau_min, tau_max, tree_bytes):  # noqa: C901, PLR0912, PLR0915
    """``tau (R,)`` (inf: no hit), ``patch (R,)`` (-1), ``s, t (R,)`` of each ray's first hit."""
    count, rays = nets.shape[0], origins.shape[0]
    size = max(model_size(nets), 1e-300)
    tolerance, across = 1e-12 * size, EDGE_SLACK * size
    shape = nets.shape
    tables = (sample_table(shape[1] - 1), sample_table(shape[2] - 1))
    work = (np.empty((STACK, shape[1], shape[2], 4)), np.empty((STACK, 4)), np.empty(STACK, dtype=np.int64),
            np.empty((2, shape[1], shape[2], 4)), np.empty((2, tables[0].shape[1], shape[2], 4)),
            np.empty((4, max(shape[1], shape[2]))), np.empty((3, 3)))  # fmt: skip
    low, high = _patch_boxes(nets, across + tolerance)
    hierarchy = bvh.build(low, high)
    stack = np.empty(len(hierarchy[0]), dtype=np.int64)
    # flat patches: their planes (corner, edges), met in one solve
    flat, planes = np.zeros(count, dtype=np.bool_), np.empty((count, 3, 3))
    for n in range(count):
        flat[n] = affine_frame(nets[n], tolerance, planes[n])
    hit_tau, hit_patch = np.full(rays, np.inf), np.full(rays, -1, dtype=np.int64)
    hit_s, hit_t = np.zeros(rays), np.zeros(rays)
    frame = np.empty((3, 3))
    candidates, entries = np.empty(count, dtype=np.int64), np.empty(count)
    # ruled patches are solved exactly (along their direction of higher degree); the other curved
    # patches' pieces are kept, where they fit
    p = ruled_degree(shape[1], shape[2])
    transposed = shape[2] != 2
    ruled_nets = np.empty((count if p > 0 else 0, max(p, 1) + 1, 2, 4))
    for n in range(len(ruled_nets)):
        ruled_net(nets[n], transposed, ruled_nets[n])
    ruled_scratch = ruled_work(max(p, 1)) + (work[5], work[6])
    curved = np.flatnonzero(~flat) if p == 0 else np.zeros(0, dtype=np.int64)
    kept = len(curved) * TREE_NODES * 8 * (7 * shape[1] * shape[2] + 4) <= tree_bytes
    tree, points, spheres = _piece_tree(nets[curved] if kept else nets[:0])
    kept_index = np.full(count, -1)
    kept_index[curved] = np.arange(len(curved))
    layout, nodes = _tree_layout(), np.empty(3 * TREE_LEVELS + 1, dtype=np.int64)
    for ray in range(rays):
        origin, direction = origins[ray], directions[ray]
        _ray_frame(direction, frame)
        best = tau_max[ray]
        # the patches whose boxes the stretch meets, nearest entry first (a near hit prunes the rest)
        found = bvh.candidates(hierarchy, low, high, origin, direction, tau_min[ray], best, candidates, entries, stack)
        for k in range(found):
            if entries[k] > best:
                break
            n = candidates[k]
            if not _cut(nets[n], origin, frame, across, tau_min[ray], best + tolerance):
                continue
            if flat[n]:  # a flat patch meets a ray once, where its plane does
                s, t, tau, grazing = _plane_hit(planes[n], origin, direction)
                if grazing or not (-EDGE_SLACK <= s <= 1.0 + EDGE_SLACK and -EDGE_SLACK <= t <= 1.0 + EDGE_SLACK):
                    continue
                s, t = min(max(s, 0.0), 1.0), min(max(t, 0.0), 1.0)
                if not tau_min[ray] < tau <= best:
                    continue
            elif p > 0:
                tau, s, t = _ruled_hit(ruled_nets[n], origin, direction, frame, tau_min[ray], best, ruled_scratch)
                s, t = (t, s) if transposed else (s, t)
            elif kept:
                m = kept_index[n]
                tau, s, t = _search_tree(nets[n], tree[m], points[m], spheres[m], layout, origin, direction, frame,
                                         tau_min[ray], best, tolerance, across, tables, work, nodes)  # fmt: skip
            else:
                tau, s, t = _search_pieces(nets[n], nets[n], WHOLE, 0, origin, direction, frame, tau_min[ray], best,
                                           tolerance, across, tables, work)  # fmt: skip
            if tau < best or (tau == best and hit_patch[ray] < 0 and np.isfinite(tau)):
                best, hit_tau[ray], hit_patch[ray], hit_s[ray], hit_t[ray] = tau, tau, n, s, t
    return hit_tau, hit_patch, hit_s, hit_t


def first_hits(nets: np.ndarray, origins: np.ndarray, directions: np.ndarray, tau_min: np.ndarray,
               tau_max: np.ndarray, tree_bytes: float = TREE_BYTES) -> rb.RayHits:  # fmt: skip
    """:func:`bhem_hpc.geometry.rational_bezier.first_hits`, compiled: the first hit of each ray
    ``origins, directions (R, 3)`` (unit directions) with ``tau_min < tau <= tau_max`` ``(R,)`` on
    the patches ``nets (P, p + 1, q + 1, 4)``; the curved patches' pieces are kept for all rays
    where they take at most ``tree_bytes``."""
    nets = np.ascontiguousarray(nets, dtype=float)
    origins, directions = np.ascontiguousarray(origins, dtype=float), np.ascontiguousarray(directions, dtype=float)
    tau_min = np.ascontiguousarray(np.broadcast_to(tau_min, len(origins)), dtype=float)
    tau_max = np.ascontiguousarray(np.broadcast_to(tau_max, len(origins)), dtype=float)
    if not len(nets) or not len(origins):
        return rb.RayHits(np.full(len(origins), np.inf), np.full(len(origins), -1), np.zeros(len(origins)),
                          np.zeros(len(origins)))  # fmt: skip
    tau, patch, s, t = _first_hits(nets, origins, directions, tau_min, tau_max, tree_bytes)
    return rb.RayHits(tau, patch, s, t)

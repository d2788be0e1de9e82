"""Closest points of moving points on moving Bezier patches, and point-patch contacts over a step."""

from __future__ import annotations

import warnings

import numpy as np

from bhem_hpc.collision.bezier import _bernstein, evaluate_many
from bhem_hpc.collision.ccd import point_patch_toi
from bhem_hpc.collision.ray import BoundReached

#: Local-parameter slack when deciding that a projected foot point lies inside a patch.
INSIDE_EPS = 1e-9
#: Newton iterations of the closest-point projection, its starting lattice (per side) and the
#: halvings of a step that would increase the distance.
PROJECTION_ITERATIONS = 12
#: Point-patch candidate pairs tested directly, without the hash grid, up to this count.
BRUTE_FORCE_PAIRS = 20_000
#: A projection has settled when its distance falls by less than this times the patch's size.
PROJECTION_TOLERANCE = 1e-12
START_GRID = 7
LINE_SEARCH_HALVINGS = 4


def control_points(nets: np.ndarray) -> np.ndarray:
    """The Euclidean control points ``(..., 4, 4, 3)`` of polynomial nets ``(..., 4, 4, 3)`` or of
    homogeneous ones ``(..., 4, 4, 4)`` (``(w x, w y, w z, w)``, positive weights): a patch lies in
    their convex hull either way."""
    return nets if nets.shape[-1] == 3 else nets[..., :3] / nets[..., 3:]


def evaluate_points(nets: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """One point per net: polynomial ``(N, 4, 4, 3)`` or homogeneous ``(N, 4, 4, 4)`` nets at
    ``u, v (N,)`` -> ``(N, 3)``."""
    point = evaluate_many(nets, u, v)
    return point if nets.shape[-1] == 3 else point[:, :3] / point[:, 3:]


def _derivatives(nets: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Points and partial derivatives up to second order of nets ``(N, 4, 4, C)`` at ``u, v (N,)``:
    ``(N, 3, 3, 3)`` indexed ``[order in u, order in v, xyz]`` (orders above 2 in total are unused).
    ``C = 3``: polynomial nets; ``C = 4``: homogeneous ones, differentiated by the quotient rule."""
    n, c = len(nets), nets.shape[-1]
    along_u = np.stack([_bernstein(u, k) for k in range(3)], axis=1)  # (N, 3, 4)
    along_v = np.stack([_bernstein(v, k) for k in range(3)], axis=1)
    partial = np.matmul(along_u, nets.reshape(n, 4, 4 * c)).reshape(-1, 3, 4, c)  # [n, order u, j, component]
    h = np.matmul(along_v[:, None], partial)  # [n, order u, order v, component]
    if c == 3:
        return h
    # x = A / W; differentiate A = W x: A_u = W_u x + W x_u, A_uv = W_uv x + W_u x_v + W_v x_u + W x_uv
    a, w = h[..., :3], h[..., 3:]
    out = np.zeros((n, 3, 3, 3))
    x = out[:, 0, 0] = a[:, 0, 0] / w[:, 0, 0]
    x_u = out[:, 1, 0] = (a[:, 1, 0] - w[:, 1, 0] * x) / w[:, 0, 0]
    x_v = out[:, 0, 1] = (a[:, 0, 1] - w[:, 0, 1] * x) / w[:, 0, 0]
    out[:, 2, 0] = (a[:, 2, 0] - w[:, 2, 0] * x - 2.0 * w[:, 1, 0] * x_u) / w[:, 0, 0]
    out[:, 0, 2] = (a[:, 0, 2] - w[:, 0, 2] * x - 2.0 * w[:, 0, 1] * x_v) / w[:, 0, 0]
    out[:, 1, 1] = (a[:, 1, 1] - w[:, 1, 1] * x - w[:, 1, 0] * x_v - w[:, 0, 1] * x_u) / w[:, 0, 0]
    return out


def project_to_patches(nets: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Closest points of ``points (N, 3)`` on Bezier patches ``nets (N, 4, 4, 3)`` (one each), or on
    rational ones given by homogeneous nets ``(N, 4, 4, 4)``.

    Newton on the first-order conditions from the nearest of ``START_GRID^2`` samples, at most
    ``PROJECTION_ITERATIONS`` iterations (each projection stops once its distance falls by less than
    ``PROJECTION_TOLERANCE`` times the patch's size), clamped to the patch (Gauss-Newton where the
    full Hessian is not positive), each step halved until the distance does not grow. The line
    search matters where a patch wraps around the point (cloth on a ball, seen from the ball's
    centre): the distance is then nearly constant over the patch, its Hessian nearly singular, and
    full Newton steps jump between the patch's corners.

    Returns:
        ``(uv (N, 2), foot (N, 3), unit normal (N, 3), inside (N,))``; ``inside`` is False where the
        closest point lies on the patch boundary (the neighbouring patch owns that contact).
    """
    n = len(points)
    if n == 0:
        return np.zeros((0, 2)), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, bool)
    grid = np.linspace(0.0, 1.0, START_GRID)
    gu, gv = np.meshgrid(grid, grid, indexing="ij")
    basis = np.einsum("si,sj->sij", _bernstein(gu.ravel()), _bernstein(gv.ravel())).reshape(-1, 16)
    samples = control_points(basis @ nets.reshape(n, 16, nets.shape[-1]))  # (N, START_GRID^2, 3)
    nearest = np.argmin(((samples - points[:, None]) ** 2).sum(-1), axis=1)
    u, v = gu.ravel()[nearest], gv.ravel()[nearest]
    distance = ((evaluate_points(nets, u, v) - points) ** 2).sum(1)
    active = np.arange(n)  # the projections still iterating
    tolerance = PROJECTION_TOLERANCE * np.linalg.norm(np.ptp(control_points(nets).reshape(n, 16, 3), axis=1), axis=1)
    for _ in range(PROJECTION_ITERATIONS):
        if not len(active):
            break
        net, point = nets[active], points[active]
        d = _derivatives(net, u[active], v[active])
        r, su, sv, suu, svv, suv = d[:, 0, 0] - point, d[:, 1, 0], d[:, 0, 1], d[:, 2, 0], d[:, 0, 2], d[:, 1, 1]
        g1, g2 = (r * su).sum(1), (r * sv).sum(1)
        a11, a12, a22 = (su * su).sum(1), (su * sv).sum(1), (sv * sv).sum(1)
        h11, h12, h22 = a11 + (r * suu).sum(1), a12 + (r * suv).sum(1), a22 + (r * svv).sum(1)
        full = (h11 > 0) & (h11 * h22 - h12 * h12 > 0)
        h11, h12, h22 = np.where(full, h11, a11), np.where(full, h12, a12), np.where(full, h22, a22)
        det = h11 * h22 - h12 * h12
        det = np.where(np.abs(det) > 1e-300, det, 1e-300)
        du, dv = -(h22 * g1 - h12 * g2) / det, -(h11 * g2 - h12 * g1) / det
        # at most half a patch, scaled as a whole: clipping each component turns the step and it
        # may then increase the distance at every length the line search tries
        scale = np.minimum(1.0, 0.5 / np.maximum(np.maximum(np.abs(du), np.abs(dv)), 1e-300))
        du, dv = scale * du, scale * dv
        new_u, new_v, new_distance = u[active], v[active], distance[active]
        pending = np.arange(len(active))
        for _ in range(LINE_SEARCH_HALVINGS + 1):
            tu, tv = np.clip(new_u[pending] + du[pending], 0.0, 1.0), np.clip(new_v[pending] + dv[pending], 0.0, 1.0)
            trial = ((evaluate_points(net[pending], tu, tv) - point[pending]) ** 2).sum(1)
            accept = trial <= new_distance[pending]
            taken = pending[accept]
            new_u[taken], new_v[taken], new_distance[taken] = tu[accept], tv[accept], trial[accept]
            pending = pending[~accept]
            if not len(pending):
                break
            du, dv = 0.5 * du, 0.5 * dv
        # Settled: the distance fell by less than the tolerance (Newton's next decrease is smaller
        # still, or the foot only slides along a valley flat to round-off: a patch wrapped around
        # the point), or the step was rejected (the same step would be taken and rejected again).
        decrease = np.sqrt(distance[active]) - np.sqrt(new_distance)
        moving = (decrease > tolerance[active]) & (np.abs(new_u - u[active]) + np.abs(new_v - v[active]) > 0.0)
        u[active], v[active], distance[active] = new_u, new_v, new_distance
        active = active[moving]
    d = _derivatives(nets, u, v)
    foot = d[:, 0, 0]
    normal = np.cross(d[:, 1, 0], d[:, 0, 1])
    normal /= np.maximum(np.linalg.norm(normal, axis=1), 1e-300)[:, None]
    inside = (u > INSIDE_EPS) & (u < 1 - INSIDE_EPS) & (v > INSIDE_EPS) & (v < 1 - INSIDE_EPS)
    return np.stack([u, v], axis=1), foot, normal, inside


def _along_normal(offset: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Rows of ``offset (N, 3)`` that are parallel to the unit ``normal (N, 3)`` to 1e-6 relative."""
    along = np.einsum("kc,kc->k", offset, normal)
    tangential = np.linalg.norm(offset - along[:, None] * normal, axis=1)
    return tangential <= 1e-6 * np.abs(along)


def _time_of_impact(net_start: np.ndarray, net_end: np.ndarray, point_start: np.ndarray, point_end: np.ndarray,
                    dt: float, gap: float) -> tuple[float, float, float] | None:  # fmt: skip
    """:func:`point_patch_toi` of a point moving ``point_start -> point_end`` ``(3,)`` and a patch
    moving ``net_start -> net_end`` (polynomial ``(4, 4, 3)`` or homogeneous ``(4, 4, 4)`` nets with
    the same weights at both ends) over ``dt``, within ``gap``."""
    if net_start.shape[-1] == 3:
        return point_patch_toi(net_start, (net_end - net_start) / dt, point_start, (point_end - point_start) / dt, dt,
                               tolerance=gap)  # fmt: skip
    # The point lies on the rational patch where sum_j B_j w_j (b_j - x) = W (X - x) = 0: a polynomial
    # patch of the weighted offsets from the point, met by the origin, which stays put. A point
    # within gap of the patch is within gap * max(w) of the origin there.
    weights = net_start[..., 3:]
    offsets_start = net_start[..., :3] - weights * point_start
    offsets_end = net_end[..., :3] - weights * point_end
    return point_patch_toi(offsets_start, (offsets_end - offsets_start) / dt, np.zeros(3), np.zeros(3), dt,
                           tolerance=gap * float(weights.max()))  # fmt: skip


def point_patch_pairs(
    points_start: np.ndarray,
    points_end: np.ndarray,
    nets_start: np.ndarray,
    nets_end: np.ndarray,
    pairs: tuple[np.ndarray, np.ndarray],
    gap: float,
    dt: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Narrow phase of candidate (point, patch) pairs (polynomial nets ``(P, 4, 4, 3)`` or
    homogeneous ones ``(P, 4, 4, 4)`` of rational patches).

    A pair is in contact when the point's projection onto the patch lies inside the patch at the
    end of the step and the point is then closer than ``gap`` on the side where it started (or has
    crossed). Pairs whose projections fall inside at one end only and that moved more than ``gap``
    are decided by the exact point-patch CCD (:func:`point_patch_toi`).

    Returns:
        ``(pair rows, uv at the end (C, 2), side normal (C, 3), separation at the end (C,), toi (C,))``
        where the side normal points from the patch towards the point's starting side.
    """
    ip, iq = pairs
    if not len(ip):
        return np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 3)), np.zeros(0), np.zeros(0)
    _, foot0, normal0, inside0 = project_to_patches(nets_start[iq], points_start[ip])
    uv1, foot1, normal1, inside1 = project_to_patches(nets_end[iq], points_end[ip])
    # A foot on the patch boundary whose offset is normal to the surface is the true closest point
    # of a point right above that boundary line (e.g. where two neighbouring patches meet):
    # inside for both patches (the nearest-patch selection keeps one), or a crossing exactly
    # there goes unseen.
    inside0 |= _along_normal(points_start[ip] - foot0, normal0)
    inside1 |= _along_normal(points_end[ip] - foot1, normal1)
    d0 = ((points_start[ip] - foot0) * normal0).sum(1)
    d1 = ((points_end[ip] - foot1) * normal1).sum(1)
    # the side the point started on; a point starting on the surface takes the side it approaches from
    motion = ((points_end[ip] - points_start[ip]) - (foot1 - foot0)) * normal1
    side = np.where(np.abs(d0) > 1e-3 * gap, np.sign(d0), -np.sign(motion.sum(1)))
    side = np.where(side == 0, 1.0, side)
    separation = side * d1
    # (the patch moves too: the relative motion bounds how far the point can have come)
    relative_motion = np.linalg.norm((points_end[ip] - points_start[ip]) - (foot1 - foot0), axis=1)
    near = inside1 & (np.abs(d0) < 10 * gap + relative_motion)
    hit = near & (separation < gap)
    denominator = np.where(side * (d0 - d1) > 0, side * (d0 - d1), np.inf)
    toi = np.clip((side * d0 - gap) / denominator, 0.0, 1.0)
    side_normal = side[:, None] * normal1
    # Closest point on the patch boundary (an edge or corner, e.g. a sphere's top under a node
    # shared by four patches): a point contact at the Euclidean distance, normal along the offset.
    offset = points_end[ip] - foot1
    length = np.linalg.norm(offset, axis=1)
    edge = ~inside1 & (length < gap) & (length > 0)
    # a point that ended on the other side of the patch than it started has crossed it there
    crossed = np.einsum("kc,kc->k", offset, side_normal) < 0
    hit |= edge
    separation = np.where(edge, np.where(crossed, -length, length), separation)
    # (an offset far below the gap has no reliable direction: the side normal stays)
    rows = edge & ~crossed & (length > 1e-2 * gap)
    side_normal[rows] = offset[rows] / length[rows, None]
    toi[edge] = 0.0
    # disagreeing projections on fast motion: exact CCD decides
    doubtful = np.flatnonzero((inside0 != inside1) & (relative_motion > gap) & ~hit)
    uv = uv1.copy()
    for row in doubtful:
        with warnings.catch_warnings():
            warnings.simplefilter("error", BoundReached)
            try:
                found = _time_of_impact(nets_start[iq[row]], nets_end[iq[row]], points_start[ip[row]],
                                        points_end[ip[row]], dt, gap)  # fmt: skip
            except BoundReached:
                found = (0.0, 0.5, 0.5)  # undecided: treat as a contact (never a silent miss)
        if found is not None:
            hit[row] = True
            toi[row] = found[0] / dt
            uv[row] = found[1:]
            separation[row] = min(separation[row], 0.0)
    rows = np.flatnonzero(hit)
    return rows, uv[rows], side_normal[rows], separation[rows], toi[rows]

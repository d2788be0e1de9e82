"""Contact detection between time steps (paper §6.2), numpy only.

A time step of the solver moves the shell's nodal data linearly from ``start`` to ``end`` (implicit
Euler: every point moves on a straight line over the step). Detection finds every contact of that
motion within a push-out distance ``gap`` and describes it as a linear function of the nodal data:

* shell samples against simple colliders (plane, sphere, cylinder, capsule): uniform samples of the
  midsurface, analytic times of impact;
* collider points against shell patches: the vertices of a triangle mesh, the samples of a patch
  model, the tips of capsules (needles) - each projected onto the shell's patches at the start and
  the end of the step;
* self-collision: samples of each patch against the other patches (a broad phase over swept boxes,
  never all pairs; :func:`self_contacts`), and, where the shell folds within a patch's 3 x 3
  neighbourhood, against the pieces of a recursive subdivision of those patches
  (:func:`folded_self_contacts`).

Each contact is a point ``a`` of the shell (16 nodal weights), optionally a second shell point ``b``
(self-contact), a unit normal ``n`` along which ``a`` separates, and an obstacle point/velocity.
Its separation ``n . (a - b - obstacle)`` and relative normal velocity are linear in the nodal data,
which is what the response (a mass-metric least-squares projection in the solver) needs.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, fields

import numpy as np

from bhem_hpc.collision.bezier import _bernstein, evaluate_many, subpatch_many
from bhem_hpc.collision.ccd import point_patch_toi
from bhem_hpc.collision.colliders import Collider
from bhem_hpc.collision.ray import BoundReached
from bhem_hpc.geometry.surface import ParameterGrid, PatchLayout

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


@dataclass(frozen=True)
class Contacts:
    """``k`` contacts, each a linear function of the shell's flat nodal data ``(m1 * m2 * 4, 3)``.

    Attributes:
        key: ``(k,)`` deterministic order (source, sample) so every rank builds the same rows.
        index_a, weights_a: ``(k, 16)`` the shell point ``a`` (see ``surface.point_weights``).
        index_b, weights_b: ``(k, 16)`` a second shell point (self-contact), weights 0 otherwise.
        normal: ``(k, 3)`` unit normal along which ``a`` separates from the obstacle.
        obstacle_point: ``(k, 3)`` a point of the obstacle's tangent plane at the end of the step.
        obstacle_velocity: ``(k, 3)`` the obstacle's velocity there (0 for self-contact).
        clearance: ``(k,)`` separation that counts as touching (a capsule tip's radius, else 0).
        toi: ``(k,)`` time of impact as a fraction of the step.
        friction: ``(k,)`` Coulomb coefficient of the pair.
    """

    key: np.ndarray
    index_a: np.ndarray
    weights_a: np.ndarray
    index_b: np.ndarray
    weights_b: np.ndarray
    normal: np.ndarray
    obstacle_point: np.ndarray
    obstacle_velocity: np.ndarray
    clearance: np.ndarray
    toi: np.ndarray
    friction: np.ndarray

    def __len__(self) -> int:
        return len(self.key)

    @staticmethod
    def empty() -> Contacts:
        z = np.zeros
        return Contacts(
            z(0, np.int64), z((0, 16), np.int64), z((0, 16)), z((0, 16), np.int64), z((0, 16)),
            z((0, 3)), z((0, 3)), z((0, 3)), z(0), z(0), z(0),
        )  # fmt: skip

    @staticmethod
    def concatenate(parts: Sequence[Contacts]) -> Contacts:
        """All contacts of ``parts`` sorted by key (duplicate keys: the last is kept - a later
        detection round knows where the contact point is now)."""
        parts = [p for p in parts if len(p)]
        if not parts:
            return Contacts.empty()
        merged = {f.name: np.concatenate([getattr(p, f.name) for p in parts])[::-1] for f in fields(Contacts)}
        _, last = np.unique(merged["key"], return_index=True)
        return Contacts(**{name: value[last] for name, value in merged.items()})

    def take(self, rows: np.ndarray) -> Contacts:
        """The contacts at ``rows``."""
        return Contacts(**{f.name: getattr(self, f.name)[rows] for f in fields(Contacts)})

    def separation(self, flat_nodal: np.ndarray) -> np.ndarray:
        """``n . (a - b - obstacle_point)`` for nodal data ``(m1 * m2 * 4, 3)``, shape ``(k,)``."""
        a = np.einsum("kj,kjc->kc", self.weights_a, flat_nodal[self.index_a])
        b = np.einsum("kj,kjc->kc", self.weights_b, flat_nodal[self.index_b])
        return np.einsum("kc,kc->k", self.normal, a - b - self.obstacle_point)

    def relative_velocity(self, flat_velocity: np.ndarray) -> np.ndarray:
        """Velocity of ``a`` relative to the obstacle, ``(k, 3)``."""
        a = np.einsum("kj,kjc->kc", self.weights_a, flat_velocity[self.index_a])
        b = np.einsum("kj,kjc->kc", self.weights_b, flat_velocity[self.index_b])
        return a - b - self.obstacle_velocity


def _empty_b(count: int) -> tuple[np.ndarray, np.ndarray]:
    return np.zeros((count, 16), np.int64), np.zeros((count, 16))


# -- shell samples ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class ShellSamples:
    """Uniform samples of the midsurface, about ``per_side^2`` per patch.

    Attributes:
        patch: ``(S,)`` flat patch index ``p1 * n2 + p2``; local: ``(S, 2)`` local coordinates.
        index, weights: ``(S, 16)`` nodal weights of each sample.
    """

    patch: np.ndarray
    local: np.ndarray
    index: np.ndarray
    weights: np.ndarray

    @staticmethod
    def build(layout: PatchLayout, per_side: int) -> ShellSamples:
        """A uniform lattice of ``n * per_side (+ 1)`` points per direction over the whole surface,
        boundary edges included (an unsampled free edge could swing through a plane)."""
        if not (isinstance(per_side, int) and 1 <= per_side <= 16):
            raise ValueError(f"samples_per_side must be an integer in 1..16, got {per_side!r}")
        grid = layout.grid
        axes = []
        for n, (lo, hi), periodic in (
            (grid.n1, grid.xi1_range, grid.periodic1),
            (grid.n2, grid.xi2_range, grid.periodic2),
        ):
            count = n * per_side + (0 if periodic else 1)
            axes.append(lo + (hi - lo) * np.arange(count) / (n * per_side))
        xi1, xi2 = (a.ravel() for a in np.meshgrid(*axes, indexing="ij"))
        p1, p2, t1, t2 = grid.locate(xi1, xi2)
        index, weights = layout.point_entries(p1, p2, t1, t2)
        return ShellSamples(p1 * grid.n2 + p2, np.stack([t1, t2], axis=1), index, weights)

    def positions(self, flat_nodal: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Positions ``(len(rows), 3)`` of samples ``rows`` for flat nodal data ``(N, 3)``."""
        return np.einsum("sj,sjc->sc", self.weights[rows], flat_nodal[self.index[rows]])


@dataclass(frozen=True)
class ShellMotion:
    """The shell's straight-line motion over one step, as detection sees it.

    Attributes:
        layout: the patches as maps of the entries (:class:`~bhem_hpc.geometry.surface.HermitePatches`).
        start, end: entries ``(N, 3)`` at the start and the end of the step.
        nets_start, nets_end: the patches' Bezier nets ``(patches, 4, 4, 3)`` at both ends.
        dt: the step [s]; gap: the push-out distance (contacts are found within it).
    """

    layout: PatchLayout
    start: np.ndarray
    end: np.ndarray
    nets_start: np.ndarray
    nets_end: np.ndarray
    dt: float
    gap: float

    @staticmethod
    def of(layout: PatchLayout, start: np.ndarray, end: np.ndarray, dt: float, gap: float) -> ShellMotion:
        return ShellMotion(layout, start, end, layout.bezier_nets(start), layout.bezier_nets(end), dt, gap)


# -- broad phase ------------------------------------------------------------------------------------
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


# -- closest points on patches -----------------------------------------------------------------------
def _derivatives(nets: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Points and partial derivatives up to second order of nets ``(N, 4, 4, 3)`` at ``u, v (N,)``:
    ``(N, 3, 3, 3)`` indexed ``[order in u, order in v, xyz]`` (orders above 2 in total are unused)."""
    along_u = np.stack([_bernstein(u, k) for k in range(3)], axis=1)  # (N, 3, 4)
    along_v = np.stack([_bernstein(v, k) for k in range(3)], axis=1)
    partial = np.matmul(along_u, nets.reshape(len(nets), 4, 12)).reshape(-1, 3, 4, 3)  # [n, order u, j, xyz]
    return np.matmul(along_v[:, None], partial)  # [n, order u, order v, xyz]


def project_to_patches(nets: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Closest points of ``points (N, 3)`` on Bezier patches ``nets (N, 4, 4, 3)`` (one each).

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
    samples = basis @ nets.reshape(n, 16, 3)  # (N, START_GRID^2, 3)
    nearest = np.argmin(((samples - points[:, None]) ** 2).sum(-1), axis=1)
    u, v = gu.ravel()[nearest], gv.ravel()[nearest]
    distance = ((evaluate_many(nets, u, v) - points) ** 2).sum(1)
    active = np.arange(n)  # the projections still iterating
    tolerance = PROJECTION_TOLERANCE * np.linalg.norm(np.ptp(nets.reshape(n, 16, 3), axis=1), axis=1)
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
            trial = ((evaluate_many(net[pending], tu, tv) - point[pending]) ** 2).sum(1)
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


def _point_patch_pairs(
    points_start: np.ndarray,
    points_end: np.ndarray,
    nets_start: np.ndarray,
    nets_end: np.ndarray,
    pairs: tuple[np.ndarray, np.ndarray],
    gap: float,
    dt: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Narrow phase of candidate (point, patch) pairs.

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
                found = point_patch_toi(
                    nets_start[iq[row]],
                    (nets_end[iq[row]] - nets_start[iq[row]]) / dt,
                    points_start[ip[row]],
                    (points_end[ip[row]] - points_start[ip[row]]) / dt,
                    dt,
                    tolerance=gap,
                )
            except BoundReached:
                found = (0.0, 0.5, 0.5)  # undecided: treat as a contact (never a silent miss)
        if found is not None:
            hit[row] = True
            toi[row] = found[0] / dt
            uv[row] = found[1:]
            separation[row] = min(separation[row], 0.0)
    rows = np.flatnonzero(hit)
    return rows, uv[rows], side_normal[rows], separation[rows], toi[rows]


# -- detection ---------------------------------------------------------------------------------------
def _nearest_per_point(point: np.ndarray, separation: np.ndarray) -> np.ndarray:
    """Rows of the smallest separation for each distinct ``point`` (a point touches one patch)."""
    order = np.lexsort((separation, point))
    return order[np.r_[True, point[order][1:] != point[order][:-1]]]


def _sample_contacts(
    source: int, samples: ShellSamples, sample: np.ndarray, second: tuple[np.ndarray, np.ndarray],
    normal: np.ndarray, obstacle_point: np.ndarray, obstacle_velocity: np.ndarray, toi: np.ndarray, friction: float,
) -> Contacts:  # fmt: skip
    """Contacts whose point ``a`` is the shell sample ``sample``; ``second`` = (index, weights) of ``b``."""
    return Contacts(
        key=source * 2**40 + sample,
        index_a=samples.index[sample],
        weights_a=samples.weights[sample],
        index_b=second[0],
        weights_b=second[1],
        normal=normal,
        obstacle_point=obstacle_point,
        obstacle_velocity=obstacle_velocity,
        clearance=np.zeros(len(sample)),
        toi=toi,
        friction=np.full(len(sample), friction),
    )


def simple_collider_contacts(
    collider, source: int, samples: ShellSamples, rows: np.ndarray, positions: tuple[np.ndarray, np.ndarray],
    dt: float, gap: float, friction: float,
) -> Contacts:  # fmt: skip
    """Shell samples ``rows`` (at ``positions`` = start and end, ``(len(rows), 3)`` each) against a
    plane, sphere, cylinder or capsule (analytic distances)."""
    if not len(rows):
        return Contacts.empty()
    p0, p1 = positions
    bounds = collider.swept_bounds(dt)
    if bounds is not None:  # only the samples whose swept box comes within gap of the collider's
        near = np.all((np.minimum(p0, p1) <= bounds[1] + gap) & (np.maximum(p0, p1) >= bounds[0] - gap), axis=1)
        rows, p0, p1 = rows[near], p0[near], p1[near]
        if not len(rows):
            return Contacts.empty()
    toi = collider.time_of_impact(p0, p1, dt, gap)
    hit = np.flatnonzero(toi <= 1.0)
    if not len(hit):
        return Contacts.empty()
    d1, normal1 = collider.signed_distance(p1[hit], dt)
    # The normal where the sample touches (a rigidly translating collider: shift the points back
    # instead of moving the collider); the tangent plane passes through the foot point at the end.
    contact_point = p0[hit] + toi[hit, None] * (p1[hit] - p0[hit])
    _, normal = collider.signed_distance(contact_point - (toi[hit] * dt)[:, None] * collider.velocity, 0.0)
    foot = p1[hit] - d1[:, None] * normal1
    b_index, b_weights = _empty_b(len(hit))
    return _sample_contacts(
        source, samples, rows[hit], (b_index, b_weights), normal, foot,
        np.broadcast_to(collider.velocity, (len(hit), 3)).copy(), toi[hit], friction,
    )  # fmt: skip


def point_contacts(
    points_start: np.ndarray, velocity: np.ndarray, clearance: float, source: int, rows: np.ndarray,
    motion: ShellMotion, friction: float, patches: np.ndarray | None = None, patch_boxes: np.ndarray | None = None,
) -> Contacts:  # fmt: skip
    """Collider points ``rows`` (mesh vertices, patch-model samples, needle tips) against shell patches.

    The points move at ``velocity``; ``clearance`` is the radius around each point that counts as
    touching (a round needle tip). ``patches``: a ``(n1 * n2,)`` mask of the patches to test (None:
    all); ``patch_boxes``: the patches' swept boxes (computed if None).
    """
    layout, nets_start, nets_end, dt, gap = motion.layout, motion.nets_start, motion.nets_end, motion.dt, motion.gap
    grid = layout.grid
    if not len(rows):
        return Contacts.empty()
    q0 = points_start[rows]
    q1 = q0 + dt * velocity
    reach = gap + clearance
    tested = np.arange(len(nets_start)) if patches is None else np.flatnonzero(patches)
    if patch_boxes is None:
        patch_boxes = swept_boxes(nets_start[tested], nets_end[tested], 0.0)
    else:
        patch_boxes = patch_boxes[tested]
    point_boxes = swept_boxes(q0, q1, 0.0)
    if len(point_boxes) * len(tested) <= BRUTE_FORCE_PAIRS:
        # a few points (a sphere's centre, needle tips): every pair, in overlapping_pairs' order
        iq, ip = np.divmod(np.arange(len(point_boxes) * len(tested)), len(tested))
    else:
        ip, iq = overlapping_pairs(patch_boxes + [[-reach], [reach]], point_boxes)
    # The padded boxes overlap where the boxes are within reach in every axis; a round tip's reach
    # (a sphere's radius) is large, so keep only the pairs within reach in Euclidean distance.
    keep = box_distance(patch_boxes[ip], point_boxes[iq]) <= reach
    ip, iq = tested[ip[keep]], iq[keep]
    found, uv, side_normal, separation, toi = _point_patch_pairs(q0, q1, nets_start, nets_end, (iq, ip), reach, dt)
    if not len(found):
        return Contacts.empty()
    point, patch = iq[found], ip[found]
    if clearance == 0.0:  # a vertex touches the shell once: keep its nearest patch
        first = _nearest_per_point(point, separation)
        point, patch, uv, side_normal, toi = point[first], patch[first], uv[first], side_normal[first], toi[first]
    normal = -side_normal
    if clearance > 0.0:
        # a round tip or a sphere's centre keeps every patch within reach: each patch's closest
        # point, with the radial normal, whatever side of the patch the centre is on
        foot = evaluate_many(nets_end[patch], uv[:, 0], uv[:, 1])
        offset = foot - q1[point]
        length = np.linalg.norm(offset, axis=1)
        # The row holds the Euclidean distance to the foot. A foot off the true closest point (next
        # to a patch edge where the closest point lies on the edge) can be nearer along the patch
        # normal than in distance: such a hit asks for nothing, and a later round would find it again.
        keep = (length < reach) | (separation < 0.0)
        point, patch, uv, normal, toi, offset, length = (
            a[keep] for a in (point, patch, uv, normal, toi, offset, length)
        )
        radial = length > 1e-12 * clearance
        normal[radial] = offset[radial] / length[radial, None]
        if not len(point):
            return Contacts.empty()
    index, weights = layout.point_entries(patch // grid.n2, patch % grid.n2, uv[:, 0], uv[:, 1])
    b_index, b_weights = _empty_b(len(point))
    # the shell point must stay on its side: the normal points from the collider point to the shell
    return Contacts(
        key=source * 2**40 + rows[point] * grid.n1 * grid.n2 + patch,
        index_a=index,
        weights_a=weights,
        index_b=b_index,
        weights_b=b_weights,
        normal=normal,
        obstacle_point=q1[point],
        obstacle_velocity=np.broadcast_to(velocity, (len(point), 3)).copy(),
        clearance=np.full(len(point), clearance),
        toi=toi,
        friction=np.full(len(point), friction),
    )


def self_contacts(
    samples: ShellSamples, rows: np.ndarray, motion: ShellMotion, friction: float, source: int
) -> Contacts:
    """Shell samples ``rows`` against the shell's other patches.

    Patches sharing a node with the sample's own patch are skipped: a sample is always within
    ``gap`` of them. Folds inside that 3 x 3 neighbourhood are :func:`folded_self_contacts`'s.
    """
    layout, start, end, dt, gap = motion.layout, motion.start, motion.end, motion.dt, motion.gap
    nets_start, nets_end, grid = motion.nets_start, motion.nets_end, layout.grid
    if not len(rows):
        return Contacts.empty()
    p0 = samples.positions(start, rows)
    p1 = samples.positions(end, rows)
    ip, iq = overlapping_pairs(swept_boxes(nets_start, nets_end, gap), swept_boxes(p0, p1, 0.0))
    d1, d2 = _neighbour_offsets(grid, samples.patch[rows][iq], ip)
    far = (np.abs(d1) > 1) | (np.abs(d2) > 1)
    ip, iq = ip[far], iq[far]
    found, uv, side_normal, separation, toi = _point_patch_pairs(p0, p1, nets_start, nets_end, (iq, ip), gap, dt)
    if not len(found):
        return Contacts.empty()
    point, patch = iq[found], ip[found]
    first = _nearest_per_point(point, separation)
    point, patch, uv, side_normal, toi = point[first], patch[first], uv[first], side_normal[first], toi[first]
    b_index, b_weights = layout.point_entries(patch // grid.n2, patch % grid.n2, uv[:, 0], uv[:, 1])
    zeros = np.zeros((len(point), 3))
    return _sample_contacts(
        source, samples, rows[point], (b_index, b_weights), side_normal, zeros, zeros, toi, friction
    )


#: A region whose normals spread by more than this can fold onto itself: its patches are searched
#: for contact within the 3 x 3 neighbourhood that :func:`self_contacts` skips.
FOLD_SPREAD_DEGREES = 120.0
#: Pieces of a folded patch are split while their own normals spread by more than this ...
PIECE_SPREAD_DEGREES = 45.0
#: ... down to at most this depth (4^depth pieces per patch).
MAX_FOLD_DEPTH = 3
_CONE_GRID = np.linspace(0.0, 1.0, 4)


def _lattice_matrices() -> tuple[np.ndarray, np.ndarray]:
    gu, gv = (a.ravel() for a in np.meshgrid(_CONE_GRID, _CONE_GRID, indexing="ij"))
    along_u = np.einsum("si,sj->sij", _bernstein(gu, 1), _bernstein(gv)).reshape(16, 16)
    along_v = np.einsum("si,sj->sij", _bernstein(gu), _bernstein(gv, 1)).reshape(16, 16)
    return along_u, along_v


_LATTICE_DU, _LATTICE_DV = _lattice_matrices()


def unit_normals(nets: np.ndarray) -> np.ndarray:
    """Unit normals ``(N, 16, 3)`` of nets ``(N, 4, 4, 3)`` at a 4 x 4 lattice including the corners."""
    points = nets.reshape(len(nets), 16, 3)
    normal = np.cross(_LATTICE_DU @ points, _LATTICE_DV @ points)
    return normal / np.maximum(np.linalg.norm(normal, axis=2), 1e-300)[..., None]


def normal_spread(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Largest angle (radians) between any normal of ``first (N, S, 3)`` and of ``second (N, S, 3)``."""
    cosine = np.matmul(first, np.swapaxes(second, 1, 2)).min(axis=(1, 2))
    return np.arccos(np.clip(cosine, -1.0, 1.0))


def _normal_cones(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axis ``(N, 3)`` and half-angle ``(N,)`` of a cone holding each row of ``normals (N, S, 3)``."""
    axis = normals.sum(axis=1)
    axis /= np.maximum(np.linalg.norm(axis, axis=1), 1e-300)[:, None]
    cosine = np.einsum("nsc,nc->ns", normals, axis).min(axis=1)
    return axis, np.arccos(np.clip(cosine, -1.0, 1.0))


def fold_pieces(net_start: np.ndarray, net_end: np.ndarray) -> np.ndarray:
    """Recursive subdivision of one patch into pieces whose normals spread by at most
    ``PIECE_SPREAD_DEGREES`` at both ends of the step (or of depth ``MAX_FOLD_DEPTH``).

    Returns:
        ``(L, 4)`` local parameter rectangles ``(u0, u1, v0, v1)`` covering ``[0, 1]^2``.
    """
    limit = math.radians(PIECE_SPREAD_DEGREES)
    rects, leaves = np.array([[0.0, 1.0, 0.0, 1.0]]), []
    for depth in range(MAX_FOLD_DEPTH + 1):
        nets = [subpatch_many(np.broadcast_to(net, (len(rects), 4, 4, 3)), *rects.T) for net in (net_start, net_end)]
        spread = np.maximum(*(normal_spread(unit_normals(n), unit_normals(n)) for n in nets))
        done = (spread <= limit) | (depth == MAX_FOLD_DEPTH)
        leaves.append(rects[done])
        split = rects[~done]
        mu, mv = 0.5 * (split[:, 0] + split[:, 1]), 0.5 * (split[:, 2] + split[:, 3])
        rects = np.concatenate(
            [
                np.stack([split[:, 0], mu, split[:, 2], mv], 1),
                np.stack([mu, split[:, 1], split[:, 2], mv], 1),
                np.stack([split[:, 0], mu, mv, split[:, 3]], 1),
                np.stack([mu, split[:, 1], mv, split[:, 3]], 1),
            ]
        )
        if not len(rects):
            break
    return np.concatenate(leaves)


def _neighbour_offsets(grid: ParameterGrid, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Patch-index offsets ``b - a`` per direction, wrapped on periodic directions (flat indices)."""
    d1 = b // grid.n2 - a // grid.n2
    d2 = b % grid.n2 - a % grid.n2
    if grid.periodic1:
        d1 = (d1 + grid.n1 // 2) % grid.n1 - grid.n1 // 2
    if grid.periodic2:
        d2 = (d2 + grid.n2 // 2) % grid.n2 - grid.n2 // 2
    return d1, d2


def _neighbourhood_pairs(grid: ParameterGrid, own: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(row, patch)``: every patch of the 3 x 3 neighbourhood (wrapped where periodic) of each
    patch ``own[row]``, ``own (k,)`` in the order ``p1 * n2 + p2``."""
    pairs_p, pairs_q = [], []
    for o1 in (-1, 0, 1):
        for o2 in (-1, 0, 1):
            q1, q2 = own // grid.n2 + o1, own % grid.n2 + o2
            if grid.periodic1:
                q1 %= grid.n1
            if grid.periodic2:
                q2 %= grid.n2
            valid = (q1 >= 0) & (q1 < grid.n1) & (q2 >= 0) & (q2 < grid.n2)
            pairs_p.append(np.flatnonzero(valid))
            pairs_q.append((q1 * grid.n2 + q2)[valid])
    return np.concatenate(pairs_p), np.concatenate(pairs_q)


def folded_self_contacts(
    samples: ShellSamples, rows: np.ndarray, motion: ShellMotion, friction: float, source: int
) -> Contacts:
    """Shell samples ``rows`` against the pieces of their own and neighbouring patches, where the
    shell folds onto itself within that 3 x 3 neighbourhood.

    A sample's patch P and a neighbour Q (P itself included) are searched when the normals of P and
    Q spread by more than ``FOLD_SPREAD_DEGREES`` (at the start or the end of the step); Q is then
    subdivided recursively (:func:`fold_pieces`) and the sample is tested against every piece that
    does not lie within one piece width of it in the parameter domain (nearer pieces are the sample's
    own surface, not a fold).
    """
    start, end, nets_start, nets_end, dt, gap = (
        motion.start, motion.end, motion.nets_start, motion.nets_end, motion.dt, motion.gap
    )
    layout, grid = motion.layout, motion.layout.grid
    if not len(rows):
        return Contacts.empty()
    normals = [unit_normals(nets) for nets in (nets_start, nets_end)]
    own = samples.patch[rows]
    sample_row, neighbour = _neighbourhood_pairs(grid, own)
    # A pair of patches can fold only if the cones of their normals allow a spread past the limit
    # (a cheap bound); the spread is then computed exactly for those pairs.
    limit = math.radians(FOLD_SPREAD_DEGREES)
    key = own[sample_row] * len(nets_end) + neighbour
    possible = np.zeros(len(key), dtype=bool)
    for n in normals:
        axis, half = _normal_cones(n)
        between = np.arccos(np.clip(np.einsum("kc,kc->k", axis[own[sample_row]], axis[neighbour]), -1.0, 1.0))
        possible |= half[own[sample_row]] + half[neighbour] + between > limit
    if not possible.any():
        return Contacts.empty()
    candidates = np.unique(key[possible])
    first, second = candidates // len(nets_end), candidates % len(nets_end)
    spread = np.maximum(*(normal_spread(n[first], n[second]) for n in normals))
    keep = np.isin(key, candidates[spread > limit])
    if not keep.any():
        return Contacts.empty()
    sample_row, neighbour = sample_row[keep], neighbour[keep]
    # pieces of every patch involved in a fold, in the patch's own local parameters
    piece_patch, piece_rect = [], []
    for patch in np.unique(neighbour):
        rects = fold_pieces(nets_start[patch], nets_end[patch])
        piece_patch.append(np.full(len(rects), patch))
        piece_rect.append(rects)
    piece_patch, piece_rect = np.concatenate(piece_patch), np.concatenate(piece_rect)
    first_piece = np.searchsorted(piece_patch, neighbour, side="left")
    count = np.searchsorted(piece_patch, neighbour, side="right") - first_piece
    point = np.repeat(sample_row, count)
    piece = np.concatenate([np.arange(a, a + c) for a, c in zip(first_piece, count, strict=True)])
    # the sample's position relative to the piece's patch, in patch units (wrapped when periodic)
    d1, d2 = _neighbour_offsets(grid, piece_patch[piece], own[point])
    s1 = d1 + samples.local[rows[point], 0]
    s2 = d2 + samples.local[rows[point], 1]
    rect = piece_rect[piece]
    width_u, width_v = rect[:, 1] - rect[:, 0], rect[:, 3] - rect[:, 2]
    near = (s1 > rect[:, 0] - width_u) & (s1 < rect[:, 1] + width_u)
    near &= (s2 > rect[:, 2] - width_v) & (s2 < rect[:, 3] + width_v)
    point, piece, rect = point[~near], piece[~near], rect[~near]
    if not len(point):
        return Contacts.empty()
    patch = piece_patch[piece]
    sub_start = subpatch_many(nets_start[patch], *rect.T)
    sub_end = subpatch_many(nets_end[patch], *rect.T)
    p0, p1 = samples.positions(start, rows[point]), samples.positions(end, rows[point])
    pairs = np.arange(len(point))
    found, uv, side_normal, separation, toi = _point_patch_pairs(p0, p1, sub_start, sub_end, (pairs, pairs), gap, dt)
    if not len(found):
        return Contacts.empty()
    first = _nearest_per_point(point[found], separation)
    found, uv, side_normal, toi = found[first], uv[first], side_normal[first], toi[first]
    rect, patch = rect[found], patch[found]
    t1 = rect[:, 0] + uv[:, 0] * (rect[:, 1] - rect[:, 0])
    t2 = rect[:, 2] + uv[:, 1] * (rect[:, 3] - rect[:, 2])
    b_index, b_weights = layout.point_entries(patch // grid.n2, patch % grid.n2, t1, t2)
    zeros = np.zeros((len(found), 3))
    return _sample_contacts(
        source, samples, rows[point[found]], (b_index, b_weights), side_normal, zeros, zeros, toi, friction
    )


@dataclass(frozen=True)
class ColliderEntry:
    """A collider with the friction coefficient of its contact with the shell."""

    collider: Collider
    friction: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.friction) and self.friction >= 0):
            raise ValueError(f"friction coefficient must be a finite number >= 0, got {self.friction!r}")


class ContactDetector:
    """All contacts of one step's motion, for one rank's share of the samples.

    Args:
        layout: the shell's patches as maps of its entries (``discretization.patches``).
        colliders: the scene's colliders with their friction coefficients.
        samples_per_side: shell samples per patch side (simple colliders and self-collision).
        self_collision: test the shell against itself; self_friction its coefficient.
    """

    def __init__(
        self,
        layout: PatchLayout,
        colliders: Sequence[ColliderEntry],
        samples_per_side: int = 2,
        self_collision: bool = False,
        self_friction: float = 0.0,
    ):
        if not (math.isfinite(self_friction) and self_friction >= 0):
            raise ValueError(f"self_friction must be a finite number >= 0, got {self_friction!r}")
        self.layout = layout
        self.grid = layout.grid
        self.colliders = tuple(colliders)
        self.samples = ShellSamples.build(layout, samples_per_side)
        self.self_collision = self_collision
        self.self_friction = self_friction

    @property
    def num_samples(self) -> int:
        """Sample points tested per step: shell samples (if used) plus collider points."""
        count = sum(len(e.collider.contact_points()[0]) for e in self.colliders)
        if self.self_collision or any(e.collider.analytic for e in self.colliders):
            count += len(self.samples.patch)
        return count

    def detect(
        self,
        start: np.ndarray,
        end: np.ndarray,
        time: float,
        dt: float,
        gap: float,
        rank: int = 0,
        size: int = 1,
        patches: np.ndarray | None = None,
    ) -> Contacts:
        """Contacts of the motion ``start -> end`` (flat nodal ``(m1 * m2 * 4, 3)``) over ``[time, time + dt]``.

        Each of ``size`` ranks tests an interleaved share of the samples; the union over ranks is
        the serial result. ``patches``: a ``(n1 * n2,)`` mask restricting the test against
        colliders to those patches and their samples (None: all; self-collision always tests all).
        """
        motion = ShellMotion.of(self.layout, start, end, dt, gap)
        patch_boxes = None  # swept boxes of the patches, shared by every collider's points
        every_row = np.arange(rank, len(self.samples.patch), size)
        shell_rows = every_row if patches is None else every_row[patches[self.samples.patch[every_row]]]
        positions = (self.samples.positions(start, shell_rows), self.samples.positions(end, shell_rows))
        parts = []
        for source, entry in enumerate(self.colliders):
            collider = collider_at(entry.collider, time)
            if collider.analytic:
                parts.append(
                    simple_collider_contacts(
                        collider, 2 * source, self.samples, shell_rows, positions, dt, gap, entry.friction
                    )
                )
            points, clearance = collider.contact_points()
            if len(points):
                if patch_boxes is None:
                    patch_boxes = swept_boxes(motion.nets_start, motion.nets_end, 0.0)
                rows = np.arange(rank, len(points), size)
                parts.append(
                    point_contacts(
                        points, collider.velocity, clearance, 2 * source + 1, rows, motion, entry.friction,
                        patches, patch_boxes,
                    )
                )  # fmt: skip
        if self.self_collision:
            parts.append(
                self_contacts(
                    self.samples, every_row, motion, self.self_friction, 2 * len(self.colliders),
                )
            )  # fmt: skip
            parts.append(
                folded_self_contacts(
                    self.samples, every_row, motion, self.self_friction, 2 * len(self.colliders) + 1,
                )
            )  # fmt: skip
        return Contacts.concatenate(parts)


def collider_at(collider: Collider, time: float) -> Collider:
    """The collider translated to where its constant velocity has taken it at ``time``."""
    if time == 0.0 or not np.any(collider.velocity):
        return collider
    return collider.translated(time * collider.velocity)

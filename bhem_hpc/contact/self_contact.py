"""Self-contact: samples against the other patches, and folds within a patch's 3 x 3 neighbourhood;
and contact between bodies: one body's samples against another's patches."""

from __future__ import annotations

import math

import numpy as np

from bhem_hpc.collision.bezier import _bernstein, subpatch_many
from bhem_hpc.contact.broad_phase import overlapping_pairs, swept_boxes
from bhem_hpc.contact.closest_points import point_patch_pairs
from bhem_hpc.contact.contacts import Contacts, nearest_per_point, sample_contacts
from bhem_hpc.contact.samples import ShellMotion, ShellSamples
from bhem_hpc.geometry.surface import ParameterGrid


def self_contacts(
    samples: ShellSamples, rows: np.ndarray, motion: ShellMotion, friction: float, source: int
) -> Contacts:
    """Shell samples ``rows`` against the shell's other patches.

    Patches sharing a node with the sample's own patch are skipped: a sample is always within
    ``gap`` of them. Folds inside that 3 x 3 neighbourhood are :func:`folded_self_contacts`'s.
    """
    if not len(rows):
        return Contacts.empty()
    p0, p1 = samples.positions(motion.start, rows), samples.positions(motion.end, rows)
    ip, iq = overlapping_pairs(swept_boxes(motion.nets_start, motion.nets_end, motion.gap), swept_boxes(p0, p1, 0.0))
    d1, d2 = _neighbour_offsets(motion.layout.grid, samples.patch[rows][iq], ip)
    far = (np.abs(d1) > 1) | (np.abs(d2) > 1)
    return points_on_patches(samples, rows, (p0, p1), motion, (ip[far], iq[far]), friction, source)


def body_contacts(
    samples: ShellSamples, rows: np.ndarray, positions: tuple[np.ndarray, np.ndarray], own_patches: int,
    motion: ShellMotion, patches: np.ndarray | None, friction: float, source: int,
) -> Contacts:  # fmt: skip
    """Samples ``rows`` of one body (at ``positions``, ``(len(rows), 3)`` at both ends of the step)
    against the patches of another (moving as ``motion``, a shell's or a solid's): point ``a`` on
    the first body, ``b`` on the second, each in its own body's entries.

    Args:
        own_patches: the sample body's patch count.
        patches: ``(sample body's patches + other body's patches,)`` mask of the patches that can
            hold a new contact (a later detection round); a pair is tested when either of its
            patches can. None: every pair.
    """
    if not len(rows):
        return Contacts.empty()
    p0, p1 = positions
    ip, iq = overlapping_pairs(motion.patch_boxes(motion.gap), swept_boxes(p0, p1, 0.0))
    if patches is not None:
        keep = patches[samples.patch[rows][iq]] | patches[own_patches + ip]
        ip, iq = ip[keep], iq[keep]
    return points_on_patches(samples, rows, (p0, p1), motion, (ip, iq), friction, source)


def points_on_patches(
    samples: ShellSamples, rows: np.ndarray, positions: tuple[np.ndarray, np.ndarray], motion: ShellMotion,
    pairs: tuple[np.ndarray, np.ndarray], friction: float, source: int,
) -> Contacts:  # fmt: skip
    """The narrow phase of candidate pairs ``(patch, point)`` of samples ``rows`` (at ``positions``,
    ``(len(rows), 3)`` at both ends of the step) and the patches of ``motion``: each point's nearest
    patch in contact."""
    ip, iq = pairs
    found, uv, side_normal, separation, toi = point_patch_pairs(
        *positions, motion.nets_start, motion.nets_end, (iq, ip), motion.gap, motion.dt
    )
    if not len(found):
        return Contacts.empty()
    point, patch = iq[found], ip[found]
    first = nearest_per_point(point, separation)
    point, patch, uv, side_normal, toi = point[first], patch[first], uv[first], side_normal[first], toi[first]
    b_index, b_weights = motion.patch_point_entries(patch, uv)
    zeros = np.zeros((len(point), 3))
    return sample_contacts(
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
    found, uv, side_normal, separation, toi = point_patch_pairs(p0, p1, sub_start, sub_end, (pairs, pairs), gap, dt)
    if not len(found):
        return Contacts.empty()
    first = nearest_per_point(point[found], separation)
    found, uv, side_normal, toi = found[first], uv[first], side_normal[first], toi[first]
    rect, patch = rect[found], patch[found]
    t1 = rect[:, 0] + uv[:, 0] * (rect[:, 1] - rect[:, 0])
    t2 = rect[:, 2] + uv[:, 1] * (rect[:, 3] - rect[:, 2])
    b_index, b_weights = layout.point_entries(patch // grid.n2, patch % grid.n2, t1, t2)
    zeros = np.zeros((len(found), 3))
    return sample_contacts(
        source, samples, rows[point[found]], (b_index, b_weights), side_normal, zeros, zeros, toi, friction
    )

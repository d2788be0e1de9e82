"""Contacts with colliders: shell samples against analytic shapes, collider points against patches."""

from __future__ import annotations

import numpy as np

from bhem_hpc.contact.broad_phase import box_distance, overlapping_pairs, swept_boxes
from bhem_hpc.contact.closest_points import BRUTE_FORCE_PAIRS, evaluate_points, point_patch_pairs
from bhem_hpc.contact.contacts import Contacts, nearest_per_point, no_second_point, sample_contacts
from bhem_hpc.contact.samples import ShellMotion, ShellSamples


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
    b_index, b_weights = no_second_point(len(hit), samples.index.shape[1])
    return sample_contacts(
        source, samples, rows[hit], (b_index, b_weights), normal, foot,
        np.broadcast_to(collider.velocity, (len(hit), 3)).copy(), toi[hit], friction,
    )  # fmt: skip


def point_contacts(
    points_start: np.ndarray, velocity: np.ndarray, clearance: float, source: int, rows: np.ndarray,
    motion: ShellMotion, friction: float, patches: np.ndarray | None = None, patch_boxes: np.ndarray | None = None,
) -> Contacts:  # fmt: skip
    """Collider points ``rows`` (mesh vertices, patch-model samples, needle tips) against a body's
    patches (``motion``: a shell's, or a solid's rational ones).

    The points move at ``velocity``; ``clearance`` is the radius around each point that counts as
    touching (a round needle tip). ``patches``: a ``(patches,)`` mask of the patches to test (None:
    all); ``patch_boxes``: the patches' swept boxes (computed if None).
    """
    nets_start, nets_end, dt, gap = motion.nets_start, motion.nets_end, motion.dt, motion.gap
    if not len(rows):
        return Contacts.empty()
    q0 = points_start[rows]
    q1 = q0 + dt * velocity
    reach = gap + clearance
    tested = np.arange(len(nets_start)) if patches is None else np.flatnonzero(patches)
    if patch_boxes is None:
        patch_boxes = motion.patch_boxes(0.0)[tested]
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
    found, uv, side_normal, separation, toi = point_patch_pairs(q0, q1, nets_start, nets_end, (iq, ip), reach, dt)
    if not len(found):
        return Contacts.empty()
    point, patch = iq[found], ip[found]
    if clearance == 0.0:  # a vertex touches the shell once: keep its nearest patch
        first = nearest_per_point(point, separation)
        point, patch, uv, side_normal, toi = point[first], patch[first], uv[first], side_normal[first], toi[first]
    normal = -side_normal
    if clearance > 0.0:
        # a round tip or a sphere's centre keeps every patch within reach: each patch's closest
        # point, with the radial normal, whatever side of the patch the centre is on
        foot = evaluate_points(nets_end[patch], uv[:, 0], uv[:, 1])
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
    index, weights = motion.patch_point_entries(patch, uv)
    b_index, b_weights = no_second_point(len(point), index.shape[1])
    # the shell point must stay on its side: the normal points from the collider point to the shell
    return Contacts(
        key=source * 2**40 + rows[point] * motion.num_patches + patch,
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

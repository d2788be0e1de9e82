"""Contact of several bodies (numpy only): their entries side by side, and detection of every
body against the colliders, itself and the other bodies.

The response (:class:`~bhem_hpc.contact.response.ContactHandler`) works on one array of flat
entries ``(N, 3)``. For several bodies that array is every body's entries, body after body
(:class:`StackedEntries`); a contact row names entries of one body (a collider, self-contact) or
of two (point ``a`` on one body, point ``b`` on another), and the projector splits it by body
(:class:`~bhem_hpc.contact.bodies_petsc.StackedProjector`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

from bhem_hpc.contact.broad_phase import overlapping_pairs, swept_boxes
from bhem_hpc.contact.closest_points import control_points, project_to_patches
from bhem_hpc.contact.contacts import Contacts
from bhem_hpc.contact.detection import ContactDetector
from bhem_hpc.contact.samples import ShellMotion, lattice_axes
from bhem_hpc.contact.self_contact import body_contacts
from bhem_hpc.errors import InputError
from bhem_hpc.geometry.bspline import BSplineSurface
from bhem_hpc.geometry.nurbs import NurbsSurface, span_lattice
from bhem_hpc.geometry.surface import HermiteSurface

if TYPE_CHECKING:  # (the discretizations are built on dolfinx; detection is numpy only)
    from bhem_hpc.discretization.protocol import Discretization

#: Keys of one group of contacts (a body's own, or one ordered pair of bodies') stay below this:
#: a body's detector keys its contacts ``source * 2**40 + sample`` with a few sources.
GROUP_KEYS = 2**47
#: Bodies a stacked detector takes: every ordered pair has a key group (``bodies * (bodies + 1)``
#: groups of ``GROUP_KEYS`` keys fit in 63 bits).
MAX_BODIES = 90

Surface = HermiteSurface | BSplineSurface


def pair_friction(first: float, second: float) -> float:
    """Coulomb coefficient between two bodies: the geometric mean of theirs (a frictionless body slides
    on every other)."""
    return math.sqrt(first * second)


@runtime_checkable
class ContactSurface(Protocol):
    """A body as impulse contact sees it: flat entries ``(N, 3)`` that its contact points are linear
    maps of, and patches (each moved by a known set of entries)."""

    @property
    def num_entries(self) -> int: ...

    @property
    def num_patches(self) -> int: ...

    @property
    def open_size(self) -> int:
        """The length of the body's open-layout array on this rank."""
        ...

    def open_to_entries(self, open_array: np.ndarray) -> np.ndarray:
        """Collective: the entries of the body's open-layout array, on every rank."""
        ...

    def entries_to_open(self, entries: np.ndarray) -> np.ndarray: ...

    def moved_patches(self, shift: np.ndarray, touched: np.ndarray, margin: float) -> np.ndarray:
        """``(patches,)`` the patches whose points can have moved by ``margin`` or more under the entry
        shift ``shift (N, 3)``, and those moved by an entry in ``touched (N,)``."""
        ...

    def motion(self, start: np.ndarray, end: np.ndarray, dt: float, gap: float) -> ShellMotion:
        """The body's straight-line motion ``start -> end`` (entries) over a step ``dt``, as the narrow
        phase sees it (a shell's :class:`ShellMotion`, or one with the same interface)."""
        ...


class ShellContactSurface:
    """A shell's discretization as a :class:`ContactSurface`: its entries, and its patches' Bezier
    nets (a patch point is a convex combination of its net's control points).

    Args:
        discretization: the shell's discretization (``patches``: its :class:`PatchLayout`).
        open_size: the length of the shell's open-layout array on this rank.
    """

    def __init__(self, discretization: Discretization, open_size: int):
        self.discretization = discretization
        self.open_size = open_size
        self.layout = discretization.patches
        self._patch_entries = self.layout.patch_entries()

    @property
    def num_entries(self) -> int:
        return self.discretization.num_entries

    @property
    def num_patches(self) -> int:
        return self.layout.grid.n1 * self.layout.grid.n2

    def open_to_entries(self, open_array: np.ndarray) -> np.ndarray:
        return self.discretization.open_to_entries(open_array)

    def entries_to_open(self, entries: np.ndarray) -> np.ndarray:
        return self.discretization.entries_to_open(entries)

    def motion(self, start: np.ndarray, end: np.ndarray, dt: float, gap: float) -> ShellMotion:
        return ShellMotion.of(self.layout, start, end, dt, gap)

    def moved_patches(self, shift: np.ndarray, touched: np.ndarray, margin: float) -> np.ndarray:
        nets = self.layout.bezier_nets(shift)
        moved = np.linalg.norm(nets, axis=-1).reshape(len(nets), -1).max(axis=1) >= margin
        return moved | touched[self._patch_entries].any(axis=1)


class StackedEntries:
    """Every body's flat entries ``(N_b, 3)`` side by side, ``(sum N_b, 3)``, and the stacked
    open-layout array of the solver's state (every body's owned + ghost values, body after body).

    Args:
        surfaces: each body's :class:`ContactSurface`.
    """

    def __init__(self, surfaces: Sequence[ContactSurface]):
        self.surfaces = tuple(surfaces)
        for surface in self.surfaces:
            if not isinstance(surface, ContactSurface):
                raise TypeError(f"{surface!r} is not a contact surface (bhem_hpc.contact.bodies.ContactSurface)")
        #: where each body's entries start, ``(bodies + 1,)``
        self.entry_offsets = np.cumsum([0] + [s.num_entries for s in self.surfaces])
        #: where each body's open array starts, ``(bodies + 1,)``
        self.open_offsets = np.cumsum([0] + [s.open_size for s in self.surfaces])
        #: where each body's patches start in a mask over every body's patches, ``(bodies + 1,)``
        self.patch_offsets = np.cumsum([0] + [s.num_patches for s in self.surfaces])

    @property
    def num_entries(self) -> int:
        return int(self.entry_offsets[-1])

    def entries(self, stacked: np.ndarray, body: int) -> np.ndarray:
        """Body ``body``'s rows of stacked entries."""
        return stacked[self.entry_offsets[body] : self.entry_offsets[body + 1]]

    def open_to_entries(self, open_array: np.ndarray) -> np.ndarray:
        """Collective: the stacked entries of a stacked open-layout array, on every rank."""
        o = self.open_offsets
        return np.concatenate([s.open_to_entries(open_array[o[b] : o[b + 1]]) for b, s in enumerate(self.surfaces)])

    def entries_to_open(self, entries: np.ndarray) -> np.ndarray:
        """The stacked open-layout array of stacked entries."""
        return np.concatenate([s.entries_to_open(self.entries(entries, b)) for b, s in enumerate(self.surfaces)])

    def patches_to_retest(self, shift: np.ndarray, touched: np.ndarray, margin: float) -> np.ndarray:
        """Mask over every body's patches: those whose points can have moved by ``margin`` or more
        under the entry shift ``shift (N, 3)``, and those moved by an entry in ``touched (N,)``."""
        return np.concatenate([s.moved_patches(self.entries(shift, b), self.entries(touched, b), margin)
                               for b, s in enumerate(self.surfaces)])  # fmt: skip


class BodiesDetector:
    """All contacts of one step's motion of several bodies, for one rank's share of the samples:
    each body's detector (its colliders and itself), and every body's samples against every other
    body's patches, for the bodies with a detector.

    Args:
        entries: the bodies' stacked entries.
        detectors: each body's detector (None: a body without contact effects).
        frictions: each body's Coulomb coefficient (a pair's is :func:`pair_friction`).
        joined: pairs of bodies joined into one shell (patches of a joint or a seam): they do not
            meet each other.
    """

    def __init__(
        self, entries: StackedEntries, detectors: Sequence[ContactDetector | None], frictions: Sequence[float],
        joined: Sequence[tuple[int, int]] = (),
    ):  # fmt: skip
        if len(detectors) != len(entries.surfaces) or len(frictions) != len(detectors):
            raise ValueError(f"one detector and one friction coefficient per body: {len(entries.surfaces)} "
                             f"bodies, {len(detectors)} detectors, {len(frictions)} coefficients")  # fmt: skip
        if len(detectors) > MAX_BODIES:
            raise InputError(f"contact of {len(detectors)} bodies: at most {MAX_BODIES} bodies meet each other")
        self.entries = entries
        self.detectors = tuple(detectors)
        self.frictions = tuple(float(f) for f in frictions)
        self.joined = {frozenset(pair) for pair in joined}
        self.width = max(16, *(d.samples.index.shape[1] for d in self.detectors if d is not None))

    @property
    def in_contact(self) -> list[int]:
        """The bodies with a detector."""
        return [b for b, d in enumerate(self.detectors) if d is not None]

    @property
    def num_samples(self) -> int:
        """Sample points tested per step: every body's, plus its samples once per other body."""
        bodies = self.in_contact
        return sum(self.detectors[b].num_samples + (len(bodies) - 1) * len(self.detectors[b].samples.patch)
                   for b in bodies)  # fmt: skip

    def detect(
        self, start: np.ndarray, end: np.ndarray, time: float, dt: float, gap: float,
        rank: int = 0, size: int = 1, patches: np.ndarray | None = None,
    ) -> Contacts:  # fmt: skip
        """Contacts of the motion ``start -> end`` (stacked entries) over ``[time, time + dt]``, in the
        stacked numbering; ``patches`` a mask over every body's patches (:meth:`ContactDetector.detect`)."""
        e, p = self.entries, self.entries.patch_offsets
        bodies = self.in_contact
        parts = []
        for b in bodies:
            own = None if patches is None else patches[p[b] : p[b + 1]]
            found = self.detectors[b].detect(e.entries(start, b), e.entries(end, b), time, dt, gap, rank, size, own)
            offset = int(e.entry_offsets[b])
            parts.append(found.stacked(offset, offset, b * GROUP_KEYS, self.width))
        if len(bodies) > 1:
            parts += self._between(start, end, dt, gap, rank, size, patches)
        return Contacts.concatenate(parts)

    def _between(self, start: np.ndarray, end: np.ndarray, dt: float, gap: float, rank: int, size: int,
                 patches: np.ndarray | None) -> list[Contacts]:  # fmt: skip
        """Every body's samples (this rank's share) against every other body's patches, stacked."""
        e, p = self.entries, self.entries.patch_offsets
        bodies, count = self.in_contact, len(self.detectors)
        motions = {b: e.surfaces[b].motion(e.entries(start, b), e.entries(end, b), dt, gap) for b in bodies}
        parts = []
        for a in bodies:
            samples = self.detectors[a].samples
            rows = np.arange(rank, len(samples.patch), size)
            positions = (samples.positions(motions[a].start, rows), samples.positions(motions[a].end, rows))
            for b in bodies:
                if b == a or frozenset((a, b)) in self.joined:
                    continue
                mask = None if patches is None else np.concatenate([patches[p[a] : p[a + 1]], patches[p[b] : p[b + 1]]])
                friction = pair_friction(self.frictions[a], self.frictions[b])
                found = body_contacts(samples, rows, positions, e.surfaces[a].num_patches, motions[b], mask, friction,
                                      0)  # fmt: skip
                group = count + a * count + b
                parts.append(found.stacked(int(e.entry_offsets[a]), int(e.entry_offsets[b]), group * GROUP_KEYS,
                                           self.width))  # fmt: skip
        return parts


def lattice_segments(surface: Surface, per_side: int) -> tuple[np.ndarray, np.ndarray]:
    """The sample lattice of a shell's surface (``per_side`` samples per patch side), neighbours joined
    by straight segments: ``(starts (L, 3), ends (L, 3))``."""
    axes = lattice_axes(surface.grid, per_side)
    return _joined(surface.evaluate(*np.meshgrid(*axes, indexing="ij")).x)  # (L1, L2, 3)


def part_segments(parts: Sequence[NurbsSurface], per_side: int) -> tuple[np.ndarray, np.ndarray]:
    """The sample lattices of a solid's NURBS parts (``per_side`` samples per knot span and side),
    neighbours joined by straight segments: ``(starts (L, 3), ends (L, 3))``."""
    pieces = []
    for part in parts:
        axes = [span_lattice(direction, per_side) for direction in (part.u, part.v)]
        u, v = np.meshgrid(*axes, indexing="ij")
        pieces.append(_joined(part.evaluate(u.ravel(), v.ravel())[0].reshape(*u.shape, 3)))
    return np.concatenate([p[0] for p in pieces]), np.concatenate([p[1] for p in pieces])


def _joined(lattice: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Segments between neighbours of a lattice ``(L1, L2, 3)``."""
    starts = np.concatenate([lattice[:-1].reshape(-1, 3), lattice[:, :-1].reshape(-1, 3)])
    ends = np.concatenate([lattice[1:].reshape(-1, 3), lattice[:, 1:].reshape(-1, 3)])
    return starts, ends


def lattice_crossing(segments: tuple[np.ndarray, np.ndarray], nets: np.ndarray) -> np.ndarray | None:
    """A point ``(3,)`` where the ``segments`` of one body's sample lattice (:func:`lattice_segments`,
    :func:`part_segments`) cross another body's patches ``nets`` (polynomial ``(P, 4, 4, 3)`` or
    homogeneous ``(P, 4, 4, 4)``), or None: a test that two bodies are apart, as detection sees them
    (a crossing shorter than a lattice segment's width can go unseen).
    A segment crosses a patch when its ends lie on opposite sides of (or one on) the tangent plane at
    the closest point of an end that projects inside the patch, and the point where it meets that
    plane projects inside the patch too: exact for segments short against the patch's curvature."""
    starts, ends = segments
    boxes = control_points(nets)
    patch, segment = overlapping_pairs(swept_boxes(boxes, boxes, 0.0), swept_boxes(starts, ends, 0.0))
    if not len(patch):
        return None
    # the ends' closest points on each candidate patch: a segment crosses the patch when its ends lie
    # on opposite sides of the tangent plane at a closest point inside the patch
    _, foot0, normal0, inside0 = project_to_patches(nets[patch], starts[segment])
    _, foot1, normal1, inside1 = project_to_patches(nets[patch], ends[segment])
    foot, normal = np.where(inside0[:, None], foot0, foot1), np.where(inside0[:, None], normal0, normal1)
    side0 = np.einsum("kc,kc->k", starts[segment] - foot, normal)
    side1 = np.einsum("kc,kc->k", ends[segment] - foot, normal)
    crossing = np.flatnonzero((inside0 | inside1) & (side0 * side1 <= 0.0))
    if not len(crossing):
        return None
    # where the segment meets that tangent plane: a crossing if it projects inside the patch (not
    # beside the patch's boundary)
    fraction = np.where(side0[crossing] == side1[crossing], 0.0,
                        side0[crossing] / np.where(side0[crossing] == side1[crossing], 1.0,
                                                   side0[crossing] - side1[crossing]))  # fmt: skip
    meeting = starts[segment[crossing]] + fraction[:, None] * (ends[segment[crossing]] - starts[segment[crossing]])
    _, _, _, inside = project_to_patches(nets[patch[crossing]], meeting)
    if not inside.any():
        return None
    return meeting[np.flatnonzero(inside)[0]]

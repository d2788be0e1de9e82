"""Contact detection between time steps (paper §6.2), numpy only: every contact of one step's motion.

A time step moves the shell's entries linearly from ``start`` to ``end`` (implicit Euler: every
point moves on a straight line over the step). :class:`ContactDetector` finds every contact of that
motion within a push-out distance ``gap`` (:class:`~bhem_hpc.contact.contacts.Contacts`, linear in
the entries):

* shell samples against analytic colliders (plane, sphere, cylinder, capsule), analytic times of
  impact (:mod:`.collider_contacts`);
* collider points against shell patches - triangle-mesh vertices, patch-model samples, needle tips,
  a sphere's centre - by closest-point projection at both ends of the step (:mod:`.closest_points`);
* self-collision: samples against the other patches through a hash-grid broad phase
  (:mod:`.broad_phase`), and folds within a patch's 3 x 3 neighbourhood (:mod:`.self_contact`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bhem_hpc.collision.colliders import Collider
from bhem_hpc.contact.collider_contacts import point_contacts, simple_collider_contacts
from bhem_hpc.contact.contacts import Contacts
from bhem_hpc.contact.samples import ShellMotion, ShellSamples
from bhem_hpc.contact.self_contact import folded_self_contacts, self_contacts
from bhem_hpc.errors import InputError
from bhem_hpc.geometry.surface import PatchLayout


@dataclass(frozen=True)
class ColliderEntry:
    """A collider with the friction coefficient of its contact with the shell (``friction``: the
    kinetic one; ``static_friction``: the static one of contact by IPC, None: the kinetic one);
    ``key``: where a scene gave it (``colliders[2]``, ``colliders[0] (capsule 7)``), for messages."""

    collider: Collider
    friction: float = 0.0
    static_friction: float | None = None
    key: str = "a collider"

    def __post_init__(self) -> None:
        for value in (self.friction, self.static_friction):
            if value is not None and not (math.isfinite(value) and value >= 0):
                raise InputError(f"friction coefficient must be a finite number >= 0, got {value!r}")


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
            raise InputError(f"self_friction must be a finite number >= 0, got {self_friction!r}")
        self.layout = layout
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
        parts = colliders_contacts(self.colliders, self.samples, motion, time, rank, size, patches)
        every_row = np.arange(rank, len(self.samples.patch), size)
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


def colliders_contacts(
    colliders: Sequence[ColliderEntry], samples: ShellSamples, motion: ShellMotion, time: float, rank: int, size: int,
    patches: np.ndarray | None,
) -> list[Contacts]:  # fmt: skip
    """A body's contacts with its colliders over the step from ``time`` (``motion``: a shell's, or a
    solid's with rational patches): its ``samples`` against analytic colliders, the colliders' own
    points (mesh vertices, a sphere's centre, needle tips) against its patches; this rank's
    interleaved share of the samples and of the points. ``patches``: a ``(patches,)`` mask of the
    patches (and their samples) to test (None: all)."""
    every_row = np.arange(rank, len(samples.patch), size)
    rows = every_row if patches is None else every_row[patches[samples.patch[every_row]]]
    positions = (samples.positions(motion.start, rows), samples.positions(motion.end, rows))
    patch_boxes = None  # swept boxes of the patches, shared by every collider's points
    parts = []
    for source, entry in enumerate(colliders):
        collider = collider_at(entry.collider, time)
        if collider.analytic:
            parts.append(simple_collider_contacts(collider, 2 * source, samples, rows, positions, motion.dt, motion.gap,
                                                  entry.friction))  # fmt: skip
        points, clearance = collider.contact_points()
        if len(points):
            if patch_boxes is None:
                patch_boxes = motion.patch_boxes(0.0)
            point_rows = np.arange(rank, len(points), size)
            parts.append(point_contacts(points, collider.velocity, clearance, 2 * source + 1, point_rows, motion,
                                        entry.friction, patches, patch_boxes))  # fmt: skip
    return parts


def collider_at(collider: Collider, time: float) -> Collider:
    """The collider translated to where its constant velocity has taken it at ``time``."""
    if time == 0.0 or not np.any(collider.velocity):
        return collider
    return collider.translated(time * collider.velocity)

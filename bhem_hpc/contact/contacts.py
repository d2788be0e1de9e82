"""The contact record: each contact a linear function of the shell's entries (flat nodal data)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields, replace

import numpy as np

from bhem_hpc.contact.samples import ShellSamples


@dataclass(frozen=True)
class Contacts:
    """``k`` contacts, each a linear function of the shell's entries ``(N, 3)`` (Hermite nodal data or
    B-spline control points).

    Attributes:
        key: ``(k,)`` deterministic order (source, sample) so every rank builds the same rows.
        index_a, weights_a: ``(k, K)`` the shell point ``a`` (``K`` entries per point: 16 for Hermite
            patches, ``(p + 1)^2`` for B-splines; see the patch layout's ``point_entries``).
        index_b, weights_b: ``(k, K)`` a second shell point (self-contact), weights 0 otherwise.
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

    def stacked(self, offset_a: int, offset_b: int, key_offset: int, width: int) -> Contacts:
        """The contacts in a numbering of several bodies' entries: point ``a``'s entries shifted by
        ``offset_a``, point ``b``'s by ``offset_b``, keys by ``key_offset``, and the points padded to
        ``width`` entries with zero weights (bodies' discretizations have different widths)."""
        if not len(self):
            return self  # (concatenate drops it)

        def padded(array: np.ndarray, value: float) -> np.ndarray:
            return np.pad(array, ((0, 0), (0, width - array.shape[1])), constant_values=value)

        return replace(
            self,
            key=self.key + key_offset,
            index_a=padded(self.index_a + offset_a, offset_a),
            weights_a=padded(self.weights_a, 0.0),
            index_b=padded(self.index_b + offset_b, offset_b),
            weights_b=padded(self.weights_b, 0.0),
        )

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


def no_second_point(count: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Index and weights ``(count, width)`` of an absent second point (zero weights)."""
    return np.zeros((count, width), np.int64), np.zeros((count, width))


def nearest_per_point(point: np.ndarray, separation: np.ndarray) -> np.ndarray:
    """Rows of the smallest separation for each distinct ``point`` (a point touches one patch)."""
    order = np.lexsort((separation, point))
    return order[np.r_[True, point[order][1:] != point[order][:-1]]]


def sample_contacts(
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

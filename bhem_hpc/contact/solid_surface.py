"""A NURBS solid's boundary as impulse contact sees it (numpy only): samples and rational Bezier
patches of its parts, linear in its control points, and its contacts with the scene's colliders.

A solid's flat entries are its control points ``(n_q, 3)`` (every part's, part after part). A part's
point at ``(u, v)`` is ``sum_i R_i(u, v) q_i`` with the rational basis ``R`` of fixed weights: a
linear map of the entries, as a shell's samples are of its nodal data, so the contact rows and the
response (:mod:`bhem_hpc.contact.response`) treat both alike. A part's patches are its rational
Bezier patches (one per pair of knot spans), degree-elevated to bicubic homogeneous nets
``(w x, w y, w z, w)``: the weighted control points are linear in the entries and the weights stay
fixed, so the narrow phase (:mod:`bhem_hpc.contact.closest_points`) projects onto them and sweeps
them as it does a shell's polynomial nets. Every patch point is a convex combination of the
control points that span it (positive weights), which bounds how far a patch moves.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bhem_hpc.collision.bezier import _bernstein
from bhem_hpc.contact.contacts import Contacts
from bhem_hpc.contact.detection import ColliderEntry, colliders_contacts
from bhem_hpc.contact.samples import ShellMotion, ShellSamples
from bhem_hpc.errors import InputError
from bhem_hpc.geometry.nurbs import NurbsSurface, span_lattice

#: The narrow phase works on bicubic nets: parts up to this degree are elevated to it exactly.
NET_DEGREE = 3


def elevation_matrix(degree: int, target: int = NET_DEGREE) -> np.ndarray:
    """``(target + 1, degree + 1)``: the Bernstein coefficients of degree ``target`` of a polynomial
    from its degree-``degree`` ones (repeated degree elevation)."""
    matrix = np.eye(degree + 1)
    for p in range(degree, target):
        step = np.zeros((p + 2, p + 1))
        i = np.arange(p + 2)
        step[i[1:], i[1:] - 1] = i[1:] / (p + 1)
        step[i[:-1], i[:-1]] = 1.0 - i[:-1] / (p + 1)
        matrix = step @ matrix
    return matrix


class SolidContactSurface:
    """The parts of a solid as linear maps of its control points, with samples for contact.

    Args:
        parts: the solid's NURBS parts, in the order of its control points.
        per_side: samples per knot span and direction.

    Attributes:
        samples: ``patch (S,)`` the flat patch of each sample (patches part after part, in each part
            ``span_u * spans_v + span_v``), ``local (S, 2)`` its coordinates in that patch,
            ``index, weights (S, K)`` its control points and rational basis values (``K`` the largest
            ``(p + 1)(q + 1)``; padded with weight 0).
        patch_points: ``(patches, K)`` the control points that span each patch (padded by repeating).
    """

    def __init__(self, parts: Sequence[NurbsSurface], per_side: int):
        if not (isinstance(per_side, int) and 1 <= per_side <= 16):
            raise InputError(f"samples_per_side must be an integer in 1..16, got {per_side!r}")
        for part in parts:
            if max(part.degrees) > NET_DEGREE:
                raise InputError(f"{part.name}: degrees {part.degrees}: impulse contact takes parts of degree at most "
                                 f"{NET_DEGREE} (contact method 'ipc' takes any)")  # fmt: skip
        self.parts = tuple(parts)
        self.offsets = np.r_[0, np.cumsum([p.control[..., 0].size for p in self.parts])]
        width = max((p.degrees[0] + 1) * (p.degrees[1] + 1) for p in self.parts)
        patch, local, index, weights, supports, maps = [], [], [], [], [], []
        first_patch = 0
        for part, offset in zip(self.parts, self.offsets[:-1], strict=True):
            u, v = (a.ravel() for a in np.meshgrid(span_lattice(part.u, per_side), span_lattice(part.v, per_side),
                                                   indexing="ij"))  # fmt: skip
            (su, tu), (sv, tv) = part.u.locate(u), part.v.locate(v)
            spans_v = len(part.v.spans)
            part_index, part_weights = part.basis_matrix(u, v)
            pad = width - part_index.shape[1]
            patch.append(first_patch + su * spans_v + sv)
            local.append(np.stack([tu, tv], axis=1))
            index.append(np.pad(part_index + offset, ((0, 0), (0, pad)), mode="edge"))
            weights.append(np.pad(part_weights, ((0, 0), (0, pad))))
            supports.append(self._supports(part, offset, width))
            maps.append(self._net_maps(part, width))
            first_patch += len(part.u.spans) * spans_v
        self.samples = ShellSamples(np.concatenate(patch), np.concatenate(local), np.concatenate(index),
                                    np.concatenate(weights))  # fmt: skip
        self.patch_points = np.concatenate(supports)
        #: ``(patches, 16, K)``: net point ``j`` of patch ``p`` is ``sum_k maps[p, j, k] (q_k, 1)`` in
        #: homogeneous coordinates, ``q_k`` the patch's control points ``patch_points[p]``
        self.net_maps = np.concatenate(maps)
        self.net_weights = self.net_maps.sum(axis=2)  # (patches, 16): the nets' fixed weights

    @staticmethod
    def _supports(part: NurbsSurface, offset: int, width: int) -> np.ndarray:
        """``(patches, width)`` the control points spanning each of the part's patches."""
        p, q = part.degrees
        columns = part.control.shape[1]
        rows = []
        for ku in part.u.spans:
            for kv in part.v.spans:
                i, j = np.meshgrid(np.arange(ku - p, ku + 1), np.arange(kv - q, kv + 1), indexing="ij")
                rows.append((offset + i * columns + j).ravel())
        return np.pad(np.array(rows), ((0, 0), (0, width - (p + 1) * (q + 1))), mode="edge")

    @staticmethod
    def _net_maps(part: NurbsSurface, width: int) -> np.ndarray:
        """``(patches, 16, width)``: each bicubic homogeneous net point as weights of the patch's
        control points, the control points' NURBS weights included."""
        p, q = part.degrees
        elevate_u, elevate_v = elevation_matrix(p), elevation_matrix(q)
        maps = []
        for a, ku in enumerate(part.u.spans):
            for b, kv in enumerate(part.v.spans):
                # Bezier point (i, j) of the span is sum_kl Eu[k, i] Ev[l, j] Pw_kl; elevated: L Bezier
                along_u = elevate_u @ part.u.extraction[a].T  # (4, p + 1)
                along_v = elevate_v @ part.v.extraction[b].T  # (4, q + 1)
                weights = part.weights[ku - p : ku + 1, kv - q : kv + 1].ravel()
                maps.append(np.kron(along_u, along_v) * weights)
        return np.pad(np.array(maps), ((0, 0), (0, 0), (0, width - (p + 1) * (q + 1))))

    def nets(self, entries: np.ndarray) -> np.ndarray:
        """Homogeneous bicubic nets ``(patches, 4, 4, 4)`` of control points ``entries (n_q, 3)``."""
        weighted = np.einsum("pjk,pkc->pjc", self.net_maps, entries[self.patch_points])
        return np.concatenate([weighted, self.net_weights[..., None]], axis=2).reshape(-1, 4, 4, 4)

    def point_entries(self, patch: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The control points and rational basis values ``(n, K)`` of the points at local ``uv (n, 2)``
        of patches ``patch (n,)``: ``x = sum_j B_j (u, v) H_j / sum_j B_j (u, v) w_j``."""
        bernstein = np.einsum("ni,nj->nij", _bernstein(uv[:, 0]), _bernstein(uv[:, 1])).reshape(-1, 16)
        coefficients = np.einsum("nj,njk->nk", bernstein, self.net_maps[patch])
        return self.patch_points[patch], coefficients / coefficients.sum(axis=1, keepdims=True)

    def parts_at(self, entries: np.ndarray) -> list[NurbsSurface]:
        """The parts with control points ``entries (n_q, 3)`` (a deformed solid's boundary)."""
        return [part.with_control(entries[a:b].reshape(part.control.shape))
                for part, a, b in zip(self.parts, self.offsets[:-1], self.offsets[1:], strict=True)]  # fmt: skip

    def motion(self, start: np.ndarray, end: np.ndarray, dt: float, gap: float) -> SolidMotion:
        """The solid's straight-line motion ``start -> end`` (control points) over a step ``dt``."""
        return SolidMotion(self, start, end, self.nets(start), self.nets(end), dt, gap)

    @property
    def num_entries(self) -> int:
        return int(self.offsets[-1])

    @property
    def num_patches(self) -> int:
        return len(self.patch_points)

    @property
    def open_size(self) -> int:
        """A solid's open-layout array: every control point's three coordinates, on every rank."""
        return 3 * self.num_entries

    def open_to_entries(self, open_array: np.ndarray) -> np.ndarray:
        """The control points ``(n_q, 3)`` of the solid's state (every control point on every rank)."""
        return np.asarray(open_array, dtype=float).reshape(-1, 3)

    def entries_to_open(self, entries: np.ndarray) -> np.ndarray:
        return np.asarray(entries, dtype=float).reshape(-1)

    def moved_patches(self, shift: np.ndarray, touched: np.ndarray, margin: float) -> np.ndarray:
        """``(patches,)`` the patches a control point of which moved by ``margin`` or more under
        ``shift (n_q, 3)`` (a bound on how far any of the patch's points moved), or is ``touched (n_q,)``."""
        moved = np.linalg.norm(shift, axis=1) >= margin
        return (moved | touched)[self.patch_points].any(axis=1)


@dataclass(frozen=True)
class SolidMotion(ShellMotion):
    """A solid's straight-line motion over one step, as detection sees it: a
    :class:`~bhem_hpc.contact.samples.ShellMotion` whose ``layout`` is the solid's
    :class:`SolidContactSurface`, its nets homogeneous ``(patches, 4, 4, 4)``."""

    layout: SolidContactSurface

    def patch_point_entries(self, patch: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.layout.point_entries(patch, uv)


class SolidContactDetector:
    """A solid's contacts with the scene's colliders over one step: its samples' straight-line
    motions against analytic colliders (plane, sphere, cylinder, capsule), the colliders' points
    (a mesh's vertices, a sphere's centre, needle tips) against its rational patches.

    Args:
        surface: the solid's parts and samples.
        colliders: the colliders with their friction coefficients.
    """

    def __init__(self, surface: SolidContactSurface, colliders: Sequence[ColliderEntry]):
        self.surface = surface
        self.samples = surface.samples
        self.colliders = tuple(colliders)

    def starting_problem(self, entries: np.ndarray) -> str | None:
        """What keeps the solid at control points ``entries (n_q, 3)`` from starting its motion (a
        sample inside an analytic collider, which the response would push through it), or None."""
        positions = self.samples.positions(entries, np.arange(len(self.samples.patch)))
        for entry in self.colliders:
            if not entry.collider.analytic:
                continue
            distance, _ = entry.collider.signed_distance(positions, 0.0)
            inside = np.flatnonzero(distance < 0.0)
            if len(inside):
                deepest = inside[np.argmin(distance[inside])]
                return (f"{len(inside)} of its {len(positions)} boundary samples start inside {entry.key}, the deepest "
                        f"at {np.array2string(positions[deepest], precision=4)} m, {-distance[deepest]:.3g} m deep")
        return None

    @property
    def num_samples(self) -> int:
        """Sample points tested per step: the solid's samples (against analytic colliders) plus the
        colliders' points."""
        count = sum(len(e.collider.contact_points()[0]) for e in self.colliders)
        return count + (len(self.samples.patch) if any(e.collider.analytic for e in self.colliders) else 0)

    def detect(
        self, start: np.ndarray, end: np.ndarray, time: float, dt: float, gap: float, rank: int = 0, size: int = 1,
        patches: np.ndarray | None = None,
    ) -> Contacts:  # fmt: skip
        """Contacts of the motion ``start -> end`` (control points ``(n_q, 3)``) over ``[time, time + dt]``,
        for this rank's interleaved share of the samples and collider points (``patches``: a
        ``(patches,)`` mask of the patches, and their samples, to test; None: all)."""
        motion = self.surface.motion(start, end, dt, gap)
        return Contacts.concatenate(colliders_contacts(self.colliders, self.samples, motion, time, rank, size, patches))

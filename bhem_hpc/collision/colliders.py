"""Colliders: rigid shapes a shell can touch (paper §6.2), each static or moving at constant velocity.

Simple shapes (plane, sphere, infinite cylinder, capsule) give signed distances and outward normals
of points and the earliest time of impact of linearly moving points (:meth:`time_of_impact`,
``t in [0, 1]`` over the step). Complex shapes - triangle meshes and Bezier-patch models - are
sampled the other way round: their vertices (or patch samples) are tested against the shell's
patches with :func:`~bhem_hpc.collision.ccd.point_patch_toi`. numpy only; meshes are read with meshio.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import ClassVar, Protocol

import numpy as np

from bhem_hpc.collision.bezier import evaluate
from bhem_hpc.collision.tessellation import cylinder_mesh, patch_model_mesh, ring_count
from bhem_hpc.errors import UserError

PATCH_FILE_FORMAT = "bhem-bezier-patches"
#: Precision of a capsule's sampled-and-bisected time of impact, as a fraction of the step.
TOI_TOLERANCE = 1e-12


class Collider(Protocol):
    """What contact detection asks of a collider (each moves rigidly at a constant ``velocity``).

    ``analytic`` colliders (plane, sphere, cylinder, capsule) also give :meth:`signed_distance` and
    :meth:`time_of_impact`, against which the shell's samples are tested; every collider may have
    points of its own (:meth:`contact_points`) that are tested against the shell's patches.
    """

    velocity: np.ndarray
    analytic: ClassVar[bool]

    def translated(self, shift: np.ndarray) -> Collider:
        """The collider moved by ``shift (3,)``."""
        ...

    def contact_points(self) -> tuple[np.ndarray, float]:
        """Points ``(P, 3)`` tested against the shell's patches and the clearance around each."""
        ...

    def swept_bounds(self, dt: float) -> np.ndarray | None:
        """A box ``(2, 3)`` holding the collider over a step of ``dt``; None if unbounded."""
        ...


class Tessellated(Protocol):
    """A collider that barrier contact meets as a triangle mesh (every collider but a plane, which
    ipc-toolkit meets exactly)."""

    velocity: np.ndarray

    def tessellation(self, max_sagitta: float, cover: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(vertices (V, 3), triangles (T, 3))`` on the collider, the triangles within
        ``max_sagitta`` of it; an unbounded collider is meshed over (at least) the part the box
        ``cover (2, 3)`` (min and max corners: where the bodies are) can reach."""
        ...


def _no_points() -> tuple[np.ndarray, float]:
    return np.zeros((0, 3)), 0.0


def _swept_box(ends: np.ndarray, velocity: np.ndarray, radius: float, dt: float) -> np.ndarray:
    """Box ``(2, 3)`` of the points ``ends (k, 3)`` over a step, grown by ``radius``."""
    ends = np.concatenate([ends, ends + dt * velocity])
    return np.stack([ends.min(axis=0) - radius, ends.max(axis=0) + radius])


class ColliderError(UserError, ValueError):
    """An invalid collider: bad geometry, an empty or broken mesh, NaN/Inf."""


def _vector(name: str, value, length: int = 3) -> np.ndarray:
    array = np.asarray(value, dtype=float).reshape(-1)
    if array.shape != (length,) or not np.all(np.isfinite(array)):
        raise ColliderError(f"{name} must be {length} finite numbers, got {value!r}")
    return array


def _first_root(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Smallest root in [0, 1] of ``a t^2 + b t + c`` (``c <= 0`` means contact at t = 0); inf if none."""
    t = np.full(np.shape(c), np.inf)
    inside = c <= 0
    t[inside] = 0.0
    linear = ~inside & (np.abs(a) < 1e-300)
    with np.errstate(divide="ignore", invalid="ignore"):
        root = np.where(b != 0, -c / b, np.inf)
        t[linear] = np.where((root[linear] >= 0) & (root[linear] <= 1), root[linear], np.inf)
        quadratic = ~inside & ~linear
        disc = b * b - 4 * a * c
        sq = np.sqrt(np.maximum(disc, 0.0))
        r1 = (-b - sq) / (2 * a)
        r2 = (-b + sq) / (2 * a)
        lo, hi = np.minimum(r1, r2), np.maximum(r1, r2)
        first = np.where(lo >= 0, lo, np.where(hi >= 0, hi, np.inf))
    ok = quadratic & (disc >= 0) & (first <= 1)
    t[ok] = first[ok]
    return t


def _round_distance(offset: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Signed distances and outward normals for offsets ``(N, 3)`` from a centre (sphere) or axis."""
    length = np.linalg.norm(offset, axis=1)
    return length - radius, offset / np.maximum(length, 1e-300)[:, None]


def _round_time_of_impact(offset: np.ndarray, motion: np.ndarray, radius: float) -> np.ndarray:
    """First fraction of the step at which ``|offset + s motion| = radius`` (rows of ``(N, 3)``)."""
    return _first_root((motion * motion).sum(1), 2 * (offset * motion).sum(1), (offset * offset).sum(1) - radius**2)


@dataclass(frozen=True)
class Plane:
    """Half-space ``(x - point) . normal >= 0`` is outside; the plane moves at ``velocity``."""

    point: np.ndarray
    normal: np.ndarray
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    analytic: ClassVar[bool] = True

    def translated(self, shift: np.ndarray) -> Plane:
        return replace(self, point=self.point + shift)

    def contact_points(self) -> tuple[np.ndarray, float]:
        return _no_points()

    def swept_bounds(self, dt: float) -> np.ndarray | None:
        return None

    def __post_init__(self) -> None:
        n = _vector("plane normal", self.normal)
        if np.linalg.norm(n) == 0:
            raise ColliderError("plane normal is zero")
        object.__setattr__(self, "normal", n / np.linalg.norm(n))
        object.__setattr__(self, "point", _vector("plane point", self.point))
        object.__setattr__(self, "velocity", _vector("plane velocity", self.velocity))

    def signed_distance(self, points: np.ndarray, t: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Distances ``(N,)`` (negative inside) and outward normals ``(N, 3)`` at time ``t``."""
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        d = (points - self.point - t * self.velocity) @ self.normal
        return d, np.broadcast_to(self.normal, points.shape)

    def time_of_impact(self, start: np.ndarray, end: np.ndarray, dt: float, gap: float = 0.0) -> np.ndarray:
        """Earliest ``t / dt in [0, 1]`` at which points moving from ``start`` to ``end`` come within
        ``gap`` of the surface (0 if already there); ``inf`` where they do not. Shapes ``(N, 3)``."""
        d0, _ = self.signed_distance(start, 0.0)
        d1, _ = self.signed_distance(end, dt)
        return _first_root(np.zeros_like(d0), d1 - d0, d0 - gap)


@dataclass(frozen=True)
class Sphere:
    """Ball of ``radius`` about ``center``, moving at ``velocity`` and, after time ``spin_from``
    [s], spinning about its centre at angular velocity ``spin`` [rad/s] (which leaves its shape
    where it is and moves its surface: friction by IPC drags what touches it, :meth:`surface_velocity`)."""

    center: np.ndarray
    radius: float
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    spin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    spin_from: float = 0.0
    analytic: ClassVar[bool] = True

    def translated(self, shift: np.ndarray) -> Sphere:
        return replace(self, center=self.center + shift)

    def contact_points(self) -> tuple[np.ndarray, float]:
        return (self.center.reshape(1, 3), float(self.radius))  # the deepest point of each nearby patch

    def swept_bounds(self, dt: float) -> np.ndarray | None:
        return _swept_box(self.center[None], self.velocity, self.radius, dt)

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", _vector("sphere center", self.center))
        object.__setattr__(self, "velocity", _vector("sphere velocity", self.velocity))
        object.__setattr__(self, "spin", _vector("sphere spin", self.spin))
        if not (isinstance(self.spin_from, int | float) and math.isfinite(self.spin_from)):
            raise ColliderError(f"sphere spin_from must be a finite time [s], got {self.spin_from!r}")
        if not (isinstance(self.radius, int | float) and math.isfinite(self.radius) and self.radius > 0):
            raise ColliderError(f"sphere radius must be a finite number > 0, got {self.radius!r}")

    def signed_distance(self, points: np.ndarray, t: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        return _round_distance(points - self.center - t * self.velocity, self.radius)

    def surface_velocity(self, points: np.ndarray, time: float = math.inf) -> np.ndarray:
        """The velocity ``(n, 3)`` [m/s] of the sphere's material at ``points`` ``(n, 3)`` at ``time``
        [s] (spinning after ``spin_from``)."""
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        spin = self.spin if time > self.spin_from else np.zeros(3)
        return self.velocity + np.cross(spin, points - self.center)

    def time_of_impact(self, start: np.ndarray, end: np.ndarray, dt: float, gap: float = 0.0) -> np.ndarray:
        start = np.asarray(start, dtype=float).reshape(-1, 3)
        end = np.asarray(end, dtype=float).reshape(-1, 3)
        # relative position at the start and relative motion over the step
        return _round_time_of_impact(start - self.center, (end - start) - dt * self.velocity, self.radius + gap)

    def tessellation(self, max_sagitta: float, cover: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.triangles(max_sagitta)

    def triangles(self, max_sagitta: float) -> tuple[np.ndarray, np.ndarray]:
        """An icosphere on the sphere: ``(vertices (V, 3), triangles (T, 3))`` whose flat faces lie
        at most ``max_sagitta`` inside it (the subdivisions of the icosahedron that need; at most
        :data:`MAX_SPHERE_SUBDIVISIONS`, else :class:`ColliderError`)."""
        for level in range(MAX_SPHERE_SUBDIVISIONS + 1):
            unit, faces = icosphere(level)
            edge = np.linalg.norm(unit[faces[:, 0]] - unit[faces[:, 1]], axis=1).max() * self.radius
            # a face's deepest point lies at most its circumradius^2 / (2 R) inside, edge / sqrt(3) bounding it
            if edge**2 / (6.0 * self.radius) <= max_sagitta:
                return self.center + self.radius * unit, faces
        raise ColliderError(f"a sphere of radius {self.radius:g} needs more than {MAX_SPHERE_SUBDIVISIONS} "
                            f"subdivisions to lie within {max_sagitta:g} of its triangles")  # fmt: skip


#: Subdivisions of the icosahedron a sphere's triangles may take (20 * 4^7 = 327680 triangles).
MAX_SPHERE_SUBDIVISIONS = 7
#: Vertices around a capsule's rings its triangles may take.
MAX_CAPSULE_AROUND = 512


def capsule_mesh(a: np.ndarray, b: np.ndarray, radius: float, around: int,
                 rings: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Vertices on the capsule of ``radius`` about segment ``a``-``b``: ``around`` per ring,
    ``rings`` rings per round end from its equator towards its pole, and the two poles. Returns
    ``(vertices (V, 3), triangles (T, 3), on_caps (T,) bool)``: the band between the equators, then
    quads and fans on the ends; outward (counter-clockwise seen from outside)."""
    axis = np.asarray(b, dtype=float) - np.asarray(a, dtype=float)
    w = axis / np.linalg.norm(axis)
    u = np.cross(w, [1.0, 0.0, 0.0] if abs(w[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(w, u)
    theta = 2.0 * np.pi * np.arange(around) / around
    radial = np.cos(theta)[:, None] * u + np.sin(theta)[:, None] * v  # (around, 3)
    latitudes = 0.5 * np.pi * np.arange(rings) / rings  # the equator first
    # rings from the pole at a (latitude -> -pi/2) up to the pole at b
    levels = [(a, -phi) for phi in latitudes[::-1]] + [(b, phi) for phi in latitudes]
    ring_points = [end + radius * (np.cos(phi) * radial + np.sin(phi) * w) for end, phi in levels]
    vertices = np.concatenate([*ring_points, [np.asarray(a) - radius * w, np.asarray(b) + radius * w]])
    nxt = (np.arange(around) + 1) % around
    faces, on_caps = [], []
    for k in range(len(levels) - 1):
        low, high = k * around + np.arange(around), (k + 1) * around + np.arange(around)
        high_next, low_next = (k + 1) * around + nxt, k * around + nxt
        faces += [np.stack([low, low_next, high_next], axis=1), np.stack([low, high_next, high], axis=1)]
        on_caps += [np.full(2 * around, k != rings - 1)]  # the band joins the two equators
    south, north = len(vertices) - 2, len(vertices) - 1
    last = (len(levels) - 1) * around
    faces += [np.stack([np.full(around, south), nxt, np.arange(around)], axis=1),
              np.stack([last + np.arange(around), last + nxt, np.full(around, north)], axis=1)]  # fmt: skip
    on_caps += [np.ones(2 * around, dtype=bool)]
    return vertices, np.concatenate(faces).astype(np.int64), np.concatenate(on_caps)


def icosphere(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """The unit icosahedron subdivided ``subdivisions`` times, every vertex on the unit sphere:
    ``(vertices (V, 3), triangles (T, 3))``, ``T = 20 * 4^subdivisions``, outward (counter-clockwise)."""
    golden = (1.0 + math.sqrt(5.0)) / 2.0
    vertices = np.array([[-1, golden, 0], [1, golden, 0], [-1, -golden, 0], [1, -golden, 0],
                         [0, -1, golden], [0, 1, golden], [0, -1, -golden], [0, 1, -golden],
                         [golden, 0, -1], [golden, 0, 1], [-golden, 0, -1], [-golden, 0, 1]], dtype=float)  # fmt: skip
    faces = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
                      [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
                      [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]], dtype=np.int64)  # fmt: skip
    vertices /= np.linalg.norm(vertices, axis=1, keepdims=True)
    for _ in range(subdivisions):
        edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
        unique, inverse = np.unique(edges, axis=0, return_inverse=True)
        middle = vertices[unique[:, 0]] + vertices[unique[:, 1]]
        middle /= np.linalg.norm(middle, axis=1, keepdims=True)
        m = len(vertices) + inverse.reshape(3, -1)  # the midpoints of edges 01, 12, 20 of each face
        a, b, c = faces.T
        faces = np.concatenate([np.stack([a, m[0], m[2]], 1), np.stack([b, m[1], m[0]], 1),
                                np.stack([c, m[2], m[1]], 1), np.stack([m[0], m[1], m[2]], 1)])  # fmt: skip
        vertices = np.concatenate([vertices, middle])
    return vertices, faces.astype(np.int32)


@dataclass(frozen=True)
class Cylinder:
    """Infinite solid cylinder of ``radius`` about the line through ``point`` along ``axis``, moving."""

    point: np.ndarray
    axis: np.ndarray
    radius: float
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    analytic: ClassVar[bool] = True

    def translated(self, shift: np.ndarray) -> Cylinder:
        return replace(self, point=self.point + shift)

    def contact_points(self) -> tuple[np.ndarray, float]:
        return _no_points()

    def swept_bounds(self, dt: float) -> np.ndarray | None:
        return None

    def __post_init__(self) -> None:
        axis = _vector("cylinder axis", self.axis)
        if np.linalg.norm(axis) == 0:
            raise ColliderError("cylinder axis is zero")
        object.__setattr__(self, "axis", axis / np.linalg.norm(axis))
        object.__setattr__(self, "point", _vector("cylinder point", self.point))
        object.__setattr__(self, "velocity", _vector("cylinder velocity", self.velocity))
        if not (isinstance(self.radius, int | float) and math.isfinite(self.radius) and self.radius > 0):
            raise ColliderError(f"cylinder radius must be a finite number > 0, got {self.radius!r}")

    def _radial(self, vectors: np.ndarray) -> np.ndarray:
        return vectors - np.outer(vectors @ self.axis, self.axis)

    def signed_distance(self, points: np.ndarray, t: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        return _round_distance(self._radial(points - self.point - t * self.velocity), self.radius)

    def time_of_impact(self, start: np.ndarray, end: np.ndarray, dt: float, gap: float = 0.0) -> np.ndarray:
        start = np.asarray(start, dtype=float).reshape(-1, 3)
        end = np.asarray(end, dtype=float).reshape(-1, 3)
        motion = self._radial((end - start) - dt * self.velocity)
        return _round_time_of_impact(self._radial(start - self.point), motion, self.radius + gap)

    def tessellation(self, max_sagitta: float, cover: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A capped cylinder over the part of the axis the box ``cover (2, 3)`` spans, and one
        diagonal of it beyond either end (:func:`~bhem_hpc.collision.tessellation.cylinder_mesh`)."""
        return cylinder_mesh(self.point, self.axis, self.radius, max_sagitta, cover)


@dataclass(frozen=True)
class Capsule:
    """Points within ``radius`` of the segment ``a``-``b`` (a needle with a round tip), moving."""

    a: np.ndarray
    b: np.ndarray
    radius: float
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    analytic: ClassVar[bool] = True

    def translated(self, shift: np.ndarray) -> Capsule:
        return replace(self, a=self.a + shift, b=self.b + shift)

    def contact_points(self) -> tuple[np.ndarray, float]:
        return (np.stack([self.a, self.b]), float(self.radius))  # its two round tips

    def swept_bounds(self, dt: float) -> np.ndarray | None:
        return _swept_box(np.stack([self.a, self.b]), self.velocity, self.radius, dt)

    def __post_init__(self) -> None:
        for name in ("a", "b", "velocity"):
            object.__setattr__(self, name, _vector(f"capsule {name}", getattr(self, name)))
        if np.allclose(self.a, self.b):
            raise ColliderError("capsule end points coincide")
        if not (math.isfinite(self.radius) and self.radius > 0):
            raise ColliderError(f"capsule radius must be a finite number > 0, got {self.radius!r}")

    def signed_distance(self, points: np.ndarray, t: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        a = self.a + t * self.velocity
        axis = self.b - self.a
        s = np.clip(((points - a) @ axis) / (axis @ axis), 0.0, 1.0)
        offset = points - (a + s[:, None] * axis)
        length = np.linalg.norm(offset, axis=1)
        return length - self.radius, offset / np.maximum(length, 1e-300)[:, None]

    def tessellation(self, max_sagitta: float, cover: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.triangles(max_sagitta)

    def triangles(self, max_sagitta: float) -> tuple[np.ndarray, np.ndarray]:
        """A triangle mesh on the capsule ``(vertices (V, 3), triangles (T, 3))`` whose flat faces lie
        at most ``max_sagitta`` inside it: ``around`` vertices per ring, a band of two rings along
        the straight part, ``around / 4`` rings per round end (at most :data:`MAX_CAPSULE_AROUND`
        around, else :class:`ColliderError`)."""
        # the fewest vertices around whose chords keep the band within the sagitta, then more
        # (a tenth at a time) until the ends' faces are within it too
        around = ring_count(self.radius, max_sagitta)
        while around <= MAX_CAPSULE_AROUND:
            vertices, faces, on_caps = capsule_mesh(self.a, self.b, self.radius, around, max(1, around // 4))
            # the band's faces lie within the ring's chords; a cap face within its circumcircle's cap
            corners = vertices[faces[on_caps]]
            sides = [np.linalg.norm(corners[:, i] - corners[:, (i + 1) % 3], axis=1) for i in range(3)]
            area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
            circumradius = sides[0] * sides[1] * sides[2] / (4.0 * np.maximum(area, 1e-300))
            cap = self.radius - np.sqrt(np.maximum(self.radius**2 - circumradius**2, 0.0))
            band = self.radius * (1.0 - math.cos(math.pi / around))
            if max(band, cap.max(initial=0.0)) <= max_sagitta:
                return vertices, faces
            around = math.ceil(1.1 * around)
        raise ColliderError(f"a capsule of radius {self.radius:g} needs more than {MAX_CAPSULE_AROUND} vertices "
                            f"around to lie within {max_sagitta:g} of its triangles")  # fmt: skip

    def _distance(self, points: np.ndarray, shift: np.ndarray) -> np.ndarray:
        """Distances of ``points (N, 3)`` to the capsule translated by ``shift (N, 3)``."""
        axis = self.b - self.a
        rel = points - self.a - shift
        s = np.clip((rel @ axis) / (axis @ axis), 0.0, 1.0)
        return np.linalg.norm(rel - s[:, None] * axis, axis=1) - self.radius

    def time_of_impact(
        self, start: np.ndarray, end: np.ndarray, dt: float, gap: float = 0.0, samples: int = 64
    ) -> np.ndarray:
        """First time (fraction of the step) at which the distance reaches ``gap``: sampled, then
        bisected. Conservative for contacts longer than one sample; a point that crosses the whole
        capsule between two samples (moving more than its diameter in 1/``samples`` of a step) can
        be missed - the documented limit of this collider."""
        start = np.asarray(start, dtype=float).reshape(-1, 3)
        end = np.asarray(end, dtype=float).reshape(-1, 3)
        motion = end - start

        def distance(fraction: np.ndarray, rows: np.ndarray) -> np.ndarray:
            return self._distance(
                start[rows] + fraction[:, None] * motion[rows], fraction[:, None] * dt * self.velocity
            )

        out = np.full(len(start), np.inf)
        everyone = np.arange(len(start))
        at_start = distance(np.zeros(len(start)), everyone)
        out[at_start <= gap] = 0.0
        # The distance changes by at most `speed` per unit fraction of the step (the point's and the
        # capsule's travel), so a point at distance d at fraction f cannot touch before
        # f + (d - gap) / speed: samples before that are skipped (they would find no contact).
        speed = np.linalg.norm(motion, axis=1) + dt * np.linalg.norm(self.velocity)
        earliest = np.where(at_start > gap, (at_start - gap) / np.maximum(speed, 1e-300), 0.0)
        halvings = math.ceil(math.log2(1.0 / (samples * TOI_TOLERANCE)))
        for k in range(1, samples + 1):
            fraction = k / samples
            pending = ~np.isfinite(out) & (earliest <= 1.0)
            if not pending.any():
                break
            rows = np.flatnonzero(pending & (earliest <= fraction))
            if not len(rows):
                continue
            now = distance(np.full(len(rows), fraction), rows)
            touching = now <= gap
            earliest[rows[~touching]] = fraction + (now[~touching] - gap) / np.maximum(speed[rows[~touching]], 1e-300)
            rows = rows[touching]
            lo, hi = np.full(len(rows), (k - 1) / samples), np.full(len(rows), fraction)
            for _ in range(halvings):  # to TOI_TOLERANCE of the step
                mid = 0.5 * (lo + hi)
                inside = distance(mid, rows) <= gap
                hi, lo = np.where(inside, mid, hi), np.where(inside, lo, mid)
            out[rows] = lo
        return out


@dataclass(frozen=True)
class TriangleMesh:
    """A closed or open triangle-mesh obstacle: its vertices are the collision samples (§6.2)."""

    vertices: np.ndarray
    triangles: np.ndarray
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    name: str = "mesh"
    analytic: ClassVar[bool] = False

    def translated(self, shift: np.ndarray) -> TriangleMesh:
        return replace(self, vertices=self.vertices + shift)

    def contact_points(self) -> tuple[np.ndarray, float]:
        return (self.vertices, 0.0)

    def swept_bounds(self, dt: float) -> np.ndarray | None:
        return None

    def __post_init__(self) -> None:
        v = np.asarray(self.vertices, dtype=float)
        f = np.asarray(self.triangles)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0 or f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
            raise ColliderError(f"{self.name}: mesh is empty or not triangles (vertices {v.shape}, cells {f.shape})")
        if not np.all(np.isfinite(v)):
            bad = int(np.argwhere(~np.isfinite(v))[0, 0])
            raise ColliderError(f"{self.name}: vertex {bad} has NaN/Inf coordinates {v[bad].tolist()}")
        if f.min() < 0 or f.max() >= len(v):
            raise ColliderError(f"{self.name}: triangle indices outside 0..{len(v) - 1}")
        edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        _, counts = np.unique(edges, axis=0, return_counts=True)
        if np.any(counts > 2):
            raise ColliderError(
                f"{self.name}: non-manifold mesh ({int(np.sum(counts > 2))} edges shared by > 2 triangles)"
            )
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "triangles", f.astype(np.int64))
        object.__setattr__(self, "velocity", _vector(f"{self.name} velocity", self.velocity))

    def tessellation(self, max_sagitta: float, cover: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.vertices, self.triangles

    @classmethod
    def read(cls, path: str | Path, velocity=(0.0, 0.0, 0.0)) -> TriangleMesh:
        """Read any meshio-supported file (OBJ, STL, PLY, ...) keeping its triangles."""
        import meshio

        try:
            mesh = meshio.read(path)
        except Exception as exc:  # meshio raises many types for unreadable files
            raise ColliderError(f"{path}: cannot read mesh ({exc})") from exc
        triangles = [c.data for c in mesh.cells if c.type == "triangle"]
        points = np.asarray(mesh.points, dtype=float)
        points = points[:, :3] if points.ndim == 2 and points.shape[1] >= 3 else np.zeros((0, 3))
        cells = np.concatenate(triangles) if triangles else np.zeros((0, 3), dtype=int)
        return cls(points, cells, velocity, str(path))


@dataclass(frozen=True)
class PatchModel:
    """A rigid parametric obstacle made of bicubic Bezier patches ``(P, 4, 4, 3)``."""

    nets: np.ndarray
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    analytic: ClassVar[bool] = False

    def translated(self, shift: np.ndarray) -> PatchModel:
        return replace(self, nets=self.nets + shift)

    def contact_points(self) -> tuple[np.ndarray, float]:
        return (self.samples(), 0.0)

    def swept_bounds(self, dt: float) -> np.ndarray | None:
        return None

    def __post_init__(self) -> None:
        nets = np.asarray(self.nets, dtype=float)
        if nets.ndim != 4 or nets.shape[1:] != (4, 4, 3) or len(nets) == 0:
            raise ColliderError(f"patch model must have nets of shape (P, 4, 4, 3), got {nets.shape}")
        if not np.all(np.isfinite(nets)):
            raise ColliderError("patch model contains NaN/Inf control points")
        spans = np.ptp(nets.reshape(len(nets), -1, 3), axis=1)
        flat = np.sort(spans, axis=1)[:, 1] == 0  # a zero-area control net spans at most a line
        if np.any(flat):
            raise ColliderError(f"patch {int(np.argmax(flat))} of the patch model has a zero-area control net")
        object.__setattr__(self, "nets", nets)
        object.__setattr__(self, "velocity", _vector("patch model velocity", self.velocity))

    def tessellation(self, max_sagitta: float, cover: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Its patches on a grid whose triangles lie within ``max_sagitta`` of them
        (:func:`~bhem_hpc.collision.tessellation.patch_model_mesh`)."""
        return patch_model_mesh(self.nets, max_sagitta)

    def samples(self, per_side: int = 4) -> np.ndarray:
        """Sample points ``(P * per_side^2, 3)`` on every patch (the collider's side of §6.2)."""
        g = (np.arange(per_side) + 0.5) / per_side
        u, v = np.meshgrid(g, g, indexing="ij")
        return np.concatenate([evaluate(net, u, v).reshape(-1, 3) for net in self.nets])

    def save(self, path: str | Path) -> None:
        np.savez(path, format=np.array(PATCH_FILE_FORMAT), version=np.array(1), nets=self.nets)

    @classmethod
    def load(cls, path: str | Path) -> PatchModel:
        try:
            with np.load(path, allow_pickle=False) as data:
                if str(data["format"]) != PATCH_FILE_FORMAT:
                    raise ColliderError(
                        f"{path}: key 'format' is {str(data['format'])!r}, expected {PATCH_FILE_FORMAT!r}"
                    )
                return cls(data["nets"])
        except (OSError, KeyError, ValueError) as exc:
            if isinstance(exc, ColliderError):
                raise
            raise ColliderError(f"{path}: cannot read patch file ({exc})") from exc

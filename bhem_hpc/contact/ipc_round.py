"""Round colliders (spheres, capsules, cylinders) met by the IPC barrier through their exact signed
distance instead of a tessellation; numpy only.

Each collision-mesh vertex ``x`` within ``dhat`` of such a collider is one barrier pair, as a vertex
and a plane are in ipc-toolkit: its energy is ``kappa b(g^2, dhat^2)`` with ipc-toolkit's clamped log
barrier ``b`` (:func:`clamped_log_barrier`) and the gap ``g = d(x) - delta``, ``d`` the collider's
signed distance. The offset ``delta`` keeps the mesh's flat triangles out of the curved shape: a
triangle whose vertices lie at least ``delta`` outside a ball of radius ``R`` (or a cylinder, a
capsule) stays outside it if ``delta >= sqrt(R^2 + rho^2) - R``, ``rho`` the triangle's circumradius
(the circle through its vertices bounds how deep its plane cuts in). ``rho`` is the mesh's largest
at rest times :data:`STRETCH_ALLOWANCE`.

The signed distance of a convex shape is a convex function, so along a straight motion of a vertex
its gap is convex in the step fraction: Newton's iteration from the start never passes the first
fraction where the gap falls to a given level (each tangent lies below the curve), which makes the
line-search step bound (:meth:`RoundObstacles.step_bound`) exact up to its tolerance and safe at any
iteration count. The barrier's Hessian is ``kappa (4 g^2 b'' + 2 b') n n^T`` plus a curvature term
``2 kappa b' g grad(n)``; ``b' < 0`` and the curvature of a convex shape is positive semi-definite, so
projecting the pair's Hessian to positive semi-definite (clamping, as ipc-toolkit's CLAMP does)
keeps ``max(kappa (4 g^2 b'' + 2 b'), 0) n n^T``, a 3 x 3 block per vertex.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import numpy as np

#: The mesh's triangles may grow to this many times their rest size (their circumradius) before
#: one could cut into a round collider between its vertices.
STRETCH_ALLOWANCE = 1.25
#: A vertex's step bound stops where this fraction of its gap at the start is left (as a vertex
#: stops short of a translating plane, :data:`~bhem_hpc.contact.ipc_contribution.PLANE_GAP_KEPT`).
GAP_KEPT = 0.1
#: Newton iterations of the step bound along one vertex's motion, and the relative gap error it stops at.
STEP_BOUND_ITERATIONS = 32
STEP_BOUND_TOLERANCE = 1e-6


@runtime_checkable
class RoundCollider(Protocol):
    """A convex collider of constant ``radius`` about a point or segment or line (sphere, capsule,
    cylinder) with an exact signed distance: ``(distances (n,), outward unit normals (n, 3))`` of
    points ``(n, 3)`` at time ``t``."""

    radius: float
    velocity: np.ndarray

    def signed_distance(self, points: np.ndarray, t: float = 0.0) -> tuple[np.ndarray, np.ndarray]: ...


def clamped_log_barrier(s: np.ndarray, s_hat: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ipc-toolkit's clamped log barrier ``b(s) = -(s - s_hat)^2 ln(s / s_hat)`` for ``0 < s < s_hat``
    (0 beyond) and its first and second derivatives, each shaped like ``s``."""
    s = np.asarray(s, dtype=float)
    active = (s > 0.0) & (s < s_hat)
    value, first, second = np.zeros_like(s), np.zeros_like(s), np.zeros_like(s)
    a = s[active]
    log, rest = np.log(a / s_hat), a - s_hat
    value[active] = -rest * rest * log
    first[active] = -2.0 * rest * log - rest * rest / a
    second[active] = -2.0 * log - 4.0 * rest / a + rest * rest / (a * a)
    return value, first, second


def circumradii(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Circumradius ``(T,)`` of each triangle ``(T, 3)`` of ``vertices`` ``(V, 3)`` (inf if degenerate)."""
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    ab, bc, ca = (np.linalg.norm(p - q, axis=1) for p, q in ((a, b), (b, c), (c, a)))
    twice_area = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    with np.errstate(divide="ignore"):
        return np.where(twice_area > 0, ab * bc * ca / (2.0 * np.maximum(twice_area, 1e-300)), np.inf)


def allowed_circumradius(vertices: np.ndarray, triangles: np.ndarray) -> float:
    """``rho`` [m]: :data:`STRETCH_ALLOWANCE` times the largest circumradius of a mesh's triangles
    ``(T, 3)`` at rest (vertices ``(V, 3)``; 0 without triangles)."""
    radii = circumradii(np.asarray(vertices, dtype=float).reshape(-1, 3), np.asarray(triangles).reshape(-1, 3))
    return STRETCH_ALLOWANCE * float(radii.max(initial=0.0))


def round_offset(radius: float, circumradius: float) -> float:
    """The gap ``sqrt(R^2 + rho^2) - R`` [m] that keeps a triangle of circumradius ``rho`` whose
    vertices are that far outside a round shape of radius ``R`` out of it."""
    return math.sqrt(radius * radius + circumradius * circumradius) - radius


class RoundObstacles:
    """Static round colliders met through their signed distance (see the module).

    Args:
        colliders: the round colliders, each at rest (no translation).
        indices: each one's collider index in the scene.
        circumradius: ``rho`` [m], :func:`allowed_circumradius` of the collision mesh.
        dhat: the barrier's activation distance [m].
    """

    def __init__(self, colliders: Sequence[RoundCollider], indices: Sequence[int], circumradius: float,
                 dhat: float):  # fmt: skip
        self.colliders = list(colliders)
        self.indices = [int(i) for i in indices]
        self.dhat = float(dhat)
        #: each collider's offset ``delta`` [m] (see the module)
        self.offsets = np.array([round_offset(float(c.radius), circumradius) for c in self.colliders])

    def __len__(self) -> int:
        return len(self.colliders)

    def gaps(self, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Gaps ``g = d - delta`` ``(C, V)`` [m] of ``vertices`` ``(V, 3)`` from each collider and
        the outward normals there ``(C, V, 3)``."""
        vertices = np.asarray(vertices, dtype=float).reshape(-1, 3)
        gaps = np.empty((len(self), len(vertices)))
        normals = np.empty((len(self), len(vertices), 3))
        for k, collider in enumerate(self.colliders):
            distance, normals[k] = collider.signed_distance(vertices)
            gaps[k] = distance - self.offsets[k]
        return gaps, normals

    def _near(self, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The pairs within dhat: ``(collider (k,), vertex (k,))``, their gaps ``(k,)`` and normals ``(k, 3)``."""
        gaps, normals = self.gaps(vertices)
        collider, vertex = np.nonzero(gaps < self.dhat)
        return np.stack([collider, vertex]), gaps[collider, vertex], normals[collider, vertex]

    def energy(self, vertices: np.ndarray, stiffness: float) -> float:
        """``kappa sum b(g^2, dhat^2)`` over the pairs [J] (inf where a vertex reached a collider's offset)."""
        _, gaps, _ = self._near(vertices)
        if np.any(gaps <= 0.0):
            return math.inf
        value, _, _ = clamped_log_barrier(gaps * gaps, self.dhat**2)
        return float(stiffness * value.sum())

    def gradient(self, vertices: np.ndarray, stiffness: float) -> np.ndarray:
        """The energy's gradient ``(V, 3)`` [N]: ``kappa b'(g^2) 2 g n`` at each vertex of a pair."""
        vertices = np.asarray(vertices, dtype=float).reshape(-1, 3)
        (_, vertex), gaps, normals = self._near(vertices)
        _, first, _ = clamped_log_barrier(gaps * gaps, self.dhat**2)
        out = np.zeros_like(vertices)
        np.add.at(out, vertex, (stiffness * 2.0 * first * gaps)[:, None] * normals)
        return out

    def hessian(self, vertices: np.ndarray, stiffness: float) -> np.ndarray:
        """The projected Hessian's diagonal blocks ``(V, 3, 3)`` [N/m]: ``max(kappa (4 g^2 b'' + 2 b'),
        0) n n^T`` at each vertex of a pair (see the module)."""
        vertices = np.asarray(vertices, dtype=float).reshape(-1, 3)
        (_, vertex), gaps, normals = self._near(vertices)
        s = gaps * gaps
        _, first, second = clamped_log_barrier(s, self.dhat**2)
        along = np.maximum(stiffness * (4.0 * s * second + 2.0 * first), 0.0)
        out = np.zeros((len(vertices), 3, 3))
        np.add.at(out, vertex, along[:, None, None] * normals[:, :, None] * normals[:, None, :])
        return out

    def min_distance(self, vertices: np.ndarray) -> float:
        """The smallest gap [m] within dhat (inf if none)."""
        _, gaps, _ = self._near(vertices)
        return float(gaps.min(initial=math.inf))

    def behind(self, vertices: np.ndarray) -> tuple[int, int, float, float] | None:
        """The first pair whose gap is not positive: ``(collider index in the scene, vertex, gap,
        the collider's offset)``, or None."""
        gaps, _ = self.gaps(vertices)
        collider, vertex = np.nonzero(gaps <= 0.0)
        if not len(collider):
            return None
        k = int(collider[0])
        return self.indices[k], int(vertex[0]), float(gaps[k, vertex[0]]), float(self.offsets[k])

    def step_bound(self, start: np.ndarray, end: np.ndarray) -> float:
        """The largest fraction ``t`` in [0, 1] of the straight motion ``start -> end`` ``(V, 3)`` of
        the vertices along which no vertex's gap falls below :data:`GAP_KEPT` of its gap at the
        start (Newton's iteration on each convex gap, from the start; see the module)."""
        start = np.asarray(start, dtype=float).reshape(-1, 3)
        motion = np.asarray(end, dtype=float).reshape(-1, 3) - start
        travel = np.linalg.norm(motion, axis=1)
        bound = 1.0
        for k, collider in enumerate(self.colliders):
            distance, _ = collider.signed_distance(start)
            gap = distance - self.offsets[k]
            target = GAP_KEPT * gap
            reach = np.flatnonzero(gap - travel < target)  # the others cannot close in that far
            bound = min(bound, self._first_fraction(collider, self.offsets[k], start[reach], motion[reach],
                                                    target[reach]))  # fmt: skip
        return bound

    @staticmethod
    def _first_fraction(collider: RoundCollider, offset: float, start: np.ndarray, motion: np.ndarray,
                        target: np.ndarray) -> float:  # fmt: skip
        """The smallest fraction (at most 1) at which some row's gap reaches its ``target``."""
        fraction = np.zeros(len(start))
        active = np.ones(len(start), dtype=bool)
        for _ in range(STEP_BOUND_ITERATIONS):
            if not np.any(active):
                break
            rows = np.flatnonzero(active)
            distance, normal = collider.signed_distance(start[rows] + fraction[rows, None] * motion[rows])
            excess = distance - offset - target[rows]
            slope = np.einsum("ij,ij->i", normal, motion[rows])
            # a gap that no longer falls never reaches its target (convex); one within tolerance has
            done = (slope >= 0.0) | (excess <= STEP_BOUND_TOLERANCE * np.abs(target[rows]))
            moving = ~done
            fraction[rows[moving]] = np.minimum(fraction[rows[moving]] - excess[moving] / slope[moving], 1.0)
            stopped = rows[moving][fraction[rows[moving]] >= 1.0]
            active[rows[done]] = False
            active[stopped] = False
            fraction[rows[done & (slope >= 0.0)]] = 1.0
        return float(fraction.min(initial=1.0))

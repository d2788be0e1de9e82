"""Lagged friction inside the Newton solve: ipc-toolkit's smooth friction dissipative potential on
the barrier's collision mesh (numpy, SciPy and ipctk only).

Over a time step of ``dt`` from vertices ``x_n``, the contacts within ``dhat`` at ``x_n``, their
normal forces ``lambda_k`` (the barrier's) and tangent bases ``T_k`` are held fixed (lagged, as IPC
does), and the incremental potential gains ``dt D(v)`` with ``v = (x - x_n) / dt`` and

    D(v) = sum_k mu_k lambda_k f0(|T_k^T (v - v_other)|; eps_v)

(ipc-toolkit's ``FrictionPotential``: ``f0`` grows like the slip speed above ``eps_v`` and smoothly
to zero below it, so slip slower than ``eps_v`` counts as sticking). Its gradient ``dD/dv`` is the
friction force (magnitude ``mu lambda`` while slipping) and its Hessian ``d2D/dv2 / dt``. A
collider's vertices move at the collider's surface velocity (a spinning sphere's ``w x (p - c)``):
the relative tangential velocity is what friction opposes.

Coefficients are per pair of surfaces (a body, a collider mesh, a plane): between two bodies the
geometric mean of theirs (as the impulse response does), within a body its own, between a body and
a collider the collider's; each pair has a static and a kinetic one.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse

#: ipc-toolkit's sticking speed ``eps_v`` [m/s] by default (IPC's choice).
DEFAULT_EPS_V = 1e-3
#: The sticking speeds a scene may set [m/s].
EPS_V_RANGE = (1e-8, 10.0)


@dataclass(frozen=True)
class Friction:
    """Coulomb coefficients of a surface: ``kinetic`` (sliding) and ``static`` (None: the kinetic)."""

    kinetic: float = 0.0
    static: float | None = None

    def __post_init__(self) -> None:
        for name, value in (("kinetic", self.kinetic), ("static", self.static)):
            if value is not None and not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} friction coefficient must be a finite number >= 0, got {value!r}")

    @property
    def static_coefficient(self) -> float:
        return float(self.kinetic if self.static is None else self.static)

    @property
    def any(self) -> bool:
        return self.kinetic > 0 or self.static_coefficient > 0

    def blended(self, other: Friction) -> Friction:
        """Between two bodies: the geometric mean of each coefficient."""
        return Friction(math.sqrt(self.kinetic * other.kinetic),
                        math.sqrt(self.static_coefficient * other.static_coefficient))  # fmt: skip


#: No friction.
FRICTIONLESS = Friction()


def surface_friction(settings: Any) -> Friction:
    """The coefficients of a body's contact settings or a collider entry (``friction``,
    ``static_friction``: a :class:`~bhem_hpc.scene.records.SceneContact` or
    :class:`~bhem_hpc.contact.detection.ColliderEntry`)."""
    return Friction(float(settings.friction), settings.static_friction)


def pair_table(bodies: Sequence[Friction], colliders: Sequence[Friction]) -> np.ndarray:
    """The coefficients of every pair of surfaces ``(S, S, 2)`` (kinetic, static): surfaces are the
    bodies, then the colliders; two colliders never meet (zero)."""
    surfaces = len(bodies) + len(colliders)
    table = np.zeros((surfaces, surfaces, 2))
    for a, first in enumerate(bodies):
        for b, second in enumerate(bodies):
            pair = first if a == b else first.blended(second)
            table[a, b] = pair.kinetic, pair.static_coefficient
        for c, collider in enumerate(colliders):
            table[a, len(bodies) + c] = table[len(bodies) + c, a] = collider.kinetic, collider.static_coefficient
    return table


class LaggedFriction:
    """ipc-toolkit's friction potential over one time step at a time (see the module).

    Args:
        owners: the surface of each vertex of the collision mesh ``(V,)`` (bodies' vertices, then
            the collider meshes' vertices).
        plane_owners: the surface of each of the mesh's planes ``(P,)``.
        table: :func:`pair_table` ``(S, S, 2)``.
        surface_velocity: the vertices' velocities ``(V, 3)`` [m/s] at a time [s] where they are
            a collider's (rows of body vertices unused).
        num_body_vertices: the bodies' vertices come first, this many.
        eps_v: the sticking speed [m/s].
    """

    def __init__(self, owners: np.ndarray, plane_owners: np.ndarray, table: np.ndarray,
                 surface_velocity: Callable[[float], np.ndarray], num_body_vertices: int,
                 eps_v: float = DEFAULT_EPS_V):  # fmt: skip
        import ipctk  # loaded with IPC contact only

        low, high = EPS_V_RANGE
        if not (isinstance(eps_v, int | float) and low <= eps_v <= high):
            raise ValueError(f"eps_v (sticking speed) must be in [{low:g}, {high:g}] m/s, got {eps_v!r}")
        self._ipctk = ipctk
        self.owners, self.plane_owners = np.asarray(owners, np.int64), np.asarray(plane_owners, np.int64)
        self.table = np.asarray(table, dtype=float)
        self.surface_velocity = surface_velocity
        self._surface = np.zeros((len(self.owners), 3))
        self.num_body_vertices = int(num_body_vertices)
        self.eps_v = float(eps_v)
        self.potential = ipctk.FrictionPotential(self.eps_v)
        self.collisions = ipctk.TangentialCollisions()
        self._start = np.zeros((0, 3))
        self.dt = 0.0

    @property
    def active(self) -> bool:
        """Whether the lagged step has contacts that rub."""
        return self.dt > 0 and len(self.collisions) > 0

    def lag(self, mesh: Any, start: np.ndarray, normal_collisions: Any, barrier: Any, time: float, dt: float) -> None:
        """Hold the contacts of ``normal_collisions`` at vertices ``start`` ``(V, 3)`` (their
        ``barrier`` normal forces and tangent bases) for a step from ``time`` of ``dt`` [s], each
        with its pair's coefficients, the colliders' surfaces moving as at the step's end."""
        self._start, self.dt = np.array(start, dtype=float), float(dt)
        self._surface = np.asarray(self.surface_velocity(time + dt), dtype=float).reshape(-1, 3)
        self.collisions = self._ipctk.TangentialCollisions()
        if not len(normal_collisions):
            return
        self.collisions.build(mesh, np.asfortranarray(self._start), normal_collisions, barrier, 0.0)
        planes = [(np.asarray(p.normal()).ravel(), float(p.offset())) for p in mesh.planes]
        edges, faces = mesh.edges, mesh.faces
        for k in range(len(self.collisions)):
            collision = self.collisions[k]
            ids = np.asarray(collision.vertex_ids(edges, faces))
            first = self.owners[ids[0]]
            if isinstance(collision, self._ipctk.PlaneVertexTangentialCollision):
                second = self.plane_owners[_plane_index(collision.plane, planes)]
            else:  # the other side: an edge's second vertex pair, or the vertex/edge/face after the first vertex
                is_edge_edge = isinstance(collision, self._ipctk.EdgeEdgeTangentialCollision)
                second = self.owners[ids[2] if is_edge_edge else ids[1]]
            collision.mu_k, collision.mu_s = self.table[first, second]
        # the potential reads the lagged effective coefficients, which the build set from its mu
        self.collisions.reset_lagged_anisotropic_friction_coefficients()

    def _velocities(self, vertices: np.ndarray) -> np.ndarray:
        velocity = np.array(self._surface)
        count = self.num_body_vertices
        velocity[:count] = (np.asarray(vertices)[:count] - self._start[:count]) / self.dt
        return np.asfortranarray(velocity)

    def energy(self, mesh: Any, vertices: np.ndarray) -> float:
        """``dt D(v)`` [J] at vertices ``(V, 3)``."""
        if not self.active:
            return 0.0
        return self.dt * float(self.potential(self.collisions, mesh, self._velocities(vertices)))

    def gradient(self, mesh: Any, vertices: np.ndarray) -> np.ndarray:
        """``dD/dv`` at vertices ``(V, 3)``: the friction forces' opposite ``(V, 3)`` [N]."""
        if not self.active:
            return np.zeros((len(vertices), 3))
        return np.asarray(self.potential.gradient(self.collisions, mesh, self._velocities(vertices))).reshape(-1, 3)

    def hessian(self, mesh: Any, vertices: np.ndarray) -> scipy.sparse.csr_matrix:
        """``d2D/dv2 / dt`` ``(3V, 3V)``, each contact's block clamped to positive semi-definite."""
        size = 3 * len(vertices)
        if not self.active:
            return scipy.sparse.csr_matrix((size, size))
        method = self._ipctk.PSDProjectionMethod.CLAMP
        hessian = self.potential.hessian(self.collisions, mesh, self._velocities(vertices), method)
        return scipy.sparse.csr_matrix(hessian) / self.dt


def _plane_index(plane: Any, planes: list[tuple[np.ndarray, float]]) -> int:
    """Which of the mesh's ``planes`` ``(normal, offset)`` a collision's plane is."""
    normal, offset = np.asarray(plane.normal()).ravel(), float(plane.offset())
    gaps = [np.abs(n - normal).max() + abs(o - offset) for n, o in planes]
    return int(np.argmin(gaps))

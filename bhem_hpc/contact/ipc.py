"""Incremental potential contact (IPC) on collision meshes embedded in the bodies, through
ipc-toolkit (``ipctk``); numpy, SciPy and ipctk only (no PETSc, no dolfinx).

Each body's collision mesh is a lattice of points on its exact surface, triangulated
(:func:`collision_lattice`); its vertices are a fixed sparse linear map of the body's flat entries
(Hermite nodal data or B-spline control points, ``(N, 3)``): ``vertices = point_map @ entries``,
with the map of :meth:`~bhem_hpc.bodies.body.Body.point_map`. The lattice's resolution is the
user's choice, apart from the patches. :class:`IpcContact` stacks every body's mesh and static
obstacle meshes into one ipc-toolkit ``CollisionMesh`` whose displacement map is the block-diagonal
of the bodies' point maps (obstacle rows are zero: they do not move), so that ipc-toolkit maps the
barrier's gradient and Hessian back to the entries (``J^T g``, ``J^T H J``).

The barrier potential is ipc-toolkit's log barrier ``kappa * b(d; dhat)`` summed over the
vertex-face and edge-edge pairs closer than ``dhat``; its Hessian is projected to positive
semi-definite per pair (``PSDProjectionMethod.CLAMP``), and :meth:`IpcContact.max_step` is
ipc-toolkit's continuous collision detection along a straight step, so that a line search capped
by it never leaves the intersection-free set. Index order everywhere: entry-major, component-minor
(``entries.ravel()``), as ipc-toolkit orders a mesh's degrees of freedom.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse

from bhem_hpc.errors import UserError

#: Smallest and largest collision-lattice resolution per side of a body.
LATTICE_RANGE = (2, 2000)
#: ``dhat`` as a fraction of the scene's bounding-box diagonal, as IPC's examples choose it.
DEFAULT_DHAT_FRACTION = 1e-3


def minimum_distance(mesh, vertices: np.ndarray, within: float) -> float:
    """The smallest distance [m] between non-adjacent elements of an ipc-toolkit ``CollisionMesh``
    at ``vertices (V, 3)`` that are closer than ``within`` (``inf`` if none are)."""
    import ipctk

    vertices = np.asfortranarray(vertices)
    collisions = ipctk.NormalCollisions()
    collisions.build(mesh, vertices, within)
    return closest_distance(collisions, mesh, vertices)


def closest_distance(collisions, mesh, vertices: np.ndarray) -> float:
    """The smallest distance [m] among ipc-toolkit ``collisions`` built on ``mesh`` at ``vertices
    (V, 3)`` (``inf`` if there are none)."""
    if collisions.empty():
        return float("inf")
    # ipc-toolkit 1.6 returns the squared distance
    return float(np.sqrt(collisions.compute_minimum_distance(mesh, vertices)))


class IpcError(UserError, ValueError):
    """A collision mesh or barrier setting that cannot be used (the message names what and why)."""


@dataclass(frozen=True)
class CollisionSurface:
    """One body's collision mesh: points on its surface and their triangles.

    Attributes:
        point_map: ``(P, N)`` sparse map from the body's flat entries ``(N, 3)`` to the points.
        triangles: ``(T, 3)`` vertex indices (counter-clockwise in the parameter plane).
    """

    point_map: scipy.sparse.csr_matrix
    triangles: np.ndarray

    @property
    def num_points(self) -> int:
        return self.point_map.shape[0]


def collision_lattice(
    xi1_range: tuple[float, float], xi2_range: tuple[float, float], per_side: tuple[int, int],
    periodic: tuple[bool, bool] = (False, False),
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """A triangulated lattice of the parameter rectangle: ``(parameters (P, 2), triangles (T, 3))``.

    ``per_side = (n1, n2)`` cells along each direction; a periodic direction's last lattice line is
    its first (the cells wrap around), so a closed surface gets a closed mesh. Points are numbered
    ``i1 * m2 + i2`` with ``m_k = n_k`` (periodic) or ``n_k + 1`` points along direction k; each
    cell is split along its diagonal into two triangles.
    """
    n1, n2 = (int(n) for n in per_side)
    low, high = LATTICE_RANGE
    if not (low <= n1 <= high and low <= n2 <= high):
        raise IpcError(f"collision lattice cells per side must be in [{low}, {high}], got {per_side}")
    m1, m2 = (n1 if periodic[0] else n1 + 1), (n2 if periodic[1] else n2 + 1)
    xi1 = np.linspace(*xi1_range, n1 + 1)[:m1]
    xi2 = np.linspace(*xi2_range, n2 + 1)[:m2]
    parameters = np.stack(np.meshgrid(xi1, xi2, indexing="ij"), axis=-1).reshape(-1, 2)
    i1, i2 = np.meshgrid(np.arange(n1), np.arange(n2), indexing="ij")
    a = i1 * m2 + i2
    b = ((i1 + 1) % m1) * m2 + i2
    c = ((i1 + 1) % m1) * m2 + (i2 + 1) % m2
    d = i1 * m2 + (i2 + 1) % m2
    triangles = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return parameters, triangles.astype(np.int32)


def chord_gap(evaluate, parameters: np.ndarray, vertices: np.ndarray, triangles: np.ndarray,
              periods: tuple[float | None, float | None] = (None, None)) -> float:  # fmt: skip
    """The largest distance [m] between a mesh's flat triangles and the exact surface they sample,
    measured at the triangles' centroids: the distance of ``S(centroid of the parameters)`` from the
    triangle's plane (not from the vertices' centroid: a parametrization that runs faster on one side
    of a knot moves that point along the surface, not away from the triangle). Triangles of no area
    (at a collapsed edge) are skipped. ``evaluate(xi1 (n,), xi2 (n,))`` gives surface points
    ``(n, 3)``; ``parameters`` ``(P, 2)`` and the mesh's ``vertices`` ``(P, 3)`` (the surface there),
    ``triangles`` ``(T, 3)``; ``periods``: each periodic direction's period (a triangle across the
    seam is unwrapped)."""
    corners = np.asarray(parameters, dtype=float)[np.asarray(triangles)]  # (T, 3, 2)
    for k, period in enumerate(periods):
        if period:
            high = corners[:, :, k].max(axis=1, keepdims=True)
            corners[:, :, k] += period * (high - corners[:, :, k] > 0.5 * period)
    centroid = corners.mean(axis=1)
    for k, period in enumerate(periods):
        if period:  # back into the parameter range
            start = float(np.min(parameters[:, k]))
            centroid[:, k] = start + np.mod(centroid[:, k] - start, period)
    points = np.asarray(evaluate(centroid[:, 0], centroid[:, 1]), dtype=float).reshape(-1, 3)
    vertices = np.asarray(vertices, dtype=float).reshape(-1, 3)
    flat = vertices[np.asarray(triangles)]
    normals = np.cross(flat[:, 1] - flat[:, 0], flat[:, 2] - flat[:, 0])
    lengths = np.linalg.norm(normals, axis=1)
    scale = np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)) if len(vertices) else 0.0
    keep = lengths > 1e-12 * scale**2
    heights = np.einsum("ij,ij->i", points[keep] - flat[keep, 0], normals[keep]) / lengths[keep]
    return float(np.abs(heights).max(initial=0.0))


class IpcContact:
    """The barrier potential between the collision meshes of several bodies and static obstacles.

    Args:
        surfaces: each body's :class:`CollisionSurface`, in the stacked order of the entries.
        rest_entries: each body's flat entries at rest ``(N_b, 3)`` (the map's domain).
        obstacles: static triangle meshes ``(vertices (V, 3), triangles (T, 3))`` (they never move).
        dhat: the barrier's activation distance [m].
        stiffness: the barrier stiffness ``kappa`` [N/m] (see :meth:`initial_stiffness`).

    Raises:
        IpcError: a non-positive ``dhat`` or stiffness, or maps and rest entries that do not match.
    """

    def __init__(self, surfaces: Sequence[CollisionSurface], rest_entries: Sequence[np.ndarray],
                 obstacles: Sequence[tuple[np.ndarray, np.ndarray]], dhat: float, stiffness: float):  # fmt: skip
        import ipctk  # loaded with IPC contact only

        self._ipctk = ipctk
        if not (np.isfinite(dhat) and dhat > 0):
            raise IpcError(f"dhat must be a positive length, got {dhat!r}")
        if not (np.isfinite(stiffness) and stiffness > 0):
            raise IpcError(f"the barrier stiffness must be positive, got {stiffness!r}")
        if len(surfaces) != len(rest_entries):
            raise IpcError(f"{len(surfaces)} collision surfaces for {len(rest_entries)} bodies")
        for k, (surface, rest) in enumerate(zip(surfaces, rest_entries, strict=True)):
            if surface.point_map.shape[1] != len(rest):
                raise IpcError(f"body {k}: its point map takes {surface.point_map.shape[1]} entries, "
                               f"its rest state has {len(rest)}")  # fmt: skip
        self.rest_entries = np.concatenate([np.asarray(r, dtype=float).reshape(-1, 3) for r in rest_entries])
        self.num_entries = len(self.rest_entries)
        obstacle_points = sum(len(v) for v, _ in obstacles)
        self.num_body_vertices = sum(s.num_points for s in surfaces)
        blocks = [s.point_map for s in surfaces]
        body_map = scipy.sparse.block_diag(blocks, format="csr") if blocks else scipy.sparse.csr_matrix((0, 0))
        self.displacement_map = scipy.sparse.vstack(
            [body_map, scipy.sparse.csr_matrix((obstacle_points, self.num_entries))], format="csr"
        )
        rest_vertices = np.concatenate(
            [body_map @ self.rest_entries] + [np.asarray(v, dtype=float).reshape(-1, 3) for v, _ in obstacles]
        )
        triangles, start = [], 0
        for surface in surfaces:
            triangles.append(np.asarray(surface.triangles) + start)
            start += surface.num_points
        for vertices, faces in obstacles:
            triangles.append(np.asarray(faces) + start)
            start += len(vertices)
        faces = np.ascontiguousarray(np.concatenate(triangles).astype(np.int32))
        edges = ipctk.edges(faces)
        self.mesh = ipctk.CollisionMesh(np.asfortranarray(rest_vertices), edges, faces,
                                        self.displacement_map.tocsc())  # fmt: skip
        if obstacle_points:  # obstacles never meet each other
            self.mesh.can_collide = ipctk.make_static_obstacle_filter(self.num_body_vertices)
        self.dhat = float(dhat)
        self.stiffness = float(stiffness)
        self.barrier = ipctk.BarrierPotential(self.dhat, self.stiffness)

    def vertices(self, entries: np.ndarray) -> np.ndarray:
        """The collision mesh's vertices ``(V, 3)`` for the bodies' flat entries ``(N, 3)``."""
        displacement = np.asarray(entries, dtype=float).reshape(-1, 3) - self.rest_entries
        return self.mesh.displace_vertices(np.asfortranarray(displacement))

    def _collisions(self, vertices: np.ndarray):
        collisions = self._ipctk.NormalCollisions()
        collisions.build(self.mesh, vertices, self.dhat)
        return collisions

    def energy(self, entries: np.ndarray) -> float:
        """The barrier potential [J] at ``entries`` ``(N, 3)``."""
        vertices = self.vertices(entries)
        return float(self.barrier(self._collisions(vertices), self.mesh, vertices))

    def gradient(self, entries: np.ndarray) -> np.ndarray:
        """The barrier's gradient with respect to the entries, ``(N, 3)``."""
        vertices = self.vertices(entries)
        gradient = self.barrier.gradient(self._collisions(vertices), self.mesh, vertices)
        return np.asarray(self.mesh.to_full_dof(gradient)).reshape(-1, 3)

    def hessian(self, entries: np.ndarray, project: bool = True) -> scipy.sparse.csr_matrix:
        """The barrier's Hessian with respect to the entries, ``(3N, 3N)``; with ``project``, each
        pair's Hessian is clamped to positive semi-definite before it is mapped back (``J^T H J``
        of positive semi-definite ``H`` is positive semi-definite)."""
        vertices = self.vertices(entries)
        method = self._ipctk.PSDProjectionMethod.CLAMP if project else self._ipctk.PSDProjectionMethod.NONE
        hessian = self.barrier.hessian(self._collisions(vertices), self.mesh, vertices, method)
        return scipy.sparse.csr_matrix(self.mesh.to_full_dof(hessian))

    def max_step(self, entries: np.ndarray, direction: np.ndarray) -> float:
        """The largest ``a`` in ``[0, 1]`` such that the straight step ``entries + t direction``,
        ``t <= a``, stays free of intersections (ipc-toolkit's continuous collision detection; the
        start must be free of them)."""
        start = self.vertices(entries)
        end = self.vertices(np.asarray(entries) + np.asarray(direction))
        return float(self._ipctk.compute_collision_free_stepsize(self.mesh, start, end, 0.0, None,
                                                                 self._ipctk.AdditiveCCD()))  # fmt: skip

    def min_distance(self, entries: np.ndarray) -> float:
        """The smallest distance [m] between elements closer than ``dhat`` (``inf`` if none are)."""
        return minimum_distance(self.mesh, self.vertices(entries), self.dhat)

    def intersects(self, entries: np.ndarray) -> bool:
        """Whether the collision mesh intersects itself (bodies, obstacles) at ``entries``."""
        return bool(self._ipctk.has_intersections(self.mesh, self.vertices(entries)))

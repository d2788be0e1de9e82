"""The collision meshes embedded in bodies (shells, SEM solids) and the IPC barrier built from
them and a scene's colliders (:class:`~bhem_hpc.contact.ipc_contribution.IpcBarrier`); numpy,
SciPy and ipctk only."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from bhem_hpc.collision.tessellation import TessellationError
from bhem_hpc.contact.ipc import chord_gap, collision_lattice
from bhem_hpc.contact.ipc_contribution import (
    COLLIDER_SAGITTA,
    STIFFNESS_GROWTH_LIMIT,
    CoarseCollisionMesh,
    Communicator,
    IpcBarrier,
    Obstacles,
)
from bhem_hpc.contact.ipc_friction import (
    DEFAULT_EPS_V,
    FRICTIONLESS,
    Friction,
    LaggedFriction,
    pair_table,
    surface_friction,
)
from bhem_hpc.contact.ipc_round import RoundCollider, allowed_circumradius, round_offset
from bhem_hpc.errors import RunError
from bhem_hpc.geometry.nurbs import knot_aligned_grid
from bhem_hpc.solver.contributions import PointBasis
from bhem_hpc.solver.step_test import auto_velocity_tolerance

if TYPE_CHECKING:
    from bhem_hpc.model.shell import ShellModel


@dataclass(frozen=True)
class BodyMesh:
    """A body's collision mesh, its vertices material points of the body.

    Attributes:
        bases: each vertex's :data:`~bhem_hpc.solver.contributions.PointBasis` in the body's open
            blocks (empty on ranks that do not hold it: each vertex on one rank).
        triangles: ``(T, 3)`` vertex indices.
        rest: the vertices at rest ``(V, 3)`` [m] (on every rank).
        vertex_mass: the body's mass per vertex [kg] (IPC's stiffness rule).
        self_contact: whether the mesh meets itself (else only other bodies and obstacles).
        friction: the body's friction coefficients.
        chord_gap: the largest distance [m] between the mesh's triangles and the body's exact surface
            at rest (:func:`~bhem_hpc.contact.ipc.chord_gap`): how far the surface may bow through
            the mesh.
    """

    bases: list[PointBasis]
    triangles: np.ndarray
    rest: np.ndarray
    vertex_mass: float
    self_contact: bool = False
    friction: Friction = FRICTIONLESS
    chord_gap: float = 0.0


def check_chord_gaps(meshes: Sequence[BodyMesh], dhat: float) -> None:
    """Raise :class:`CoarseCollisionMesh` for the first of the bodies' ``meshes`` whose
    :attr:`BodyMesh.chord_gap` exceeds ``dhat``."""
    for body, mesh in enumerate(meshes):
        if mesh.chord_gap > dhat:
            raise CoarseCollisionMesh(body, mesh.chord_gap, dhat)


def shell_mesh(model: ShellModel, cells_per_patch: int, density: float, thickness: float,
               self_contact: bool = False, friction: Friction = FRICTIONLESS) -> BodyMesh:  # fmt: skip
    """A shell's collision lattice of ``cells_per_patch`` cells per patch side (aligned with the
    patches, so each lattice triangle lies in one cell); of a trimmed shell (``model.trim``), the
    triangles whose centre it keeps (the mesh's edge follows the trim within a lattice cell)."""
    grid = model.rest_surface.grid
    per_side = (grid.n1 * cells_per_patch, grid.n2 * cells_per_patch)
    periodic = (grid.periodic1, grid.periodic2)
    parameters, triangles = collision_lattice(grid.xi1_range, grid.xi2_range, per_side, periodic)
    if model.trim is not None:
        triangles = model.trim.kept_elements(parameters, triangles)
        used, triangles = np.unique(triangles, return_inverse=True)
        parameters, triangles = parameters[used], triangles.reshape(-1, 3)
    disc = model.discretization
    bases = disc.points_basis(parameters[:, 0], parameters[:, 1])
    rest = model.rest_surface.evaluate(parameters[:, 0], parameters[:, 1]).x
    corners = rest[triangles]
    area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1).sum()
    periods = tuple(high - low if wraps else None
                    for (low, high), wraps in zip((grid.xi1_range, grid.xi2_range), periodic, strict=True))  # fmt: skip
    gap = chord_gap(lambda a, b: model.rest_surface.evaluate(a, b).x, parameters, rest, triangles, periods)
    return BodyMesh(bases, triangles, rest, density * thickness * area / len(rest), self_contact, friction, gap)


def solid_mesh(parts: Sequence[Any], rank: int, mass: float, samples: int = 9,
               friction: Friction = FRICTIONLESS) -> BodyMesh:  # fmt: skip
    """An SEM solid's boundary: its NURBS ``parts`` (stacked control points as the DOF blocks, every
    block on every rank) tessellated on parameter grids of at least ``samples - 1`` cells per side
    that hold every knot (:func:`knot_aligned_grid`: a part's kinks and seams are mesh lines), each
    vertex a fixed rational combination of its part's control points (given on rank 0: each term
    once); ``mass`` [kg] the solid's. Its parts never meet each other (a modeller's parts overlap)."""
    bases, triangles, rest, offset, count, gap = [], [], [], 0, 0, 0.0
    for part in parts:
        (u0, u1), (v0, v1) = part.u.domain, part.v.domain
        grid_u, grid_v = knot_aligned_grid(part.u, samples - 1), knot_aligned_grid(part.v, samples - 1)
        u, v = (a.ravel() for a in np.meshgrid(grid_u, grid_v, indexing="ij"))
        local_triangles = _grid_triangles(len(grid_u), len(grid_v))

        def evaluate(a: np.ndarray, b: np.ndarray, part=part, u0=u0, u1=u1, v0=v0, v1=v1) -> np.ndarray:
            index, values = part.basis_matrix(u0 + a * (u1 - u0), v0 + b * (v1 - v0))
            return np.einsum("pk,pkc->pc", values, part.control.reshape(-1, 3)[index])

        index, values = part.basis_matrix(u0 + u * (u1 - u0), v0 + v * (v1 - v0))
        bases += [(offset + i, w) if rank == 0 else (np.zeros(0, np.int64), np.zeros(0))
                  for i, w in zip(index, values, strict=True)]  # fmt: skip
        triangles.append(local_triangles + count)
        rest.append(np.einsum("pk,pkc->pc", values, part.control.reshape(-1, 3)[index]))
        gap = max(gap, chord_gap(evaluate, np.stack([u, v], axis=1), rest[-1], local_triangles))
        offset += part.control[..., 0].size
        count += len(u)
    rest = np.concatenate(rest)
    return BodyMesh(bases, np.concatenate(triangles), rest, mass / len(rest), friction=friction, chord_gap=gap)


def _grid_triangles(count_u: int, count_v: int) -> np.ndarray:
    """Two triangles per cell of a ``count_u x count_v`` grid of points numbered ``i * count_v + j``."""
    corner = (np.arange(count_u - 1)[:, None] * count_v + np.arange(count_v - 1)[None, :]).ravel()
    return np.concatenate([np.stack([corner, corner + count_v, corner + count_v + 1], axis=1),
                           np.stack([corner, corner + count_v + 1, corner + 1], axis=1)])  # fmt: skip


def bodies_barrier(meshes: Sequence[BodyMesh], open_offsets: Sequence[int], global_open_blocks: np.ndarray,
                   comm: Communicator, colliders: Sequence[Any] = (), dhat: float | None = None,
                   stiffness: float | None = None, collider_friction: Sequence[Friction] | None = None,
                   eps_v: float = DEFAULT_EPS_V,
                   joined: Sequence[tuple[int, int]] = ()) -> IpcBarrier:  # fmt: skip
    """The barrier between bodies' collision ``meshes`` (each body's open blocks at rows
    ``open_offsets[b]:`` of the contributions' state, their global blocks ``global_open_blocks``),
    and between them and colliders (planes exactly, round ones at rest without friction by their signed
    distance, the others as triangle meshes, :func:`_obstacles`);
    ``dhat`` by default 1e-3 of the bodies' rest bounding-box diagonal. ``kappa`` by default starts at
    the top of ipc-toolkit's adaptive range for that ``dhat`` and the bodies' mean mass per vertex and
    grows up to :data:`STIFFNESS_GROWTH_LIMIT` times that (:meth:`IpcBarrier.adapt`); a given one
    stays fixed. Where a
    body (``mesh.friction``) or a collider (``collider_friction``, one per collider; None:
    frictionless colliders) has friction, lagged friction with sticking speed ``eps_v`` [m/s] acts
    at the contacts (:class:`~bhem_hpc.contact.ipc_friction.LaggedFriction`). Meshes ``joined``
    (pairs of indices: patches of one shell) share a vertex group: they do not meet each other."""
    rest = np.concatenate([mesh.rest for mesh in meshes])
    dhat = 1e-3 * float(np.linalg.norm(rest.max(axis=0) - rest.min(axis=0))) if dhat is None else float(dhat)
    adaptive = stiffness is None
    if adaptive:
        mass = sum(mesh.vertex_mass * len(mesh.rest) for mesh in meshes)
        stiffness = _kappa(rest, dhat, mass / len(rest))
    bases, triangles, groups, start = [], [], [], 0
    for body, mesh in enumerate(meshes):
        offset = int(open_offsets[body])
        bases += [(np.asarray(rows, dtype=np.int64) + offset, values) for rows, values in mesh.bases]
        triangles.append(np.asarray(mesh.triangles, dtype=np.int64) + start)
        count = len(mesh.rest)
        groups.append(start + np.arange(count) if mesh.self_contact else np.full(count, start))
        start += count
    for pair in joined:
        if any(meshes[k].self_contact for k in pair):
            raise ValueError(f"meshes {pair} are joined and one has self-contact: joined meshes share one group")
    for _ in joined:  # each pass joins one more link of a chain of joined meshes
        for first, second in joined:
            groups[first][:] = groups[second][:] = min(groups[first][0], groups[second][0])
    frictions = [FRICTIONLESS] * len(colliders) if collider_friction is None else list(collider_friction)
    if len(frictions) != len(colliders):
        raise ValueError(f"{len(colliders)} colliders need as many friction coefficients, got {len(frictions)}")
    cover = np.stack([rest.min(axis=0), rest.max(axis=0)])
    circumradius = allowed_circumradius(rest, np.concatenate(triangles))
    obstacles = _obstacles(colliders, dhat, cover, [not f.any for f in frictions], circumradius)
    friction = None
    if any(f.any for f in [mesh.friction for mesh in meshes] + frictions):
        friction = _lagged_friction(meshes, obstacles, frictions, eps_v)
    barrier = IpcBarrier(bases, global_open_blocks, np.concatenate(triangles), rest, obstacles, dhat, stiffness, comm,
                         np.concatenate(groups), friction)  # fmt: skip
    if adaptive:
        barrier.allow_stiffness_growth(STIFFNESS_GROWTH_LIMIT * stiffness)
    return barrier


def scene_barrier(meshes: Sequence[BodyMesh], open_offsets: Sequence[int], global_open_blocks: np.ndarray,
                  comm: Communicator, contact: Any, scene_file: Any,
                  joined: Sequence[tuple[int, int]] = ()) -> IpcBarrier:  # fmt: skip
    """:func:`bodies_barrier` for a scene's ``contact`` settings (its collider entries with their
    friction and scene keys, ``dhat``, ``barrier_stiffness``, ``eps_v``, ``velocity_tolerance``): a
    collider it cannot mesh is a :class:`~bhem_hpc.errors.RunError` naming ``scene_file`` and the
    collider's key, and :meth:`IpcBarrier.starting_problem` names colliders by their keys."""
    entries = contact.colliders
    try:
        barrier = bodies_barrier(meshes, open_offsets, global_open_blocks, comm, [e.collider for e in entries],
                                 contact.dhat, contact.barrier_stiffness, [surface_friction(e) for e in entries],
                                 contact.eps_v, joined)  # fmt: skip
    except TessellationError as exc:
        raise RunError(f"{scene_file}: key '{entries[exc.collider].key}': {exc}") from exc
    barrier.collider_names = [e.key for e in entries]
    tolerance = contact.velocity_tolerance
    barrier.velocity_tolerance = auto_velocity_tolerance(barrier.diagonal) if tolerance == "auto" else tolerance
    return barrier


def _lagged_friction(meshes: Sequence[BodyMesh], obstacles: Obstacles, colliders: Sequence[Friction],
                     eps_v: float) -> LaggedFriction:  # fmt: skip
    """The friction of bodies' ``meshes`` and the ``obstacles`` made of colliders with coefficients
    ``colliders``: the vertices' surfaces (bodies, then colliders) and the colliders' surface velocities."""
    bodies = len(meshes)
    owners = [np.full(len(mesh.rest), body) for body, mesh in enumerate(meshes)]
    owners += [np.full(len(points), bodies + collider) for points, _, _, collider in obstacles.meshes]
    body_vertices = sum(len(mesh.rest) for mesh in meshes)
    resting = np.zeros((body_vertices, 3))

    def velocity(time: float) -> np.ndarray:
        return np.concatenate([resting] + [at(time) for _, _, at, _ in obstacles.meshes])

    table = pair_table([mesh.friction for mesh in meshes], colliders)
    return LaggedFriction(np.concatenate(owners), bodies + np.asarray(obstacles.plane_colliders, dtype=np.int64),
                          table, velocity, body_vertices, eps_v)  # fmt: skip


def shell_barrier(model: ShellModel, colliders: Sequence[Any], dhat: float | None, stiffness: float | None,
                  cells_per_patch: int, density: float, thickness: float, self_contact: bool = False,
                  ) -> IpcBarrier:  # fmt: skip
    """The barrier between ``model``'s shell and static colliders, and within the shell with
    ``self_contact`` (:func:`shell_mesh`, :func:`bodies_barrier`)."""
    mesh = shell_mesh(model, cells_per_patch, density, thickness, self_contact)
    return bodies_barrier([mesh], [0], model.global_open_blocks, model.comm, colliders, dhat, stiffness)


def _obstacles(colliders: Sequence[Any], dhat: float, cover: np.ndarray, frictionless: Sequence[bool],
               circumradius: float) -> Obstacles:  # fmt: skip
    """Colliders as the barrier's planes, round colliders and triangle meshes. A sphere, capsule or
    cylinder that does not move, has no friction (``frictionless``, per collider) and whose offset
    for the mesh's triangles (``circumradius`` [m], :func:`~bhem_hpc.contact.ipc_round.round_offset`)
    is within dhat, the distance the barrier keeps contacts at anyway, is met through its exact
    signed distance; the other curved ones are tessellated within :data:`COLLIDER_SAGITTA` dhat (an
    infinite cylinder over the part of its axis the bodies' box ``cover (2, 3)`` spans and a
    diagonal of it beyond; a sphere's vertices moving at its surface velocity)."""
    from bhem_hpc.collision.colliders import ColliderError, Plane

    meshes, planes, plane_colliders, mesh_velocities, plane_velocities, round_colliders = [], [], [], [], [], []
    for index, c in enumerate(colliders):
        if isinstance(c, Plane):
            planes.append((c.normal / np.linalg.norm(c.normal), c.point))
            plane_colliders.append(index)
            plane_velocities.append(np.asarray(c.velocity, dtype=float))
            continue
        if (isinstance(c, RoundCollider) and frictionless[index] and not np.any(c.velocity)
                and round_offset(float(c.radius), circumradius) <= dhat):  # fmt: skip
            round_colliders.append((c, index))
            continue
        try:
            points, faces = c.tessellation(COLLIDER_SAGITTA * dhat, cover)
        except (TessellationError, ColliderError) as exc:  # spheres' and capsules' limits are the latter
            raise TessellationError(f"{exc} ({COLLIDER_SAGITTA:g} dhat; a larger 'effects.contact.dhat' allows "
                                    "coarser triangles)", index) from None  # fmt: skip
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        meshes.append((points, faces, _surface_velocity(c, points), index))
        mesh_velocities.append(np.asarray(c.velocity, dtype=float))
    return Obstacles(meshes, planes, plane_colliders, mesh_velocities, plane_velocities, round_colliders)


def _surface_velocity(collider: Any, points: np.ndarray) -> Callable[[float], np.ndarray]:
    """The velocity of a collider's surface at its mesh's ``points`` ``(V, 3)`` as a function of
    time: its translation's, and a spinning sphere's turn (the turn about the centre is the same
    wherever the translation has taken the sphere)."""
    from bhem_hpc.collision.colliders import Sphere

    if isinstance(collider, Sphere):
        return lambda time: collider.surface_velocity(points, time)
    translating = np.broadcast_to(np.asarray(collider.velocity, dtype=float), points.shape).copy()
    return lambda time: translating


def _kappa(rest: np.ndarray, dhat: float, mass_per_vertex: float) -> float:
    """The top of ipc-toolkit's adaptive barrier stiffness range for a mesh at ``rest (V, 3)`` with
    ``mass_per_vertex`` [kg]. Its rule starts at the bottom, 1/100 of it, and doubles kappa while
    contacts close in: at the bottom, a rubber sheet landing on a floor (dhat 1e-3) sank to 5e-8 m
    of it and Newton stalled there; at the top it lands in 8 iterations and rests 1e-6 m above
    (measured)."""
    import ipctk

    diagonal = float(np.linalg.norm(rest.max(axis=0) - rest.min(axis=0)))
    zero = np.zeros(3)
    return ipctk.initial_barrier_stiffness(diagonal, ipctk.ClampedLogBarrier(), dhat, mass_per_vertex, zero, zero)[1]


def solid_barrier(
    parts: Sequence[Any], comm: Communicator, colliders: Sequence[Any], mass: float, dhat: float | None = None,
    stiffness: float | None = None, samples: int = 9,
) -> IpcBarrier:  # fmt: skip
    """The barrier between an SEM solid's boundary (:func:`solid_mesh`) and static colliders."""
    mesh = solid_mesh(parts, comm.rank, mass, samples)
    blocks = np.arange(sum(part.control[..., 0].size for part in parts))
    return bodies_barrier([mesh], [0], blocks, comm, colliders, dhat, stiffness)

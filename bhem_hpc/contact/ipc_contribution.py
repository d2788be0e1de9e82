"""Incremental potential contact inside the Newton solve: ipc-toolkit's barrier between bodies'
collision meshes and static obstacles as an energy contribution with a line-search step bound
(:class:`~bhem_hpc.solver.contributions.StepBounded`), with lagged friction
(:mod:`~bhem_hpc.contact.ipc_friction`) where the surfaces have friction coefficients; numpy, SciPy
and ipctk only.

The collision mesh's vertices are material points of the shell, each a fixed linear combination
of the open DOF blocks of the cell that holds it (``discretization.point_basis``, on the rank that
owns the cell): ``vertices = B x`` with ``B`` sparse ``(points, blocks)``. Every rank evaluates the
barrier on the whole mesh (the vertices are summed over the ranks, so all ranks see the same
mesh and take the same decisions); each adds ``B_r^T g`` of its own points to the gradient, and
rank 0 adds the Hessian ``(B ⊗ I3)^T H (B ⊗ I3)`` in global blocks. Against static obstacles
every barrier pair involves one triangle, edge or vertex of the shell's mesh, so the Hessian's
blocks lie within the block pairs of the mesh's triangles: the pattern is fixed at construction.
"""

from __future__ import annotations

import functools
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from bhem_hpc.contact.ipc import IpcError, closest_distance
from bhem_hpc.contact.ipc_friction import LaggedFriction
from bhem_hpc.contact.ipc_round import RoundCollider, RoundObstacles, allowed_circumradius
from bhem_hpc.solver.contributions import ContributionState, PointBasis, no_blocks

log = logging.getLogger(__name__)


def _timed(method: Callable) -> Callable:
    """Add the seconds a barrier method takes to the barrier's :attr:`IpcBarrier.seconds`."""

    @functools.wraps(method)
    def timed(self: IpcBarrier, *args: Any, **kwargs: Any) -> Any:
        start = time.perf_counter()
        try:
            return method(self, *args, **kwargs)
        finally:
            self.seconds += time.perf_counter() - start

    return timed


class Communicator(Protocol):
    """What the barrier needs of an MPI communicator (mpi4py's has it)."""

    rank: int

    def allreduce(self, value: Any) -> Any: ...

    def allgather(self, value: Any) -> list: ...


#: A curved collider (sphere, capsule, cylinder, patch model) meets the barrier as a triangle mesh
#: whose faces lie at most this fraction of dhat from it (a shell resting on a sphere, capsule or
#: cylinder may sink that far into the exact shape: their faces lie inside).
COLLIDER_SAGITTA = 0.25
#: A step's first guess moves a vertex towards a translating plane until at most this fraction of
#: its gap at the step's start is left (as ipc-toolkit's additive CCD stops short of contact).
PLANE_GAP_KEPT = 0.1
#: The barrier stiffness doubles after a Newton iterate whose closest pair is nearer than the
#: previous iterate's, both nearer than this fraction of the bodies' rest bounding-box diagonal
#: (IPC's rule, Li et al. 2020, as ipc-toolkit's ``update_barrier_stiffness`` applies it). A
#: threshold of 1e-3 dhat got the mandrel's worst landing step through in 35 Newton iterations
#: where this one takes 61; with it, and without asking the previous iterate to be within it too,
#: kappa grew on contacts that rest well (a solid landing on a floor halved dt twice, a frictionless
#: sheet on a spinning sphere drifted farther, measured): here kappa grows only where Newton crawls.
STIFFNESS_GROWTH_DISTANCE = 1e-9
#: The adaptive stiffness grows up to this many times its start (the top of ipc-toolkit's range):
#: on the mandrel the can's wall, pressed onto the mandrel by the axial load, took 2^13 of it.
STIFFNESS_GROWTH_LIMIT = 1e4
#: The pairs that may come within dhat are found once for boxes inflated by dhat / 2 plus this
#: fraction of dhat, and kept for every state whose vertices all lie within that fraction of dhat
#: (in each coordinate) of where they were found: a pair within dhat there has boxes within dhat plus
#: twice the margin where they were found. The broad phase is most of a build's time (the needles
#: job: 18 of 25 ms), and Newton's later iterations and line-search trials move the vertices much
#: less than dhat.
CANDIDATE_MARGIN = 0.5
#: A motion that moves a vertex farther than this fraction of the bodies' rest bounding-box diagonal is
#: bounded through its first stretch of that length (a smaller, still collision-free fraction of the
#: whole): ipc-toolkit's broad phase takes every pair whose swept boxes overlap, and a trust-region
#: trial of the crushed can by IPC that moved its wall by 1.5 m (eight diagonals) made nearly every
#: pair of the mesh a candidate, 67 s for one bound; that step takes 1.8 s with this (measured).
CCD_REACH = 0.1
#: How many states' vertices and pairs the barrier keeps (:meth:`IpcBarrier._vertices`,
#: :meth:`IpcBarrier._collisions`): an iterate and a step's end (a step bound asks for both), or a
#: step's start and its inertial prediction (its first guess).
KEPT_VERTEX_STATES = 2
#: Basis weights below this (relative to the point's largest) are dropped from the map: a point on
#: a cell's edge then depends only on that edge's blocks, which neighbouring cells share.
WEIGHT_CUTOFF = 1e-12


def _kept_value(states: list[tuple[np.ndarray, Any]], at: np.ndarray) -> Any:
    """The value kept in ``states`` (``(array, value)``, the latest first) for an array equal to
    ``at`` (shape and entries), or None."""
    return next((value for key, value in states if key.shape == at.shape and np.array_equal(key, at)), None)


def _keeping(states: list[tuple[np.ndarray, Any]], at: np.ndarray, value: Any) -> list[tuple[np.ndarray, Any]]:
    """``states`` with ``(at, value)`` first, the oldest dropped beyond :data:`KEPT_VERTEX_STATES`."""
    return [(at, value), *states][:KEPT_VERTEX_STATES]


@dataclass(frozen=True)
class Obstacles:
    """Colliders as the barrier sees them, where they are at time 0, each translating at a constant velocity.

    Attributes:
        meshes: ``(vertices (V, 3), triangles (F, 3), surface velocity, collider index)``, the
            surface velocity a function of time [s] giving the vertices' ``(V, 3)`` [m/s].
        planes: ``(unit normal, point)``; plane_colliders: each plane's collider index.
        mesh_velocities, plane_velocities: each mesh's and plane's translation velocity ``(3,)``
            [m/s] (empty: all at rest).
        round: static round colliders met through their signed distance, with their collider
            indices (:mod:`~bhem_hpc.contact.ipc_round`).
    """

    meshes: list[tuple[np.ndarray, np.ndarray, Callable[[float], np.ndarray], int]]
    planes: list[tuple[np.ndarray, np.ndarray]]
    plane_colliders: list[int]
    mesh_velocities: list[np.ndarray] = field(default_factory=list)
    plane_velocities: list[np.ndarray] = field(default_factory=list)
    round: list[tuple[RoundCollider, int]] = field(default_factory=list)

    @property
    def moving(self) -> bool:
        """Whether some obstacle translates."""
        return any(np.any(v) for v in [*self.mesh_velocities, *self.plane_velocities])


class CoarseCollisionMesh(IpcError):
    """A body's collision mesh lies farther from its exact surface than ``dhat``: the surface could
    pass through a collider or another body between the mesh's vertices, unseen by the barrier
    (scenes refuse it, :func:`check_chord_gaps`; the Python API leaves the choice to its caller)."""

    def __init__(self, body: int, gap: float, dhat: float):
        self.body, self.gap, self.dhat = body, gap, dhat
        super().__init__(f"the collision mesh lies up to {gap:.3g} m from the exact surface at rest (measured at its "
                         f"triangles' centroids), more than dhat = {dhat:.3g} m: more collision_cells, or a larger "
                         "dhat, bring it within")  # fmt: skip


class IpcBarrier:
    """ipc-toolkit's barrier between a shell's collision mesh and static obstacles.

    Args:
        bases: each mesh vertex's :data:`~bhem_hpc.solver.contributions.PointBasis` (empty on
            ranks that do not own its cell).
        global_blocks: global open block index of each local block ``(blocks,)``.
        triangles: the mesh's triangles ``(T, 3)`` (vertex indices).
        rest: the mesh's vertices at rest ``(points, 3)`` [m]: ipc-toolkit's edge-edge mollifier
            is scaled by the rest edges' lengths (a mesh at rest in one point makes the barrier's
            gradient disagree with its energy where edges cross).
        obstacles: the colliders' triangle meshes, planes (the barrier distance to the plane) and
            round colliders (the barrier distance to their exact shape).
        dhat: the barrier's activation distance [m]; stiffness: ``kappa`` [N/m].
        comm: the shell's communicator (``rank``, ``allreduce``, ``allgather``: an mpi4py one).
        groups: each mesh vertex's group ``(points,)``: elements whose vertices are all of one group
            never meet (a body without self-contact is one group; a body with it gives every vertex
            a group of its own); None: every vertex its own (the mesh meets itself). Obstacles form
            one more group: they meet the mesh, never each other.
        friction: the lagged friction on the mesh (vertices of the mesh, then of the obstacles), or
            None: frictionless.
    """

    name = "ipc barrier"

    def __init__(self, bases: Sequence[PointBasis], global_blocks: np.ndarray, triangles: np.ndarray, rest: np.ndarray,
                 obstacles: Obstacles, dhat: float, stiffness: float, comm: Communicator,
                 groups: np.ndarray | None = None, friction: LaggedFriction | None = None):  # fmt: skip
        import ipctk  # loaded with IPC contact only

        self._ipctk = ipctk
        self.rank, self._comm = comm.rank, comm
        self.num_points = len(bases)
        self.dhat, self.stiffness = float(dhat), float(stiffness)
        #: the largest stiffness it may grow to (:meth:`allow_stiffness_growth`; the stiffness
        #: itself: fixed), the closest distance of the last Newton iterate [m], the doublings made
        self.stiffness_limit, self._last_distance, self.stiffness_doublings = self.stiffness, np.inf, 0
        self._start_stiffness = self.stiffness
        #: IPC's Newton stopping test [m/s] (:meth:`step_converged`); None: the solver's own tests only
        self.velocity_tolerance: float | None = None
        #: seconds spent in the barrier's energy, gradient, Hessian, step bounds and adaptation
        self.seconds = 0.0
        rest = np.asarray(rest, dtype=float).reshape(-1, 3)
        self._diagonal = float(np.linalg.norm(rest.max(axis=0) - rest.min(axis=0))) if len(rest) else 1.0
        #: the distance [m] below which contacts still closing in grow the stiffness
        self.growth_distance = STIFFNESS_GROWTH_DISTANCE * self._diagonal
        groups = np.arange(self.num_points) if groups is None else np.asarray(groups, dtype=np.int64)
        if groups.shape != (self.num_points,):
            raise ValueError(f"{self.num_points} mesh vertices need as many groups, got shape {groups.shape}")
        #: whether some elements of one body meet each other (not only other bodies and obstacles)
        # a group of one vertex: a body that meets itself
        self.self_contact = bool(len(groups) and np.any(np.bincount(groups - groups.min()) == 1))
        self._beyond = no_blocks()
        global_blocks = np.asarray(global_blocks, dtype=np.int64)
        self._global_blocks = global_blocks  # of the local blocks
        rows, cols, weights = [], [], []
        for point, (blocks, values) in enumerate(bases):
            blocks, values = np.asarray(blocks, dtype=np.int64), np.asarray(values, dtype=float)
            if len(values):
                keep = np.abs(values) > WEIGHT_CUTOFF * np.abs(values).max()
                rows.append(np.full(keep.sum(), point))
                cols.append(blocks[keep])
                weights.append(values[keep])
        local = [np.concatenate(a) if a else np.zeros(0) for a in (rows, cols, weights)]
        num_local = len(global_blocks)
        #: this rank's points in its local blocks (owned and ghost), ``(points, blocks)``
        self.local_map = scipy.sparse.csr_matrix((local[2], (local[0].astype(np.int64), local[1].astype(np.int64))),
                                                 shape=(self.num_points, num_local))  # fmt: skip
        # every point's map in global blocks, on every rank (the Hessian's blocks and pattern)
        triplets = (local[0].astype(np.int64), global_blocks[local[1].astype(np.int64)], local[2])
        gathered = [np.concatenate(parts) for parts in zip(*comm.allgather(triplets), strict=True)]
        self.blocks, column = np.unique(gathered[1], return_inverse=True)  # the global blocks the mesh uses
        self.global_map = scipy.sparse.csr_matrix((gathered[2], (gathered[0], column)),
                                                  shape=(self.num_points, len(self.blocks)))  # fmt: skip
        # the map of the vertices' coordinates (3 per vertex) to the blocks' (the Hessian's J)
        self._coordinate_map = scipy.sparse.kron(self.global_map, scipy.sparse.identity(3), format="csr")
        self._coordinate_map_transposed = self._coordinate_map.T.tocsr()
        self._pattern = self._triangle_pattern(np.asarray(triangles, dtype=np.int64))
        self.round = RoundObstacles([c for c, _ in obstacles.round], [i for _, i in obstacles.round],
                                    allowed_circumradius(rest, triangles), self.dhat)  # fmt: skip
        # ipc-toolkit finds pairs only across vertex groups, or with obstacle meshes and planes
        self._toolkit_pairs = bool(obstacles.meshes or obstacles.planes or len(np.unique(groups)) > 1)
        self.mesh = self._collision_mesh(np.asarray(triangles), np.asarray(rest, dtype=float).reshape(-1, 3), obstacles,
                                         groups)  # fmt: skip
        self.barrier = ipctk.BarrierPotential(self.dhat, self.stiffness)
        # additive CCD (Li et al. 2021, conservative): on a sheet lying 1e-6 m above a floor mesh,
        # Tight Inclusion took 0.4 s per bound on the near-parallel edge pairs and 76 Newton
        # iterations in the landing step, additive CCD 0.02 s and 27 (measured)
        self._ccd = ipctk.AdditiveCCD()
        self.friction = friction
        self._translation = self._translation_weights() if self.moving else np.zeros(0)
        self._step = (0.0, 0.0)  # the time step of the last begin_step: its start and length [s]
        # vertices and the pairs there, the latest first (:meth:`_collisions`)
        self._kept_collisions: list[tuple[np.ndarray, Any]] = []
        # the pairs' candidates and the vertices where they were found (:meth:`_candidates_near`)
        self._candidates: tuple[np.ndarray, Any] = (np.zeros((0, 3)), None)
        # open block positions and the shell's vertices there, the latest first (:meth:`_vertices`)
        self._kept_vertices: list[tuple[np.ndarray, np.ndarray]] = []

    def _triangle_pattern(self, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pairs ``(i, j)`` of mesh blocks (columns of the global map) that share a triangle."""
        incidence = scipy.sparse.csr_matrix(
            (np.ones(triangles.size), (np.repeat(np.arange(len(triangles)), 3), triangles.ravel())),
            shape=(len(triangles), self.num_points),
        )
        support = incidence @ abs(self.global_map)  # triangles x blocks
        support.data[:] = 1.0
        pairs = (support.T @ support).tocoo()
        order = np.lexsort((pairs.col, pairs.row))
        return pairs.row[order].astype(np.int64), pairs.col[order].astype(np.int64)

    def _collision_mesh(self, triangles: np.ndarray, rest: np.ndarray, obstacles: Obstacles, groups: np.ndarray):
        ipctk = self._ipctk
        if rest.shape != (self.num_points, 3):
            raise ValueError(f"{self.num_points} mesh vertices need as many rest positions, got shape {rest.shape}")
        faces, vertices, start = [triangles], [rest], self.num_points
        for points, obstacle_faces, _, _ in obstacles.meshes:
            vertices.append(np.asarray(points, dtype=float).reshape(-1, 3))
            faces.append(np.asarray(obstacle_faces) + start)
            start += len(vertices[-1])
        self._obstacle_vertices = np.concatenate(vertices[1:]) if obstacles.meshes else np.zeros((0, 3))
        self._obstacle_rest = self._obstacle_vertices  # where the obstacles are at time 0
        velocities = obstacles.mesh_velocities or [np.zeros(3)] * len(obstacles.meshes)
        # each obstacle mesh's translation velocity and vertex count, in the order of its vertices
        self._mesh_groups = [(np.asarray(v, dtype=float), len(points))
                             for (points, *_), v in zip(obstacles.meshes, velocities, strict=True)]  # fmt: skip
        self._obstacle_velocity = np.concatenate(
            [np.zeros((0, 3))] + [np.broadcast_to(v, (count, 3)) for v, count in self._mesh_groups])
        plane_velocities = obstacles.plane_velocities or [np.zeros(3)] * len(obstacles.planes)
        self._plane_colliders = list(obstacles.plane_colliders)
        #: each collider's name in messages (a scene sets its keys, e.g. ``colliders[1]``)
        self.collider_names: list[str] | None = None
        self._planes = [(np.asarray(n, dtype=float), np.asarray(p, dtype=float), np.asarray(v, dtype=float))
                        for (n, p), v in zip(obstacles.planes, plane_velocities, strict=True)]  # fmt: skip
        #: whether some obstacle translates (its place follows the time steps, :meth:`place_obstacles`)
        self.moving = obstacles.moving
        faces = np.ascontiguousarray(np.concatenate(faces).astype(np.int32))
        mesh = ipctk.CollisionMesh(np.asfortranarray(np.concatenate(vertices)), ipctk.edges(faces), faces)
        # only pairs across groups meet: a vertex group per body without self-contact, one per vertex
        # of a body with it, one for all obstacles
        every = np.empty(start, dtype=np.int32)
        every[: self.num_points] = groups - groups.min() if len(groups) else groups
        every[self.num_points:] = every[: self.num_points].max(initial=-1) + 1
        mesh.can_collide = ipctk.make_vertex_patches_filter(every)
        mesh.planes = self._planes_at(0.0)
        return mesh

    def _planes_at(self, time: float) -> list:
        return [self._ipctk.Hyperplane(n, p + time * v) for n, p, v in self._planes]

    @staticmethod
    def _plane_gaps(vertices: np.ndarray, plane: tuple[np.ndarray, np.ndarray, np.ndarray], time: float) -> np.ndarray:
        """Signed distances ``(V,)`` of ``vertices`` ``(V, 3)`` from a translating ``plane`` (unit
        normal, point at time 0, velocity) where it is at ``time`` [s]."""
        normal, point, velocity = plane
        return (vertices - point - time * velocity) @ normal

    def place_obstacles(self, time: float) -> None:
        """Put the translating obstacles where they are at ``time`` [s]: the barrier, its Newton step
        bound and :meth:`starting_problem` meet them there."""
        if self.moving:
            self._obstacle_vertices = self._obstacle_rest + time * self._obstacle_velocity
            self.mesh.planes = self._planes_at(time)
            self._kept_collisions = []  # the planes are not among the vertices

    def _vertices(self, positions: np.ndarray) -> np.ndarray:
        """Collective: the mesh's vertices for this rank's open block positions ``(blocks, 3)``. A
        Newton iteration asks at its iterate for the energy, gradient, Hessian and step bounds: the
        shell's vertices of the last :data:`KEPT_VERTEX_STATES` positions are kept (a state is taken
        from there only where every rank has it: the sum over the ranks is collective)."""
        positions = np.asarray(positions, dtype=float).reshape(-1, 3)
        kept = _kept_value(self._kept_vertices, positions)
        if self._comm.allreduce(int(kept is None)):
            kept = self._comm.allreduce(self.local_map @ positions)
            self._kept_vertices = _keeping(self._kept_vertices, positions.copy(), kept)
        return np.asfortranarray(np.concatenate([kept, self._obstacle_vertices]))

    def _collisions(self, vertices: np.ndarray):
        """The pairs closer than dhat at ``vertices``: those of one of the last
        :data:`KEPT_VERTEX_STATES` calls again where the vertices (and the obstacles' places) are
        that call's. A Newton iteration asks at one state for the energy (its line search's
        accepted trial), the gradient and the Hessian; a step's first guess for the energies of the
        inertial prediction and of the step's start (the last step's end). The pairs come from
        candidates kept while the vertices stay near (:meth:`_candidates_near`)."""
        if self._kept_collisions and not self._toolkit_pairs:
            return self._kept_collisions[0][1]
        kept = _kept_value(self._kept_collisions, vertices)
        if kept is not None:
            return kept
        collisions = self._ipctk.NormalCollisions()
        if self._toolkit_pairs:
            collisions.build(self._candidates_near(vertices), self.mesh, vertices, self.dhat)
        if self.mesh.planes:
            collisions.pv_collisions = self._plane_collisions(vertices)
        self._kept_collisions = _keeping(self._kept_collisions, np.array(vertices), collisions)
        return collisions

    def _candidates_near(self, vertices: np.ndarray):
        """ipc-toolkit's candidate pairs for the barrier at ``vertices`` ``(vertices, 3)``: those found
        last if no vertex has moved farther than :data:`CANDIDATE_MARGIN` dhat in a coordinate since,
        else found anew there (the same on every rank: the vertices are everyone's)."""
        margin = CANDIDATE_MARGIN * self.dhat
        found_at, candidates = self._candidates
        if (candidates is None or found_at.shape != vertices.shape
                or np.abs(vertices - found_at).max(initial=0.0) > margin):
            candidates = self._ipctk.Candidates()
            candidates.build(self.mesh, vertices, 0.5 * self.dhat + margin)
            self._candidates = (np.array(vertices), candidates)
        return candidates

    def _plane_collisions(self, vertices: np.ndarray) -> list:
        """The plane-vertex pairs closer than dhat: every body vertex within dhat of a plane.
        ipc-toolkit 1.6.1 builds them only within dhat / 2 while its barrier reaches dhat, so a
        vertex crossing dhat / 2 met an energy step: a cloth's corner hanging onto the ground stuck
        there and the line search stalled (the cloth on a spinning sphere at t = 0.965 s). Its
        vertex filter does not reach planes either: a collider mesh resting on a plane collider
        (a ball on the ground) met it, with a constant energy that swamps the line search's energy
        scale; colliders never meet each other."""
        body = np.asarray(vertices)[: self.num_points]
        pairs = []
        for plane in self.mesh.planes:
            gaps = body @ plane.normal() + plane.offset()
            near = np.flatnonzero(np.abs(gaps) < self.dhat)
            pairs += [self._ipctk.PlaneVertexNormalCollision(plane, int(v)) for v in near]
        return pairs

    def hessian_pattern(self) -> tuple[np.ndarray, np.ndarray]:
        if self.rank != 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        rows, cols = self._pattern
        return self.blocks[rows], self.blocks[cols]

    def allow_stiffness_growth(self, limit: float) -> None:
        """Let the stiffness double, up to ``limit`` [N/m], while contacts keep closing in nearer than
        :attr:`growth_distance` (:meth:`adapt`)."""
        self.stiffness_limit = max(float(limit), self.stiffness)

    @_timed
    def adapt(self, state: ContributionState) -> bool:
        """Collective: IPC's adaptive stiffness at a Newton iterate: double it (up to its limit) where
        the closest pair is nearer than at the previous iterate of the step's solve, both nearer than
        :attr:`growth_distance`; returns whether it changed. It never shrinks: a stiffness that had
        to grow once is kept for the contacts that follow."""
        if self.stiffness >= self.stiffness_limit:
            return False
        distance = self.min_distance(state.positions)
        previous, self._last_distance = self._last_distance, distance
        grown = self._ipctk.update_barrier_stiffness(previous**2, distance**2, self.stiffness_limit, self.stiffness,
                                                     self._diagonal, STIFFNESS_GROWTH_DISTANCE)  # fmt: skip
        if grown == self.stiffness:
            return False
        self.set_stiffness(grown)
        self.stiffness_doublings += 1
        if self.rank == 0:
            log.info("ipc barrier: closest pair %.3g m (was %.3g m): stiffness doubled to %.4g N/m", distance,
                     previous, self.stiffness)  # fmt: skip
        return True

    def set_stiffness(self, stiffness: float) -> None:
        """The barrier's stiffness ``kappa`` [N/m] (a restart's, or one grown by :meth:`adapt`)."""
        self.stiffness = float(stiffness)
        self.barrier = self._ipctk.BarrierPotential(self.dhat, self.stiffness)

    def parameters(self) -> dict[str, float]:
        """What :meth:`adapt` changed, for a checkpoint: a continued run goes on with it."""
        return {"ipc_barrier_stiffness": self.stiffness}

    def restore(self, parameters: dict[str, float]) -> None:
        """Take the stiffness of a checkpoint's :meth:`parameters` (absent: keep this one)."""
        if "ipc_barrier_stiffness" in parameters:
            self.set_stiffness(float(parameters["ipc_barrier_stiffness"]))

    def summary(self) -> dict:
        """The barrier's settings as a run's summary records them."""
        friction = self.friction
        return {"method": "ipc", "dhat_m": self.dhat, "barrier_stiffness": self.stiffness,
                "barrier_stiffness_start": self._start_stiffness, "barrier_stiffness_limit": self.stiffness_limit,
                "stiffness_doublings": self.stiffness_doublings, "barrier_s": self.seconds,
                "collision_vertices": self.num_points, "round_colliders": len(self.round),
                "round_offsets_m": self.round.offsets.tolist(), "friction": friction is not None,
                "eps_v_m_s": friction.eps_v if friction is not None else None,
                "velocity_tolerance_m_s": self.velocity_tolerance}  # fmt: skip

    @_timed
    def begin_step(self, state: ContributionState, time: float, dt: float) -> None:
        """Collective: with friction, lag the contacts at the step's start (their normal forces and
        tangent bases) for a step from ``time`` of ``dt`` [s]; then the translating obstacles go to
        where they are at the step's end, where the step's Newton meets them."""
        self.place_obstacles(time)
        self._last_distance = np.inf  # the stiffness grows on contacts closing in within a step's solve
        if self.friction is not None:
            vertices = self._vertices(state.positions)
            self.friction.lag(self.mesh, vertices, self._collisions(vertices), self.barrier, time, dt)
        self._step = (time, dt)
        self.place_obstacles(time + dt)

    @_timed
    def energy(self, state: ContributionState) -> float:
        vertices = self._vertices(state.positions)
        energy = float(self.barrier(self._collisions(vertices), self.mesh, vertices))
        if len(self.round):
            energy += self.round.energy(vertices[: self.num_points], self.stiffness)
        if self.friction is not None:
            energy += self.friction.energy(self.mesh, vertices)
        return energy if self.rank == 0 else 0.0

    @_timed
    def add_gradient(self, state: ContributionState, gradient: np.ndarray) -> None:
        vertices = self._vertices(state.positions)
        full = np.asarray(self.barrier.gradient(self._collisions(vertices), self.mesh, vertices)).reshape(-1, 3)
        if self.friction is not None:
            full = full + self.friction.gradient(self.mesh, vertices)
        if len(self.round):
            full[: self.num_points] += self.round.gradient(vertices[: self.num_points], self.stiffness)
        gradient += self.local_map.T @ full[: self.num_points]

    @_timed
    def hessian(self, state: ContributionState) -> np.ndarray:
        """Rank 0: the blocks of :meth:`hessian_pattern` ``(k, 3, 3)``, each barrier pair's Hessian
        clamped to positive semi-definite before it is mapped to the blocks."""
        vertices = self._vertices(state.positions)
        if self.rank != 0:
            return np.zeros((0, 3, 3))
        # negative eigenvalues clamped to zero: with their absolute values instead, the hairpin's
        # arms meeting halved dt and failed where clamping converges without recovery (measured)
        method = self._ipctk.PSDProjectionMethod.CLAMP
        hessian = scipy.sparse.csr_matrix(self.barrier.hessian(self._collisions(vertices), self.mesh, vertices, method))
        if self.friction is not None:
            hessian = hessian + self.friction.hessian(self.mesh, vertices)
        size = 3 * self.num_points
        shell = hessian[:size, :size]
        if len(self.round):
            diagonal = self.round.hessian(vertices[: self.num_points], self.stiffness)  # (points, 3, 3)
            count = np.arange(self.num_points + 1)
            shell = shell + scipy.sparse.bsr_matrix((diagonal, count[:-1], count), shape=(size, size)).tocsr()
        blocks = (self._coordinate_map_transposed @ shell @ self._coordinate_map).tobsr(blocksize=(3, 3))
        return self._split(blocks)

    def _split(self, blocks: scipy.sparse.bsr_matrix) -> np.ndarray:
        """The Hessian's 3 x 3 ``blocks`` (mesh block indices) on the fixed pattern ``(k, 3, 3)``;
        those outside it (two vertices of no common triangle: self-contact) are kept for
        :meth:`hessian_beyond_pattern`."""
        rows, cols = self._pattern
        out = np.zeros((len(rows), 3, 3))
        self._beyond = no_blocks()
        if not blocks.nnz:
            return out
        count = len(self.blocks)
        pattern_keys = rows * count + cols
        block_rows = np.repeat(np.arange(blocks.shape[0] // 3), np.diff(blocks.indptr))
        keys = block_rows * count + blocks.indices
        where = np.minimum(np.searchsorted(pattern_keys, keys), len(pattern_keys) - 1)
        inside = pattern_keys[where] == keys
        out[where[inside]] = blocks.data[inside]
        outside = ~inside
        self._beyond = (self.blocks[block_rows[outside]], self.blocks[blocks.indices[outside]], blocks.data[outside])
        return out

    def hessian_beyond_pattern(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rank 0: the blocks of the last :meth:`hessian` outside its pattern, global ``(rows,
        columns, values (k, 3, 3))`` (empty elsewhere and without self-contact)."""
        return self._beyond

    @_timed
    def max_step(self, state: ContributionState, direction: np.ndarray) -> float:
        start = self._vertices(state.positions)
        end = self._vertices(np.asarray(state.positions) + np.asarray(direction).reshape(-1, 3))
        return self._collision_free_fraction(start, end)

    def _collision_free_fraction(self, start: np.ndarray, end: np.ndarray) -> float:
        """The largest fraction of the straight motion of the mesh's vertices ``start -> end``
        ``(vertices, 3)`` that no pair crosses (ipc-toolkit's additive CCD), or a smaller one where
        a vertex moves farther than :data:`CCD_REACH` diagonals."""
        bound = 1.0
        if np.array_equal(start, end):  # no motion (the step's start as a first guess)
            return bound
        move = float(np.linalg.norm(end - start, axis=1).max())
        reach = CCD_REACH * self._diagonal
        share = min(1.0, reach / move) if reach > 0.0 else 1.0
        if share < 1.0:
            end = np.asfortranarray(start + share * (end - start))
        if self._toolkit_pairs:
            bound = float(self._ipctk.compute_collision_free_stepsize(self.mesh, start, end, 0.0, None, self._ccd))
        if len(self.round):
            bound = min(bound, self.round.step_bound(start[: self.num_points], end[: self.num_points]))
        return share * bound

    @property
    def diagonal(self) -> float:
        """The diagonal [m] of the bodies' rest bounding box (``dhat``'s and the growth distance's scale)."""
        return self._diagonal

    @property
    def tests_steps(self) -> bool:
        """Whether :meth:`step_converged` is on (a ``velocity_tolerance`` is set)."""
        return self.velocity_tolerance is not None

    @_timed
    def step_converged(self, state: ContributionState, direction: np.ndarray) -> bool:
        """Collective: IPC's termination test (libuipc's ``velocity_tol``): a time step's Newton
        ends with a step ``direction`` that moves no vertex of the collision mesh by more than
        ``velocity_tolerance * dt`` and is collision-free in full (a step the barrier cuts short
        still closes in on a contact)."""
        if not self.tests_steps:
            return False
        start = self._vertices(state.positions)
        end = self._vertices(np.asarray(state.positions) + np.asarray(direction).reshape(-1, 3))
        moved = float(np.max(np.linalg.norm((end - start)[: self.num_points], axis=1), initial=0.0))
        if moved > self.velocity_tolerance * self._step[1]:
            return False
        return self._collision_free_fraction(start, end) >= 1.0

    def _translation_weights(self) -> np.ndarray:
        """Weights ``c`` ``(local blocks,)`` with ``local_map @ c = 1`` where the rank holds points:
        adding ``c t`` to the blocks translates their points by ``t`` (B-spline control points 1,
        Hermite nodal values 1 and derivatives 0; least squares on the map)."""
        rows = np.flatnonzero(np.diff(self.local_map.indptr))
        weights = np.zeros(self.local_map.shape[1])
        if len(rows):
            weights = scipy.sparse.linalg.lsqr(self.local_map[rows], np.ones(len(rows)), atol=1e-14, btol=1e-14)[0]
        return weights

    @_timed
    def carried(self, state: ContributionState, since: float) -> tuple[np.ndarray, np.ndarray]:
        """Collective: the open blocks ``(blocks,)`` (a mask) of every point within dhat plus an
        obstacle's travel from the fraction ``since`` of the step to its end, and the displacement
        ``(blocks, 3)`` that moves them by that travel (a translation of their points)."""
        time, dt = self._step
        remaining = (1.0 - since) * dt
        displacement = np.zeros_like(np.asarray(state.positions, dtype=float).reshape(-1, 3))
        carried = np.zeros(len(displacement), dtype=bool)
        if not self.moving:
            return carried, displacement
        at = time + since * dt
        shell = self._vertices(state.positions)[: self.num_points]  # wherever the obstacles are placed
        travels, reached = [], []
        for plane in self._planes:
            travel = remaining * plane[2]
            travels.append(travel)
            reached.append(self._plane_gaps(shell, plane, at) < self.dhat + max(travel @ plane[0], 0.0))
        start = 0
        for velocity, points in self._mesh_groups:
            travel = remaining * velocity
            vertices = self._obstacle_rest[start:start + points] + at * velocity
            start += points
            low = np.minimum(vertices.min(axis=0), vertices.min(axis=0) + travel) - self.dhat
            high = np.maximum(vertices.max(axis=0), vertices.max(axis=0) + travel) + self.dhat
            travels.append(travel)
            reached.append(np.all((shell >= low) & (shell <= high), axis=1))
        for travel, near in zip(travels, reached, strict=True):
            if np.any(travel) and np.any(near):  # the same on every rank: the vertices are everyone's
                # a block is carried on every rank that holds it (owned or ghost), whichever holds the point
                local = np.unique(self.local_map[np.flatnonzero(near)].indices)
                union = np.unique(np.concatenate(self._comm.allgather(self._global_blocks[local])))
                blocks = np.flatnonzero(np.isin(self._global_blocks, union))
                displacement[blocks] = self._translation[blocks, None] * travel
                carried[blocks] = True
        return carried, displacement

    def place_obstacles_within_step(self, fraction: float) -> None:
        """Put the translating obstacles where they are at ``fraction`` of the step of the last
        :meth:`begin_step` (1: its end)."""
        time, dt = self._step
        self.place_obstacles(time + fraction * dt)

    def max_swept_step(self, state: ContributionState, direction: np.ndarray, since: float = 0.0) -> float:
        """Collective: :meth:`max_step` of a guess within the step of the last :meth:`begin_step`,
        the obstacles moving along with it from where they are at the fraction ``since`` of the step
        to where they are at its end (and left there). ipc-toolkit's CCD takes the moving meshes;
        planes are met here, a vertex stopping where :data:`PLANE_GAP_KEPT` of its gap is left."""
        if not self.moving:
            return self.max_step(state, direction)
        return self._swept_bound(state, direction, since)

    @_timed
    def _swept_bound(self, state: ContributionState, direction: np.ndarray, since: float) -> float:
        """:meth:`max_swept_step` with moving obstacles."""
        time, dt = self._step
        start_time, end_time = time + since * dt, time + dt
        end_positions = np.asarray(state.positions) + np.asarray(direction).reshape(-1, 3)
        self.place_obstacles(start_time)
        start = self._vertices(state.positions)
        self.place_obstacles(end_time)
        end = self._vertices(end_positions)
        planes, self.mesh.planes = self.mesh.planes, []
        try:
            bound = self._collision_free_fraction(start, end)
        finally:
            self.mesh.planes = planes
        shell = slice(0, self.num_points)
        for plane in self._planes:
            gap_start = self._plane_gaps(start[shell], plane, start_time)
            gap_end = self._plane_gaps(end[shell], plane, end_time)
            closing = gap_end < PLANE_GAP_KEPT * gap_start
            if np.any(closing):
                fractions = (1.0 - PLANE_GAP_KEPT) * gap_start[closing] / (gap_start[closing] - gap_end[closing])
                bound = min(bound, float(np.clip(fractions, 0.0, 1.0).min()))
        return bound

    def min_distance(self, positions: np.ndarray) -> float:
        """Collective: the smallest distance [m] between the mesh and the obstacles within ``dhat``
        (``inf`` if none is)."""
        vertices = self._vertices(positions)
        distance = closest_distance(self._collisions(vertices), self.mesh, vertices)
        return min(distance, self.round.min_distance(vertices[: self.num_points])) if len(self.round) else distance

    def starting_problem(self, positions: np.ndarray) -> str | None:
        """Collective: why the mesh at ``positions`` cannot start a barrier solve (it intersects an
        obstacle, or a vertex lies on or behind a plane), or None."""
        vertices = self._vertices(positions)
        shell = np.asarray(vertices[: self.num_points])
        for k, plane in enumerate(self.mesh.planes):
            normal, offset = np.asarray(plane.normal()).ravel(), float(plane.offset())
            behind = np.flatnonzero(shell @ normal + offset <= 0.0)
            if len(behind):
                index = self._plane_colliders[k]
                name = self.collider_names[index] if self.collider_names else f"collider {index}"
                return (f"{name} (a plane) has {len(behind)} collision vertices on or behind it, "
                        f"e.g. {shell[behind[0]]}")
        behind = self.round.behind(shell) if len(self.round) else None
        if behind is not None:
            index, vertex, gap, offset = behind
            name = self.collider_names[index] if self.collider_names else f"collider {index}"
            return (f"{name} has collision vertices within {offset:.3g} m "
                    f"of it (the offset that keeps the mesh's triangles out of it), e.g. {shell[vertex]} "
                    f"({gap:.3g} m from there)")
        if self._toolkit_pairs and self._ipctk.has_intersections(self.mesh, vertices):
            within = ", or within a body that meets itself" if self.self_contact else ""
            return f"the collision mesh intersects (between bodies, or with a collider mesh{within})"
        return None

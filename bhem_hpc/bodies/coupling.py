"""The penalty coupling that joins shell patches along an interface into one shell (numpy only):
an energy contribution on the stacked problem of the patches
(:class:`~bhem_hpc.bodies.petsc.StackedProblem`).

Along the interface (:class:`~bhem_hpc.geometry.interfaces.EdgeQuadrature`: points ``k`` with rest
arc-length weights ``w_k``, parameters on patch A and patch B), the energy is

    E = sum_k w_k [ a_d/2 |d_k|^2 + a_r/2 |r_k|^2 ],
    d = (x_A - x_B) - (X_A - X_B),
    r = n_B - (cos f0 n_A + sin f0 m_A) - r_0,

``n`` the unit normals, ``m_A = t x n_A`` patch A's conormal (``t`` the unit tangent of A's edge),
``cos f0 = N_A.N_B`` and ``sin f0 = N_B.M_A`` the rest angle between the patches and ``r_0`` the
rest value of the bracket (zero where the rest normals are both normal to the edge). ``d`` keeps
the patches together (C0); ``r`` keeps the angle between them - zero at a smooth interface, the
fold angle at a kink - in the rotation-invariant frame of patch A (the normal-and-conormal penalty
of Herrema et al. 2019, "Penalty coupling of non-matching isogeometric Kirchhoff-Love shell
patches", written as one vector). Both terms vanish for rigid motions and for any deformation
that moves both sides alike, so a constant strain across the interface costs nothing.

A seam (``sewing_time``) is the same energy between panels apart at rest whose target offset
``X_A - X_B`` shrinks to zero over the sewing time: each pair of partners is pulled together along
the line between their rest positions (a quadratic, convex pull; once sewn, the seam is a joint).

The gradient is exact; the Hessian is exact for ``d`` and Gauss-Newton (``J^T J``) for ``r``:
positive semi-definite, as every contribution's Hessian is, and exact at the rest angle.

Penalty rule (:func:`penalty_stiffness`): ``a_d = alpha E t / ((1 - nu^2) h)`` and
``a_r = alpha D / h`` with ``D = E t^3 / (12 (1 - nu^2))``: ``alpha`` times the membrane and bending
stiffness of a strip of the patches' element size ``h`` across the interface.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from mpi4py import MPI

from bhem_hpc.geometry.interfaces import EdgeQuadrature, Patch
from bhem_hpc.solver.contributions import ContributionState, PointBasis

#: Slots of a quadrature point's variables: patch A's position and tangents, then patch B's.
SLOTS = 6
#: The slots the rotation term reads (A's tangents a1, a2; B's tangents a1, a2).
TANGENT_SLOTS = (1, 2, 4, 5)
#: The default penalty factor ``alpha`` (:func:`penalty_stiffness`).
DEFAULT_PENALTY = 1.0e3


class FrameBlocks(Protocol):
    """Where a coupling sees the patches' open blocks (a stacked problem or its ``StackedBlocks``)."""

    comm: MPI.Comm
    global_open_blocks: np.ndarray

    def point_frame_basis(self, body: int, xi1: float, xi2: float) -> PointBasis:
        """``(rows, values (3, n))``: position and tangents of a material point of ``body``."""
        ...


def penalty_stiffness(young: float, poisson: float, thickness: float, element: float,
                      factor: float = DEFAULT_PENALTY) -> tuple[float, float]:  # fmt: skip
    """``(a_d [N/m^2], a_r [N])``: ``factor`` times the membrane and the bending stiffness of a strip
    ``element`` [m] wide (the module's rule)."""
    plate = 1.0 - poisson**2
    return factor * young * thickness / (plate * element), factor * young * thickness**3 / (12 * plate * element)


def rest_frames(first: Patch, second: Patch, quadrature: EdgeQuadrature) -> np.ndarray:
    """The rest position and tangents of each quadrature point on both patches, ``(k, 6, 3)`` in
    the order of :data:`SLOTS`."""
    a = first.evaluate(quadrature.first[:, 0], quadrature.first[:, 1])
    b = second.evaluate(quadrature.second[:, 0], quadrature.second[:, 1])
    return np.stack([a.x, a.a1, a.a2, b.x, b.a1, b.a2], axis=1)


def _skew(v: np.ndarray) -> np.ndarray:
    """``[v]_x`` ``(k, 3, 3)`` of vectors ``(k, 3)``: ``[v]_x u = v x u``."""
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    out[..., 1, 0], out[..., 2, 0], out[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return out


def _unit(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(v / |v|, d(v/|v|)/dv)`` of vectors ``(k, 3)``."""
    length = np.linalg.norm(v, axis=-1)[:, None]
    unit = v / length
    return unit, (np.eye(3) - unit[:, :, None] * unit[:, None, :]) / length[:, :, None]


def _normal(a1: np.ndarray, a2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The unit normal ``(k, 3)`` of tangents ``a1 x a2`` and its derivatives by a1 and by a2 ``(k, 3, 3)``."""
    n, by_c = _unit(np.cross(a1, a2))
    return n, by_c @ -_skew(a2), by_c @ _skew(a1)


@dataclass(frozen=True)
class _Frames:
    """Patch A's unit normal, edge tangent and conormal and patch B's unit normal ``(k, 3)``, with the
    derivatives ``(k, 3, 3)`` of the normals by each tangent and of A's edge tangent by its own."""

    n_a: np.ndarray
    n_a1: np.ndarray
    n_a2: np.ndarray
    t: np.ndarray
    t_e: np.ndarray
    m_a: np.ndarray
    n_b: np.ndarray
    n_b1: np.ndarray
    n_b2: np.ndarray

    @staticmethod
    def of(frames: np.ndarray, along: int | np.ndarray) -> _Frames:
        n_a, n_a1, n_a2 = _normal(frames[:, 1], frames[:, 2])
        n_b, n_b1, n_b2 = _normal(frames[:, 4], frames[:, 5])
        c = _directions(along, len(frames))
        t, t_e = _unit(c[:, :1] * frames[:, 1] + c[:, 1:] * frames[:, 2])
        return _Frames(n_a, n_a1, n_a2, t, t_e, np.cross(t, n_a), n_b, n_b1, n_b2)


def _directions(along: int | np.ndarray, count: int) -> np.ndarray:
    """The interface's direction in patch A's parameters at each point ``(k, 2)``: ``along`` 0 or 1
    (an edge: a1 or a2), or the directions themselves (a curve, :attr:`EdgeQuadrature.directions`)."""
    if isinstance(along, int | np.integer):
        return np.tile(np.eye(2)[int(along)], (count, 1))
    return np.asarray(along, dtype=float).reshape(count, 2)


def rest_angles(frames: np.ndarray, along: int | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(cos f0, sin f0, r_0)`` ``(k,), (k,), (k, 3)`` of rest frames ``(k, 6, 3)`` (``along``: which
    tangent of patch A runs along its edge, 0: a1, 1: a2; or each point's direction ``(k, 2)`` in
    A's parameters, the interface's tangent ``t ~ c1 a1 + c2 a2``)."""
    f = _Frames.of(frames, along)
    cos0, sin0 = np.einsum("kc,kc->k", f.n_a, f.n_b), np.einsum("kc,kc->k", f.m_a, f.n_b)
    return cos0, sin0, f.n_b - cos0[:, None] * f.n_a - sin0[:, None] * f.m_a


def angle_residual(frames: np.ndarray, along: int | np.ndarray,
                   rest: tuple[np.ndarray, np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The rotation term's residual ``r (k, 3)`` at frames ``(k, 6, 3)`` and its derivatives
    ``J (k, 4, 3, 3)`` by the tangent slots (:data:`TANGENT_SLOTS`); ``along`` as for
    :func:`rest_angles`, ``rest`` from it."""
    f = _Frames.of(frames, along)
    c = _directions(along, len(frames))
    cos0, sin0, r0 = rest
    # m_A = t x n_A with t ~ c1 a1 + c2 a2: dm_A = -[n_A]x dt + [t]x dn_A, dt = t_e c_i da_i
    m_a1 = _skew(f.t) @ f.n_a1 - c[:, 0, None, None] * (_skew(f.n_a) @ f.t_e)
    m_a2 = _skew(f.t) @ f.n_a2 - c[:, 1, None, None] * (_skew(f.n_a) @ f.t_e)
    c, s = cos0[:, None, None], sin0[:, None, None]
    residual = f.n_b - cos0[:, None] * f.n_a - sin0[:, None] * f.m_a - r0
    return residual, np.stack([-c * f.n_a1 - s * m_a1, -c * f.n_a2 - s * m_a2, f.n_b1, f.n_b2], axis=1)


@dataclass
class _Point:
    """A quadrature point's blocks: the rows (contributions' layout) of the sides this rank owns,
    and on every rank each side's global blocks and basis ``(3, n)``."""

    rows: list[np.ndarray]  # per side, empty where this rank does not own it
    global_blocks: list[np.ndarray]
    bases: list[np.ndarray]

    def coefficients(self) -> np.ndarray:
        """``(n_A + n_B, 6)``: how each block enters each slot."""
        n_a = len(self.global_blocks[0])
        out = np.zeros((n_a + len(self.global_blocks[1]), SLOTS))
        out[:n_a, :3], out[n_a:, 3:] = self.bases[0].T, self.bases[1].T
        return out


class InterfaceCoupling:
    """The penalty coupling (module docstring) of patch ``bodies[0]`` and patch ``bodies[1]`` along an
    interface, an energy contribution of the stacked problem.

    Args:
        blocks: the stacked problem (or its blocks) of the patches.
        bodies: the two patches' places among the bodies.
        quadrature: the interface's points (:func:`~bhem_hpc.geometry.interfaces.pair_edges`).
        frames: their rest frames ``(k, 6, 3)`` (:func:`rest_frames`).
        stiffness: ``(a_d, a_r)`` (:func:`penalty_stiffness`).
        name: names the interface in messages.
    """

    def __init__(self, blocks: FrameBlocks, bodies: tuple[int, int], quadrature: EdgeQuadrature,
                 frames: np.ndarray, stiffness: tuple[float, float], name: str = "interface",
                 sewing_time: float | None = None):  # fmt: skip
        self.name = name
        self.sewing_time = sewing_time
        #: the partners' target offset as a fraction of their rest offset (a seam: 1 when sewing
        #: starts, 0 once sewn; a joint: 1)
        self.stitch_scale = 1.0
        self.comm = blocks.comm
        #: the interface's direction in the first patch's parameters (an edge: its index; a curve: per point)
        self.along = quadrature.along if quadrature.directions is None else quadrature.directions
        self.weights = np.asarray(quadrature.weights, dtype=float)
        self.displacement_stiffness, self.rotation_stiffness = (float(v) for v in stiffness)
        frames = np.asarray(frames, dtype=float)
        self.rest_offset = frames[:, 0] - frames[:, 3]
        self.rest = rest_angles(frames, self.along)
        sides = [(bodies[0], quadrature.first), (bodies[1], quadrature.second)]
        local = [[blocks.point_frame_basis(body, *map(float, xi)) for xi in parameters] for body, parameters in sides]
        owned = [[(k, blocks.global_open_blocks[rows], values) for k, (rows, values) in enumerate(side) if len(rows)]
                 for side in local]  # fmt: skip
        gathered = [dict((k, (g, v)) for part in self.comm.allgather(side) for k, g, v in part) for side in owned]
        self.points = [_Point([local[s][k][0] for s in (0, 1)], [gathered[s][k][0] for s in (0, 1)],
                              [gathered[s][k][1] for s in (0, 1)]) for k in range(len(self.weights))]  # fmt: skip
        # every point's position and tangents as material points (each on the rank owning it)
        self._bases: list[PointBasis] = [(rows, values[d]) for k in range(len(self.weights)) for s in (0, 1)
                                         for rows, values in [local[s][k]] for d in range(3)]  # fmt: skip
        self._coefficients = [p.coefficients() for p in self.points]
        self._pattern = self._make_pattern()

    def _row_range(self, point: _Point) -> np.ndarray:
        """The entries of a point's blocks this rank adds rows for (the sides it owns)."""
        n_a = len(point.global_blocks[0])
        parts = [np.arange(n_a)] if len(point.rows[0]) else []
        parts += [n_a + np.arange(len(point.global_blocks[1]))] if len(point.rows[1]) else []
        return np.concatenate(parts) if parts else np.zeros(0, np.int64)

    def _make_pattern(self) -> tuple[np.ndarray, np.ndarray]:
        rows, columns = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
        for point in self.points:
            blocks = np.concatenate(point.global_blocks)
            mine = blocks[self._row_range(point)]
            rows.append(np.repeat(mine, len(blocks)))
            columns.append(np.tile(blocks, len(mine)))
        return np.concatenate(rows), np.concatenate(columns)

    def hessian_pattern(self) -> tuple[np.ndarray, np.ndarray]:
        return self._pattern

    def frames(self, state: ContributionState) -> np.ndarray:
        """Collective: every point's position and tangents on both patches, ``(k, 6, 3)``."""
        return state.point_positions(self._bases).reshape(-1, SLOTS, 3)

    def begin_step(self, state: ContributionState, time: float, dt: float) -> None:
        """A seam's stitches shorten linearly over its sewing time: their length at the step's end."""
        if self.sewing_time is not None:
            self.stitch_scale = max(0.0, 1.0 - (time + dt) / self.sewing_time)

    def _stitches(self, frames: np.ndarray) -> np.ndarray:
        """``d (k, 3)``: how far each pair of partners is from its target offset, :attr:`stitch_scale`
        times the rest offset (a joint's stays 1: its rest offset, about zero; a seam's goes to 0,
        pulling each pair together along the line between their rest positions)."""
        return frames[:, 0] - frames[:, 3] - self.stitch_scale * self.rest_offset

    def energy(self, state: ContributionState) -> float:
        if not len(self.weights):
            return 0.0
        frames = self.frames(state)
        d = self._stitches(frames)
        r, _ = angle_residual(frames, self.along, self.rest)
        energy = 0.5 * np.sum(self.weights * (self.displacement_stiffness * np.sum(d * d, axis=1)
                                              + self.rotation_stiffness * np.sum(r * r, axis=1)))  # fmt: skip
        return float(energy) if self.comm.rank == 0 else 0.0

    def slot_gradients(self, frames: np.ndarray) -> np.ndarray:
        """dE/d of each point's slots, ``(k, 6, 3)``."""
        pull = self._stitches(frames)
        r, jacobian = angle_residual(frames, self.along, self.rest)
        out = np.zeros((len(frames), SLOTS, 3))
        out[:, 0] = self.displacement_stiffness * self.weights[:, None] * pull
        out[:, 3] = -out[:, 0]
        out[:, list(TANGENT_SLOTS)] = self.rotation_stiffness * self.weights[:, None, None] * np.einsum(
            "ksij,ki->ksj", jacobian, r)  # fmt: skip
        return out

    def add_gradient(self, state: ContributionState, gradient: np.ndarray) -> None:
        if not len(self.weights):
            return
        slots = self.slot_gradients(self.frames(state))
        for point, slot, coefficients in zip(self.points, slots, self._coefficients, strict=True):
            n_a = len(point.global_blocks[0])
            for side, part in ((0, slice(0, n_a)), (1, slice(n_a, None))):
                if len(point.rows[side]):
                    gradient[point.rows[side]] += coefficients[part] @ slot

    def slot_hessians(self, frames: np.ndarray) -> np.ndarray:
        """The Hessian on each point's slots, ``(k, 6, 6, 3, 3)`` (Gauss-Newton for the angle)."""
        _, jacobian = angle_residual(frames, self.along, self.rest)
        out = np.zeros((len(frames), SLOTS, SLOTS, 3, 3))
        block = self.displacement_stiffness * self.weights[:, None, None] * np.eye(3)
        out[:, 0, 0], out[:, 3, 3], out[:, 0, 3], out[:, 3, 0] = block, block, -block, -block
        rotation = self.rotation_stiffness * self.weights[:, None, None, None, None] * np.einsum(
            "ksij,ktil->kstjl", jacobian, jacobian)  # fmt: skip
        for i, slot_i in enumerate(TANGENT_SLOTS):
            for j, slot_j in enumerate(TANGENT_SLOTS):
                out[:, slot_i, slot_j] += rotation[:, i, j]
        return out

    def hessian(self, state: ContributionState) -> np.ndarray:
        if not len(self.weights):
            return np.zeros((0, 3, 3))
        slots = self.slot_hessians(self.frames(state))
        parts = [np.zeros((0, 3, 3))]
        for point, slot, coefficients in zip(self.points, slots, self._coefficients, strict=True):
            mine = self._row_range(point)
            if len(mine):
                rows = np.tensordot(coefficients[mine], slot, axes=(1, 0))  # (rows, t, 3, 3)
                blocks = np.tensordot(rows, coefficients, axes=(1, 1))  # (rows, 3, 3, columns)
                parts.append(blocks.transpose(0, 3, 1, 2).reshape(-1, 3, 3))
        return np.concatenate(parts)

"""An SEM solid as a body of the Newton driver: its DOFs, state, constraints and incremental
potential, split among ranks (numpy, scipy and mpi4py; no PETSc here).

The DOFs are the solid's control points, interleaved (``3 * point + component``). Each rank owns a
contiguous range of the points (:attr:`SolidModel.owned`) and holds the whole state: a solid has
thousands of DOFs where a shell has millions, and every quadrature point sees the control points of
the parts blended there, which may be anywhere in the numbering. The quadrature points are split
among the ranks in contiguous shares; each rank adds the elastic energy of its share, rank 0 the
terms over all DOFs (inertia, the error energy, dead loads), and the sum over ranks is the
incremental potential

    E(q) = |q - q_pred|^2_M / (2 dt^2) + sum_k v_k psi(F_k) + gamma |Phi_b Pi q - J q|^2_S - s f . q

with ``s`` the load factor and ``f`` the dead loads (gravity, forces on control points).
:class:`SolidState` advances the state as :class:`~bhem_hpc.solver.state.ShellState` does a shell's.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse
from mpi4py import MPI

from bhem_hpc.errors import UserError
from bhem_hpc.geometry.nurbs import NurbsSurface
from bhem_hpc.solids.equilibrium import STATIC_SHIFT
from bhem_hpc.solids.sem import ShapeMatchingSolid
from bhem_hpc.solver.state import StateCorrection, StepStart

#: The Hessian kinds a solid can assemble; the shells' kinds that are not ``"exact"`` (the
#: adaptive ladder's rung ``"out_of_plane"``, ``"pseudo"``) give a solid its projected Hessian.
SOLID_HESSIANS = ("exact", "projected")


class Parameter:
    """A scalar the energy reads and the driver sets (as dolfinx's ``fem.Constant``): ``value``."""

    def __init__(self, value: float):
        self.value = float(value)


@dataclass(frozen=True)
class SolidDynamics:
    """Implicit Euler of a solid: the time step [s]."""

    time_step: float


@dataclass(frozen=True)
class FixedPoints:
    """Control points held: ``points (k,)`` indices into the stacked control points, ``components``
    the coordinates held (0, 1, 2), ``targets (k, 3)`` where they are held (None: where they are)."""

    points: np.ndarray
    components: tuple[int, ...] = (0, 1, 2)
    targets: np.ndarray | None = None


@dataclass(frozen=True)
class SolidFrame:
    """A solid's state for output: its ``parts`` deformed, the quadrature points' ``positions (Q, 3)``,
    Cauchy ``stresses (Q, 3, 3)`` [Pa] and reference ``volumes (Q,)`` [m^3]."""

    parts: list[NurbsSurface]
    positions: np.ndarray
    stresses: np.ndarray
    volumes: np.ndarray

    @property
    def nodal(self) -> np.ndarray:
        """``(n_q, 3)`` the control points (what a checkpoint keeps of a shell's frame as its nodal data)."""
        return np.concatenate([part.control.reshape(-1, 3) for part in self.parts])


def block_range(count: int, rank: int, size: int) -> tuple[int, int]:
    """The contiguous range of ``count`` blocks rank ``rank`` of ``size`` owns (PETSc's split)."""
    base, extra = divmod(count, size)
    start = rank * base + min(rank, extra)
    return start, start + base + (rank < extra)


class SolidModel:
    """An SEM solid with its dynamics, dead loads and held control points, on ``comm``.

    Args:
        solid: the preprocessed solid (replicated on every rank).
        comm: the communicator of the solve.
        dynamics: implicit Euler settings, None for statics.
        gravity: ``(3,)`` [m/s^2].
        point_forces: ``(n_q, 3)`` forces on the control points [N], or None.
        body_force: ``t -> (3,)`` a time-dependent force per unit mass [m/s^2] besides gravity
            (a periodic wind), or None.
        initial_velocity: ``(3,)`` every control point's velocity at the start [m/s].
        fixed: held control points.
        hessian: the Hessian kind of the solve (:data:`SOLID_HESSIANS`, or a shell's composed kind).
        initial: ``(n_q, 3)`` the control points at the start (None: the rest shape).

    Raises:
        UserError: a held point or component out of range, targets of the wrong shape.
    """

    symmetric = True
    has_potential = True
    closed_is_open = False  # assembled as AIJ, never the serial one-triangle path

    def __init__(
        self,
        solid: ShapeMatchingSolid,
        comm: MPI.Comm,
        dynamics: SolidDynamics | None = None,
        gravity: Sequence[float] = (0.0, 0.0, 0.0),
        point_forces: np.ndarray | None = None,
        fixed: Sequence[FixedPoints] = (),
        hessian: str = "projected",
        initial: np.ndarray | None = None,
        body_force: Callable[[float], np.ndarray] | None = None,
        initial_velocity: Sequence[float] | None = None,
    ):
        self.solid, self.comm, self.dynamics, self.hessian = solid, comm, dynamics, hessian
        self.name = solid.name
        count = len(solid.reference)
        self.owned = block_range(count, comm.rank, comm.size)
        self.share = solid.share(comm.rank, comm.size)
        self.load_factor = Parameter(1.0)
        self.time_step = Parameter(dynamics.time_step if dynamics is not None else 0.0)
        self.gravity = np.asarray(gravity, dtype=float)
        self.body_force = body_force
        self.point_forces = None if point_forces is None else np.asarray(point_forces, dtype=float).reshape(-1)
        self.set_time(0.0)
        self.mass_matrix = solid.mass_matrix() if dynamics is not None else None
        # control-point motions no quadrature point sees have no stiffness: a diagonal shift keeps
        # Newton's steps finite along them (fixed at the rest state: the same on every rank)
        self._rest_stiffness = solid.hessian(solid.reference, projected=False)  # F = I: PSD as it is
        self.diagonal_shift = STATIC_SHIFT * float(self._rest_stiffness.diagonal().max())
        start = solid.reference.reshape(-1).copy() if initial is None else np.asarray(initial, float).reshape(-1)
        self.position = start.copy()
        self.velocity = np.zeros_like(start)
        if initial_velocity is not None:
            self.velocity[:] = np.tile(np.asarray(initial_velocity, dtype=float), len(start) // 3)
        self.previous = start.copy()
        self.predicted = start.copy()
        self.initial = start.copy()
        self.constrained, targets = self._constrained(fixed)
        mine = (self.constrained >= 3 * self.owned[0]) & (self.constrained < 3 * self.owned[1])
        #: this rank's held DOFs: local indices within its owned DOFs, global rows, targets
        self.constrained_local = self.constrained[mine] - 3 * self.owned[0]
        self.constrained_rows = self.constrained[mine]
        self.constrained_target = targets[mine]
        self.constrained_initial = self.initial[self.constrained_rows]

    def _constrained(self, fixed: Sequence[FixedPoints]) -> tuple[np.ndarray, np.ndarray]:
        count = len(self.solid.reference)
        values = self.initial.reshape(-1, 3).copy()
        held = np.zeros((count, 3), dtype=bool)
        for group in fixed:
            points = np.asarray(group.points, dtype=np.int64).reshape(-1)
            if points.size and (points.min() < 0 or points.max() >= count):
                raise UserError(f"{self.name}: held control points must lie in [0, {count}), got "
                                f"[{points.min()}, {points.max()}]")  # fmt: skip
            if not set(group.components) <= {0, 1, 2}:
                raise UserError(f"{self.name}: held components must be 0, 1 or 2, got {group.components}")
            components = list(group.components)
            held[np.ix_(points, components)] = True
            if group.targets is not None:
                targets = np.asarray(group.targets, dtype=float)
                if targets.shape != (len(points), 3):
                    raise UserError(f"{self.name}: targets of {len(points)} held points must have shape "
                                    f"({len(points)}, 3), got {targets.shape}")  # fmt: skip
                values[np.ix_(points, components)] = targets[:, components]
        rows = np.flatnonzero(held.reshape(-1))
        return rows, values.reshape(-1)[rows]

    def set_time(self, t: float) -> None:
        """The dead loads at time ``t``: gravity, the body force and the point forces."""
        acceleration = self.gravity if self.body_force is None else self.gravity + self.body_force(t)
        forces = self.solid.gravity_force(acceleration)
        self.dead_loads = forces if self.point_forces is None else forces + self.point_forces

    def state_surface(self) -> SolidFrame:
        """The current state for output (on every rank)."""
        q = self.position.reshape(-1, 3)
        solid = self.solid
        return SolidFrame(solid.deformed_parts(q), solid.positions(q), solid.cauchy_stresses(q),
                          solid.quadrature.weights)  # fmt: skip

    # -- what the driver asks of a body -------------------------------------------------------
    @property
    def closed_dofs(self) -> tuple[int, int]:
        """DOFs this rank owns and in all."""
        return 3 * (self.owned[1] - self.owned[0]), 3 * len(self.solid.reference)

    @property
    def open_blocks(self) -> tuple[int, int]:
        """Blocks this rank owns and the others it holds (every control point)."""
        owned = self.owned[1] - self.owned[0]
        return owned, len(self.solid.reference) - owned

    @property
    def global_open_blocks(self) -> np.ndarray:
        """The global block of each row of :attr:`open_positions` (all, in order)."""
        return np.arange(len(self.solid.reference), dtype=np.int64)

    @property
    def open_positions(self) -> np.ndarray:
        """``(n_q, 3)`` the control points (a view)."""
        return self.position.reshape(-1, 3)

    @property
    def force_scale(self) -> float:
        """Young's modulus times the largest extent squared [N]: the scale of the internal forces."""
        extent = np.ptp(self.solid.reference, axis=0).max()
        return max(m.young for m in self.solid.materials) * float(extent) ** 2

    @property
    def linear_scales(self) -> tuple[float, float, float, float]:
        """Density, Young's modulus, Poisson's ratio and the control net's median edge [m]."""
        material = self.solid.materials[0]
        edges = [np.linalg.norm(np.diff(p.control, axis=a), axis=-1).ravel() for p in self.solid.parts for a in (0, 1)]
        return material.density, material.young, material.poisson, float(np.median(np.concatenate(edges)))

    def point_basis(self, xi1: float, xi2: float):
        raise UserError(f"{self.name}: a solid's points are its control points, not surface parameters "
                        f"({xi1}, {xi2})")  # fmt: skip

    def open_state(self) -> tuple[np.ndarray, np.ndarray | None]:
        """Copies of the position and, in dynamics, the previous position."""
        return self.position.copy(), self.previous.copy() if self.dynamics is not None else None

    def set_open_state(self, position: np.ndarray, previous: np.ndarray | None) -> None:
        self.position[:] = position
        if previous is not None:
            self.previous[:] = previous

    def gather_raw(self, array: np.ndarray) -> np.ndarray:
        """An open array as raw DOFs ``(n_q, 3)`` (the whole array is on every rank)."""
        return np.asarray(array, dtype=float).reshape(-1, 3).copy()

    def scatter_raw(self, raw: np.ndarray) -> np.ndarray:
        """Raw DOFs ``(n_q, 3)`` as the open array ``(3 n_q,)``."""
        return np.asarray(raw, dtype=float).reshape(-1).copy()

    # -- the incremental potential, this rank's part --------------------------------------------
    def _rank0(self) -> bool:
        return self.comm.rank == 0

    def local_terms(self) -> dict[str, float]:
        """This rank's part of each term's energy [J] at the current position."""
        q = self.position
        terms = {"elasticity": self.share.energy(q)}
        if self._rank0():
            terms["error"] = 0.5 * float(q @ (self.solid.error_matrix @ q))
            terms["loads"] = -float(self.load_factor.value) * float(self.dead_loads @ q)
            if self.dynamics is not None:
                step = q - self.predicted
                terms["inertia"] = 0.5 * float(step @ (self.mass_matrix @ step)) / self.time_step.value**2
        return terms

    def local_gradients(self) -> dict[str, np.ndarray]:
        """This rank's part of each term's gradient ``(3 n_q,)`` (the same terms on every rank)."""
        q = self.position
        gradients = {"elasticity": self.share.gradient(q)}
        names = ("error", "loads", "inertia") if self.dynamics is not None else ("error", "loads")
        if not self._rank0():  # the same terms on every rank: their norms are summed over the ranks
            return gradients | {name: np.zeros_like(q) for name in names}
        gradients["error"] = self.solid.error_matrix @ q
        gradients["loads"] = -float(self.load_factor.value) * self.dead_loads
        if self.dynamics is not None:
            gradients["inertia"] = self.mass_matrix @ (q - self.predicted) / self.time_step.value**2
        return gradients

    def local_hessian(self, kind: str) -> scipy.sparse.csr_matrix:
        """This rank's part of the Hessian ``(3 n_q, 3 n_q)``: exact for ``"exact"``, each quadrature
        point's tangent projected positive semi-definite for every other kind."""
        hessian = self.share.hessian(self.position, projected=kind != "exact")
        if self._rank0():
            hessian = hessian + self.solid.error_matrix
            hessian = hessian + self.diagonal_shift * scipy.sparse.identity(hessian.shape[0])
            if self.dynamics is not None:
                hessian = hessian + self.mass_matrix / self.time_step.value**2
        hessian = hessian.tocsr()
        # a share's fixed pattern holds exact zeros where its merged point groups pad columns their
        # points do not see; the Jacobian is preallocated for the entries that can be nonzero only
        hessian.eliminate_zeros()
        return hessian

    def hessian_pattern(self) -> scipy.sparse.csr_matrix:
        """Every entry any rank's Hessian may have (on every rank): the stiffness of all points,
        the error energy, the mass and the diagonal."""
        pattern = abs(self._rest_stiffness) + scipy.sparse.identity(self._rest_stiffness.shape[0])
        if self.mass_matrix is not None:
            pattern = pattern + abs(self.mass_matrix)
        return pattern.tocsr()


class SolidState:
    """Position, velocity and the step's previous state of a :class:`SolidModel`, with the interface
    of :class:`~bhem_hpc.solver.state.ShellState` (arrays: every control point, interleaved)."""

    def __init__(self, model: SolidModel):
        self.model = model

    @property
    def position(self) -> np.ndarray:
        view = self.model.position.view()
        view.flags.writeable = False
        return view

    @property
    def velocity(self) -> np.ndarray:
        view = self.model.velocity.view()
        view.flags.writeable = False
        return view

    def begin_step(self, dt: float) -> StepStart:
        model = self.model
        start = StepStart(model.position.copy(), model.velocity.copy())
        model.time_step.value = dt
        model.previous[:] = start.position
        model.predicted[:] = start.position + dt * start.velocity
        # the inertial prediction is the first guess where it inverts no quadrature point (an
        # infinite energy would leave the energy line search nothing to compare); else x_n
        admissible = np.isfinite(model.share.energy(model.predicted))
        if model.comm.allreduce(admissible, op=MPI.LAND):
            model.position[:] = model.predicted
        return start

    def roll_back(self, start: StepStart) -> None:
        self.model.position[:] = start.position

    def set_guess(self, position: np.ndarray) -> None:
        self.model.position[:] = position

    def finish_step(self, start: StepStart, dt: float, correction: StateCorrection | None = None) -> None:
        model = self.model
        model.velocity[:] = (model.position - start.position) / dt
        if correction is not None:
            model.velocity[:] += correction.delta_velocity
            model.position[:] += correction.delta_position

    def set_raw(self, position: np.ndarray, velocity: np.ndarray | None = None) -> None:
        """Set x (and v) from raw DOFs ``(n_q, 3)`` as checkpoints hold them."""
        self.model.position[:] = self.model.scatter_raw(position)
        if velocity is not None:
            self.model.velocity[:] = self.model.scatter_raw(velocity)

    def raw_position(self) -> np.ndarray:
        """``(n_q, 3)`` the control points."""
        return self.model.gather_raw(self.model.position)

    def raw_velocity(self) -> np.ndarray:
        return self.model.gather_raw(self.model.velocity)

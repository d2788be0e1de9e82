"""Energy contributions outside UFL: each gives its energy, gradient and a positive semi-definite
Hessian on the open DOF layout, and may bound the line-search step (no PETSc here).

:class:`~bhem_hpc.solver.problem.ShellProblem` adds every contribution of its list to the UFL
terms of the model: energies summed over the ranks, gradients into the residual before the ghost
exchange, Hessian blocks into the Jacobian at a sparsity fixed when the problem is made, and the
smallest step bound of the :class:`StepBounded` ones caps each line search (what a contact barrier
with continuous collision detection needs). Point loads and the augmented-Lagrangian point
constraints are contributions; a caller adds its own (``ShellProblem(..., contributions=[...])``,
``ShellSolver(..., contributions=[...])``) without touching the solver.

Layout: the open DOFs are 3-vectors in blocks; a rank sees its owned and ghost blocks
(``positions``, ``gradient`` and ``direction`` arrays of shape ``(local blocks, 3)``), and Hessian
blocks are named by global block index (:attr:`~bhem_hpc.model.shell.ShellModel.global_open_blocks`),
so a contribution may couple blocks that live on different ranks.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from bhem_hpc.solver.step_test import StepVelocityTest

#: A material point's ``(local open blocks, basis values)`` on the rank that owns its patch
#: (empty elsewhere), as ``discretization.point_basis`` gives it.
PointBasis = tuple[np.ndarray, np.ndarray]


@dataclass(frozen=True)
class ContributionState:
    """The iterate as a contribution sees it on this rank.

    Attributes:
        positions: open DOF values of this rank's owned and ghost blocks, shape ``(blocks, 3)``.
        load_factor: the load factor (1 in time steps).
        point_positions: collective; positions ``(points, 3)`` of material points given by their
            :data:`PointBasis` (every rank gets all of them).
    """

    positions: np.ndarray
    load_factor: float
    point_positions: Callable[[Sequence[PointBasis]], np.ndarray]


@runtime_checkable
class Contribution(Protocol):
    """An energy term of the problem outside UFL. Every method is called on every rank in the same
    order (they may be collective); each returns or adds this rank's share only."""

    name: str

    def hessian_pattern(self) -> tuple[np.ndarray, np.ndarray]:
        """The 3x3 blocks this rank adds to the Hessian: global open block ``(rows, columns)``,
        shape ``(k,)`` each, fixed for the problem's life (empty: no Hessian)."""
        ...

    def energy(self, state: ContributionState) -> float:
        """This rank's share of the energy (the problem sums the shares over the ranks)."""
        ...

    def add_gradient(self, state: ContributionState, gradient: np.ndarray) -> None:
        """Add this rank's share of the gradient into ``gradient`` ``(blocks, 3)`` (owned and ghost
        blocks; ghost entries go to their owners)."""
        ...

    def hessian(self, state: ContributionState) -> np.ndarray:
        """The blocks of :meth:`hessian_pattern`, shape ``(k, 3, 3)`` (row-major blocks), positive
        semi-definite as a whole so that every Newton step stays a descent step."""
        ...


@runtime_checkable
class StepBounded(Contribution, Protocol):
    """A contribution that bounds the line search (a barrier that must not be crossed)."""

    def max_step(self, state: ContributionState, direction: np.ndarray) -> float:
        """Collective: the largest ``a`` in ``(0, 1]`` such that ``positions + t direction`` is
        admissible for every ``t <= a`` (``direction``: ``(blocks, 3)``; the same on every rank)."""
        ...


@runtime_checkable
class SweptStepBounded(StepBounded, Protocol):
    """A step-bounded contribution whose obstacles may move during a time step (translating
    colliders): a time step's first guess must not cross them while they move."""

    #: whether some obstacle moves
    moving: bool

    def max_swept_step(self, state: ContributionState, direction: np.ndarray, since: float) -> float:
        """Collective: :meth:`StepBounded.max_step` of a guess within a time step, the obstacles
        moving along with it from their places at the fraction ``since`` of the step to those at
        its end."""
        ...

    def place_obstacles_within_step(self, fraction: float) -> None:
        """Put the obstacles where they are at ``fraction`` of the time step (1: its end, where
        :meth:`StepLagged.begin_step` puts them)."""
        ...

    def carried(self, state: ContributionState, since: float) -> tuple[np.ndarray, np.ndarray]:
        """Collective: the open blocks the moving obstacles reach from the fraction ``since`` of the
        time step to its end ``(blocks,)`` (a mask) and the displacement ``(blocks, 3)`` that moves
        them along with the obstacles (zero elsewhere)."""
        ...


def step_bound(contributions: Sequence[Contribution], state: ContributionState, direction: np.ndarray,
               swept_from: float | None = None) -> float:  # fmt: skip
    """Collective: the largest fraction of ``direction`` ``(blocks, 3)`` from ``state`` that every
    :class:`StepBounded` one of ``contributions`` admits (1: none bounds it); ``swept_from``: a
    guess within a time step, moving obstacles moving along from that fraction of the step to its
    end (:class:`SweptStepBounded`)."""
    blocks = np.asarray(direction, dtype=float).reshape(-1, 3)
    bounds = [c.max_swept_step(state, blocks, swept_from)
              if swept_from is not None and isinstance(c, SweptStepBounded) else c.max_step(state, blocks)
              for c in contributions if isinstance(c, StepBounded)]  # fmt: skip
    return min(1.0, *(float(b) for b in bounds))


@runtime_checkable
class StepTested(Contribution, Protocol):
    """A contribution with a stopping test of its own on Newton's step (IPC's: the full step is
    collision-free and moves no point of the collision mesh by more than a tolerance)."""

    #: whether the test is on (IPC's: a velocity tolerance is set); off, the solver never asks it
    tests_steps: bool

    def step_converged(self, state: ContributionState, direction: np.ndarray) -> bool:
        """Collective: whether a Newton solve at ``state`` ends with the step ``direction``
        ``(blocks, 3)``, taken without a line search (the same answer on every rank)."""
        ...


def step_testers(contributions: Sequence[Contribution]) -> list[StepTested]:
    """The :class:`StepTested` ones of ``contributions`` whose test is on."""
    return [c for c in contributions if isinstance(c, StepTested) and c.tests_steps]


def step_converged(contributions: Sequence[Contribution], state: ContributionState, direction: np.ndarray) -> bool:
    """Collective: whether every :class:`StepTested` one of ``contributions`` lets the solve end
    with the step ``direction`` ``(blocks, 3)`` from ``state`` (False: none tests steps)."""
    tested = step_testers(contributions)
    blocks = np.asarray(direction, dtype=float).reshape(-1, 3)
    return bool(tested) and all([c.step_converged(state, blocks) for c in tested])


def moving_obstacles(contributions: Sequence[Contribution]) -> bool:
    """Whether one of ``contributions`` has obstacles that move during a time step."""
    return any(isinstance(c, SweptStepBounded) and c.moving for c in contributions)


def carried_by_obstacles(contributions: Sequence[Contribution], state: ContributionState,
                         since: float) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Collective: the blocks every moving obstacle of ``contributions`` reaches ``(blocks,)`` and
    their displacement ``(blocks, 3)`` (:meth:`SweptStepBounded.carried`; the last one's where two reach a block)."""
    displacement = np.zeros_like(np.asarray(state.positions, dtype=float).reshape(-1, 3))
    reached = np.zeros(len(displacement), dtype=bool)
    for c in contributions:
        if isinstance(c, SweptStepBounded) and c.moving:
            mask, moved = c.carried(state, since)
            reached |= mask
            displacement[mask] = moved[mask]
    return reached, displacement


def place_obstacles_within_step(contributions: Sequence[Contribution], fraction: float) -> None:
    """Every moving obstacle of ``contributions`` where it is at ``fraction`` of the time step."""
    for c in contributions:
        if isinstance(c, SweptStepBounded) and c.moving:
            c.place_obstacles_within_step(fraction)


class ContributionSteps:
    """A problem's step bounds and moving obstacles, from its ``contributions`` (a mixin: the
    problem has ``contributions`` and ``contribution_state()``, its open blocks' state)."""

    contributions: Sequence[Contribution]
    #: the solver's own test on Newton's step (``solver.velocity_tolerance``), or None
    step_velocity_test: StepVelocityTest | None = None

    def contribution_state(self) -> ContributionState: ...

    @property
    def has_step_bounds(self) -> bool:
        """Whether a contribution bounds the line search (:class:`StepBounded`: a barrier's collision-free step)."""
        return any(isinstance(c, StepBounded) for c in self.contributions)

    def max_open_step(self, direction: np.ndarray, swept_from: float | None = None) -> float:
        """Collective: the largest fraction of a direction on the open blocks ``(blocks, 3)`` that
        every step-bounded contribution admits from the current state; ``swept_from``: a guess
        within a time step, moving obstacles moving along (:func:`step_bound`)."""
        if not self.has_step_bounds:
            return 1.0
        return step_bound(self.contributions, self.contribution_state(), direction, swept_from)

    @property
    def has_step_tests(self) -> bool:
        """Whether Newton's step is tested: by the solver's own test or by a contribution
        (:class:`StepTested`)."""
        return self.step_velocity_test is not None or bool(step_testers(self.contributions))

    def open_step_converged(self, direction: np.ndarray) -> bool:
        """Collective: whether the solver's step test and the step-testing contributions all let the
        solve end with a step on the open blocks ``(blocks, 3)`` from the current state
        (:func:`step_converged`)."""
        if not self.has_step_tests:
            return False
        if self.step_velocity_test is not None and not self.step_velocity_test.passes(direction):
            return False
        return not step_testers(self.contributions) or step_converged(self.contributions, self.contribution_state(),
                                                                      direction)  # fmt: skip

    @property
    def moves_obstacles(self) -> bool:
        """Whether a contribution's obstacles move during a time step (translating colliders)."""
        return moving_obstacles(self.contributions)

    def place_obstacles_within_step(self, fraction: float) -> None:
        """Moving obstacles where they are at ``fraction`` of the time step."""
        place_obstacles_within_step(self.contributions, fraction)

    def carried_by_obstacles(self, since: float) -> tuple[np.ndarray, np.ndarray]:
        """Collective: the open blocks moving obstacles reach from the fraction ``since`` of the time
        step to its end ``(blocks,)`` and the displacement ``(blocks, 3)`` that carries them along."""
        return carried_by_obstacles(self.contributions, self.contribution_state(), since)

    def adapt_to_iterate(self) -> bool:
        """Collective: the contributions adapt at the current state (:class:`IterationAdapted`);
        returns whether some energy changed."""
        return adapt_to_iterate(self.contributions, self.contribution_state())

    def adapted_parameters(self) -> dict[str, float]:
        """The contributions' adapted parameters, for a checkpoint."""
        return adapted_parameters(self.contributions)

    def restore_adapted(self, parameters: dict[str, float]) -> None:
        """Take the contributions' adapted parameters from a checkpoint."""
        restore_adapted(self.contributions, parameters)


@runtime_checkable
class GrowingPattern(Contribution, Protocol):
    """A contribution whose Hessian may reach beyond its fixed pattern (a barrier between parts of
    a mesh that share no triangle: self-contact, contact between bodies)."""

    def hessian_beyond_pattern(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The blocks of the last :meth:`hessian` call outside :meth:`hessian_pattern`: global open
        block ``(rows, columns)`` ``(k,)`` and values ``(k, 3, 3)``; with those of the pattern a
        positive semi-definite whole."""
        ...


@runtime_checkable
class StepLagged(Contribution, Protocol):
    """A contribution that takes quantities from the state at the start of each time step (lagged
    friction: the contacts, their normal forces and tangent bases of the step's start)."""

    def begin_step(self, state: ContributionState, time: float, dt: float) -> None:
        """Collective: the state at the start ``time`` [s] of a time step of ``dt`` [s] (before the
        first guess)."""
        ...


def begin_lagged_step(contributions: Sequence[Contribution], state: ContributionState, time: float,
                      dt: float) -> None:  # fmt: skip
    """Collective: hand the step's start ``state`` and ``time`` to every :class:`StepLagged` contribution."""
    for contribution in contributions:
        if isinstance(contribution, StepLagged):
            contribution.begin_step(state, time, dt)


@runtime_checkable
class IterationAdapted(Contribution, Protocol):
    """A contribution that adapts a parameter of its energy between Newton iterations (IPC's
    barrier stiffness, which grows while contacts keep closing in)."""

    def adapt(self, state: ContributionState) -> bool:
        """Collective: adapt at the Newton iterate ``state`` (the line search's accepted state, before
        the residual there is assembled); returns whether the energy changed, so that energies
        evaluated before no longer hold."""
        ...

    def parameters(self) -> dict[str, float]:
        """The adapted parameters by name, for a checkpoint (names unique among contributions)."""
        ...

    def restore(self, parameters: dict[str, float]) -> None:
        """Take this contribution's parameters from a checkpoint's (names it does not know: ignored)."""
        ...


def adapt_to_iterate(contributions: Sequence[Contribution], state: ContributionState) -> bool:
    """Collective: let every :class:`IterationAdapted` one of ``contributions`` adapt at ``state``;
    returns whether some energy changed."""
    changed = [c.adapt(state) for c in contributions if isinstance(c, IterationAdapted)]
    return any(changed)


def adapted_parameters(contributions: Sequence[Contribution]) -> dict[str, float]:
    """The :class:`IterationAdapted` ones' parameters, for a checkpoint."""
    return {k: v for c in contributions if isinstance(c, IterationAdapted) for k, v in c.parameters().items()}


def restore_adapted(contributions: Sequence[Contribution], parameters: dict[str, float]) -> None:
    """Hand a checkpoint's adapted ``parameters`` to every :class:`IterationAdapted` contribution."""
    for contribution in contributions:
        if isinstance(contribution, IterationAdapted):
            contribution.restore(parameters)


def diagonal_compensation(rows: np.ndarray, columns: np.ndarray,
                          values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Where a matrix's pattern cannot take blocks ``(rows, columns, values (k, 3, 3))`` of a
    symmetric set (each block's transpose among them): diagonal blocks ``(rows, rows, D)`` to add
    instead, ``D`` the absolute sums of each block's rows. Replacing the blocks so changes the
    matrix by a diagonally dominant one, so a positive semi-definite matrix stays one: its steps
    still go downhill, each side of a dropped coupling stepping as if the other held still."""
    values = np.asarray(values, dtype=float).reshape(-1, 3, 3)
    diagonal = np.zeros_like(values)
    for r in range(3):
        diagonal[:, r, r] = np.abs(values[:, r, :]).sum(axis=1)
    return np.asarray(rows), np.asarray(rows), diagonal


def _no_pattern() -> tuple[np.ndarray, np.ndarray]:
    return np.zeros(0, np.int64), np.zeros(0, np.int64)


def no_blocks() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """No Hessian blocks: empty ``(rows, columns, values (0, 3, 3))``, as
    :meth:`GrowingPattern.hessian_beyond_pattern` gives them."""
    return (*_no_pattern(), np.zeros((0, 3, 3)))


class PointLoads:
    """Dead point forces ``f`` scaled by the load factor ``lambda``: energy ``-lambda f.x``.

    Args:
        read: returns the load vector on this rank's open blocks, ``(blocks, 3)``: every point
            force on the rank that owns its patch (ghost entries included, not yet summed to owners).
        version: returns a number that changes whenever the load vector must be read again.
    """

    name = "point loads"

    def __init__(self, read: Callable[[], np.ndarray], version: Callable[[], int]):
        self._read, self._version = read, version
        self._seen = -1
        self._forces = np.zeros((0, 3))
        self._any = False  # whether this rank holds a nonzero force

    @property
    def forces(self) -> np.ndarray:
        """The current load vector ``(blocks, 3)`` (read again after a change of the loads)."""
        if self._seen != self._version():
            self._forces = np.asarray(self._read(), dtype=float).reshape(-1, 3)
            self._any = bool(np.any(self._forces))
            self._seen = self._version()
        return self._forces

    def hessian_pattern(self) -> tuple[np.ndarray, np.ndarray]:
        return _no_pattern()

    def energy(self, state: ContributionState) -> float:
        forces = self.forces
        return -state.load_factor * float(np.dot(forces.ravel(), state.positions.ravel())) if self._any else 0.0

    def add_gradient(self, state: ContributionState, gradient: np.ndarray) -> None:
        forces = self.forces
        if self._any:
            gradient -= state.load_factor * forces

    def hessian(self, state: ContributionState) -> np.ndarray:
        return np.zeros((0, 3, 3))


class PointConstraints:
    """Material points held at targets (chosen components) by an augmented Lagrangian: energy
    ``sum_k lambda_k.c_k + rho/2 |c_k|^2`` with ``c_k = (x(xi_k) - target_k) * mask_k``; the
    multipliers ``lambda`` are updated between solves (:meth:`update_multipliers`).

    Args:
        bases: each point's :data:`PointBasis`.
        global_blocks: global open block index of each local block, ``(blocks,)``.
        masks: ``(points, 3)``, 1 for the held components.
        penalty: ``rho`` [N/m].
        tolerance: the largest violation [m] a converged constraint may keep.
        rank: this process's rank (rank 0 adds the energy, which every rank computes alike).
    """

    name = "point constraints"

    def __init__(self, bases: Sequence[PointBasis], global_blocks: np.ndarray, masks: np.ndarray,
                 penalty: float, tolerance: float, rank: int):  # fmt: skip
        self.bases = list(bases)
        self.global_blocks = np.asarray(global_blocks, dtype=np.int64)
        self.mask = np.asarray(masks, dtype=float).reshape(-1, 3)
        self.multipliers = np.zeros_like(self.mask)
        self.targets = np.zeros_like(self.mask)
        self.penalty = float(penalty)
        self.tolerance = float(tolerance)
        self.rank = rank

    def violation(self, state: ContributionState) -> np.ndarray:
        """Collective: ``c``, shape ``(points, 3)`` (free components 0)."""
        return (state.point_positions(self.bases) - self.targets) * self.mask

    def update_multipliers(self, state: ContributionState) -> bool:
        """Collective, after a converged solve: whether every held point is within tolerance of its
        target; if not, the multipliers take the step ``rho c`` for the next solve."""
        violation = self.violation(state)
        if np.abs(violation).max(initial=0.0) <= self.tolerance:
            return True
        self.multipliers += self.penalty * violation
        return False

    def hessian_pattern(self) -> tuple[np.ndarray, np.ndarray]:
        rows, columns = [], []
        for blocks, _ in self.bases:
            held = self.global_blocks[np.asarray(blocks, dtype=np.int64)]
            rows.append(np.repeat(held, len(held)))
            columns.append(np.tile(held, len(held)))
        if not rows:
            return _no_pattern()
        return np.concatenate(rows), np.concatenate(columns)

    def energy(self, state: ContributionState) -> float:
        if not self.bases:  # the same on every rank: no collective skipped
            return 0.0
        c = self.violation(state)
        energy = float(np.sum(self.multipliers * c) + 0.5 * self.penalty * np.sum(c * c))
        return energy if self.rank == 0 else 0.0

    def add_gradient(self, state: ContributionState, gradient: np.ndarray) -> None:
        if not self.bases:
            return
        force = (self.multipliers + self.penalty * self.violation(state)) * self.mask
        for (blocks, values), f in zip(self.bases, force, strict=True):
            gradient[blocks] += values[:, None] * f

    def hessian(self, state: ContributionState) -> np.ndarray:
        """``rho phi_i phi_j`` on every component, held or not: one 3x3 block pattern for every mask,
        exact for the held components and a positive (stiffer than exact) term for the free ones."""
        blocks = [self.penalty * np.outer(values, values).ravel() for _, values in self.bases]
        if not blocks:
            return np.zeros((0, 3, 3))
        return np.concatenate(blocks)[:, None, None] * np.eye(3)

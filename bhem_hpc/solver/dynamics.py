"""Implicit Euler time stepping (paper eq. 30) with recovery; no PETSc here.

Each step minimizes the incremental potential built by :class:`bhem_hpc.model.shell.ShellModel` with
``dynamics`` set: ``x_predicted = x_n + dt v_n``, ``x_previous = x_n``, solve, then
``v_{n+1} = (x_{n+1} - x_n) / dt`` and the contact response's correction (the stepper's
:class:`~bhem_hpc.solver.state.ShellState` writes them all). A step whose solve fails (after the solver's regularized
retries) is retried as two half steps, recursively, at most ``max_halvings`` deep; a step that
still fails stops the run with an error naming the step, the time and the solver's reasons.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from bhem_hpc.errors import UserError
from bhem_hpc.model.bcs import NodalConstraint
from bhem_hpc.model.shell import ShellModel
from bhem_hpc.solids.model import SolidModel, SolidState
from bhem_hpc.solver.model_group import ModelGroup
from bhem_hpc.solver.newton import LINEAR_COUNTERS, RECOVERY_COUNTERS, ShellSolver
from bhem_hpc.solver.petsc import SolverError, SolverSetupError
from bhem_hpc.solver.state import ShellState, StackedState, StepStart

if TYPE_CHECKING:  # a scene without contact never imports the collision code
    from bhem_hpc.contact.response import ContactHandler

log = logging.getLogger(__name__)
#: The part of the collision-free bound of the inertial prediction a first guess goes (a barrier's
#: energy grows without bound at the bound itself).
FIRST_GUESS_FRACTION = 0.9
#: The most solves with moving obstacles part of the way through a time step before its own
#: (:meth:`TimeStepper._push_by_moving_obstacles`).
MAX_PUSH_STAGES = 6


class StepFailure(UserError, RuntimeError):
    """A time step could not be completed; the run must stop."""


@dataclass
class StepRecord:
    """Everything one time step did, measured over that step alone (a row of a run's summary).

    Times are seconds of this rank; solver figures cover every attempt and substep of the step.
    """

    step: int
    time: float
    newton_iterations: int = 0
    substeps: int = 1
    dt_halvings: int = 0
    regularized_retries: int = 0
    regularized_iterations: int = 0
    projected_iterations: int = 0  # Newton steps recomputed with the projected Hessian (adaptive)
    trust_region_solves: int = 0  # solves recovered by the trust-region Newton fallback
    trust_region_failures: int = 0  # energy trust-region solves (hessian = "trust_region") that failed
    negative_pivots: int = -1  # of the last factorization (-1: unknown, not LDL^T)
    refactorizations: int = 0  # Jacobians assembled and factored
    chord_iterations: int = 0  # Newton iterations on a kept factorization
    refactor_retries: int = 0  # failed solves repeated with a fresh factorization
    krylov_iterations: int = 0  # of the iterative linear solver (0 with MUMPS' preonly)
    collider_pushes: int = 0  # solves with moving colliders part of the way (TimeStepper._push_by_moving_obstacles)
    start_guesses: int = 0  # solves started from the step's start rather than the inertial prediction
    linear_solves: int = 0
    wall_s: float = 0.0
    assembly_s: float = 0.0
    factorization_s: float = 0.0
    linear_solve_s: float = 0.0
    contacts: int = 0
    contact_rounds: int = 0
    earliest_toi: float = float("inf")
    collision_s: float = 0.0
    detection_s: float = 0.0
    projections: int = 0

    @property
    def recoveries(self) -> int:
        """Regularized retries, trust-region solves and failures, and dt halvings."""
        return self.regularized_retries + self.trust_region_solves + self.trust_region_failures + self.dt_halvings


def body_state(model: ShellModel | SolidModel) -> ShellState | SolidState:
    """The writer of a body's position and velocity: a shell's or a solid's."""
    return SolidState(model) if isinstance(model, SolidModel) else ShellState(model)


def _constraint_key(c: NodalConstraint) -> tuple:
    return tuple(c.nodes.ravel()) + c.kinds + c.components


def _check_motion(models: Sequence[ShellModel], motion: PrescribedMotion) -> None:
    """A prescribed motion moves one of its body's constraints (same nodes, kinds and components)."""
    if not 0 <= motion.body < len(models):
        raise ValueError(f"a prescribed motion of body {motion.body}: there are {len(models)} bodies")
    if _constraint_key(motion.constraint) not in {_constraint_key(c) for c in models[motion.body].constraints}:
        raise ValueError("a prescribed motion must be one of the model's constraints (same nodes/kinds)")


@dataclass
class TimeStepper:
    """Advance a dynamic :class:`ShellModel` (or several bodies' models, in one Newton solve per
    step) with a :class:`ShellSolver`.

    Args:
        model: a model built with ``dynamics``, or several (one dt), as the solver was made with.
        solver: its solver.
        motions: time-dependent nodal constraints: each maps time ``t`` to the parametric values
            of its ``(nodes, kinds, components)`` of body ``motion.body`` (see :class:`PrescribedMotion`).
        max_halvings: bound on recursive dt halvings of one step.
        contact: contact detection and response run after every solve (None: no contact effects,
            nothing is detected and nothing is paid for); with several bodies, the handler of them
            all (:meth:`ContactHandler.between_bodies`: contacts with colliders, within a body and
            between bodies resolved together).
        state: the model's state (default: a :class:`ShellState` of the model, a
            :class:`StackedState` of several); the stepper writes position and velocity through it only.
    """

    model: ShellModel | SolidModel | Sequence[ShellModel | SolidModel]
    solver: ShellSolver
    motions: Sequence[PrescribedMotion] = ()
    max_halvings: int = 4
    contact: ContactHandler | None = None
    state: ShellState | SolidState | StackedState | None = None
    time: float = 0.0
    step: int = 0
    history: list[StepRecord] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.models = ModelGroup(self.model).models
        if any(m.dynamics is None for m in self.models):
            raise ValueError("TimeStepper needs models built with dynamics (Dynamics, or a solid's SolidDynamics)")
        handled = 0 if self.contact is None else len(self.contact.entries.surfaces)
        if self.contact is not None and handled != len(self.models):
            raise ValueError(f"the contact handler covers {handled} bodies; the stepper has {len(self.models)}")
        self.dt = self.models[0].dynamics.time_step
        self._clock = (self.time, self.step, self.dt)  # (time, step, dt) after the last advance
        self._origin = (self.time, self.step)  # where the clock was last set
        if self.state is None:  # the one writer of x, v and the step's previous state
            states = [body_state(m) for m in self.models]
            self.state = states[0] if len(states) == 1 else StackedState(states)
        for motion in self.motions:
            _check_motion(self.models, motion)

    def _tick(self) -> None:
        """Advance step and time. The time is ``t0 + (step - step0) dt`` from the last time the
        clock was set (start, restart, a change of dt), rounded to 15 significant digits: exact
        decimal step times (0.3, not 0.30000000000000004) that do not drift over long runs."""
        if (self.time, self.step, self.dt) != self._clock:  # set from outside (restart, new dt)
            self._origin = (self.time, self.step)
        self.step += 1
        origin_time, origin_step = self._origin
        self.time = float(f"{origin_time + (self.step - origin_step) * self.dt:.15g}")
        self._clock = (self.time, self.step, self.dt)

    def bc_values_at(self, t: float) -> np.ndarray:
        """Reference-DOF values of all constrained DOFs at time ``t``, body after body."""
        values = []
        for body, model in enumerate(self.models):
            moved = [m.at(t) for m in self.motions if m.body == body]
            values.append(model.prescribed_values(moved) if moved else model.constrained_target)
        return values[0] if len(values) == 1 else np.concatenate(values)

    def _bound_first_guess(self, start: StepStart, bc_values: np.ndarray, report: StepRecord) -> None:
        """Where a contribution bounds steps (a barrier), the first guess is the inertial prediction
        or the step's start, whichever has the lower incremental potential, each only as far as the
        straight path from the step's start allows: ``x_n + a (x_target - x_n)`` with ``a``
        :data:`FIRST_GUESS_FRACTION` of the bound (the start is admissible, and so is every Newton
        iterate after it). What translating obstacles reach moves with them to their places at the
        step's end in either; where they would meet the shell on the prediction's path (a collider
        pushing the shell), :meth:`_push_by_moving_obstacles` finds the guess from the prediction
        (its solves counted in ``report``).

        Why the start is a candidate: where a stiff shell snaps, its velocity is that of a jump
        between equilibria, not of a motion that goes on, and inertia, ``M / dt^2``, is far weaker
        than its stiffness; the prediction then overshoots into a state of much higher energy. The
        crushed can by IPC, steps 36-40: the prediction's potential 36-51 J against the start's 1.6 J
        at the snap, and 11, 13, 35, 99, 22 Newton iterations with 4 recoveries from the prediction
        against 10, 13, 28, 12, 8 without any from the lower of the two (measured). Where inertia
        carries a body (free flight, a fall) the prediction has the lower potential and stays."""
        problem = self.solver.problem
        if not problem.has_step_bounds:
            return
        predicted = np.array(self.state.position)
        self.state.roll_back(start)
        moving = self.solver.bodies.comm.allreduce(int(not np.array_equal(predicted, start.position))) > 0
        targets = [predicted, np.array(start.position)] if moving else [predicted]
        if problem.moves_obstacles:  # what a collider reaches moves with it, not as inertia predicts
            reached, displacement = problem.carried_by_obstacles(0.0)
            for target in targets:
                blocks = target.reshape(-1, 3)  # a view
                blocks[reached] = start.position.reshape(-1, 3)[reached] + displacement[reached]
        bounds = [problem.max_open_step(target - start.position, swept_from=0.0) for target in targets]
        if bounds[0] < 1.0 and problem.moves_obstacles:
            self._push_by_moving_obstacles(start.position, predicted, bounds[0], bc_values, report)
            return
        # a path that moving obstacles would cut is no candidate (its guess would leave them behind)
        kept = [i for i, bound in enumerate(bounds) if bound >= 1.0 or not problem.moves_obstacles]
        guesses = [targets[i] if bounds[i] >= 1.0 else
                   start.position + FIRST_GUESS_FRACTION * bounds[i] * (targets[i] - start.position) for i in kept]
        chosen = kept[self._lowest_potential(guesses)]
        report.start_guesses += int(chosen == 1)  # targets[1] is the step's start
        self.state.set_guess(guesses[kept.index(chosen)])

    def _lowest_potential(self, guesses: Sequence[np.ndarray]) -> int:
        """Collective: the index of the open positions among ``guesses`` where the incremental
        potential is lowest (the first of equals; the state is left at the last one)."""
        if len(guesses) == 1:
            return 0
        energies = []
        for guess in guesses:
            self.state.set_guess(guess)
            energies.append(self.solver.problem.potential_energy())
        return int(np.argmin(energies))

    def _push_by_moving_obstacles(self, start: np.ndarray, target: np.ndarray, bound: float,
                                  bc_values: np.ndarray, report: StepRecord) -> None:  # fmt: skip
        """Obstacles that would meet the shell on the straight path to the guess ``target`` (at
        ``bound`` of it) move as far as :data:`FIRST_GUESS_FRACTION` of that within the step; the
        step is solved with them there, and that state, with what the obstacles reach carried on
        with them to the step's end, is the next guess. Repeated at most :data:`MAX_PUSH_STAGES`
        times until the obstacles reach their places at the step's end on the guess's path (a
        :class:`~bhem_hpc.solver.petsc.SolverError` where they do not: dt is halved); the solves
        and their Newton iterations are counted in ``report``. ``start``, ``target``: open
        positions at the step's start and the guess."""
        problem, reached, position = self.solver.problem, 0.0, start
        for _ in range(MAX_PUSH_STAGES):
            share = FIRST_GUESS_FRACTION * bound
            reached += share * (1.0 - reached)
            problem.place_obstacles_within_step(reached)
            self.state.set_guess(position + share * (target - position))
            report.newton_iterations += self.solver.solve_step(bc_values)
            report.collider_pushes += 1
            position = np.array(self.state.position)
            # what the obstacles reach goes on with them; the rest stays
            target = position + problem.carried_by_obstacles(reached)[1].reshape(position.shape)
            log.info("step %d: moving colliders pushed the shell to %.3g of the step", report.step, reached)
            bound = problem.max_open_step(target - position, swept_from=reached)
            if bound >= 1.0:
                problem.place_obstacles_within_step(1.0)
                self.state.set_guess(target)
                return
        problem.place_obstacles_within_step(1.0)
        raise SolverError(f"moving colliders reached {reached:.3g} of the step in {MAX_PUSH_STAGES} pushes of the "
                          "shell")  # fmt: skip

    def advance(self) -> StepRecord:
        """One time step of the model's dt (possibly as recovered substeps)."""
        start = time.perf_counter()
        report = StepRecord(step=self.step + 1, time=self.time + self.dt)
        before = self.solver.counters()
        try:
            self._advance(self.time, self.dt, 0, report)
        finally:
            for model in self.models:
                model.time_step.value = self.dt
        self._tick()
        report.time = self.time
        after = self.solver.counters()
        counted = ("regularized_retries", "regularized_iterations", *RECOVERY_COUNTERS, "assembly_s",
                   "factorization_s", "linear_solve_s", *LINEAR_COUNTERS)  # fmt: skip
        for name in counted:
            setattr(report, name, after[name] - before[name])
        report.negative_pivots = after["negative_pivots"]
        report.wall_s = time.perf_counter() - start
        self.history.append(report)
        return report

    def _advance(self, t_start: float, dt: float, depth: int, report: StepRecord) -> None:
        self.solver.problem.begin_step(t_start, dt)  # at the accepted state x_n, before the first guess
        start = self.state.begin_step(dt)
        try:
            self.solver.problem.set_point_targets(t_start + dt)
            bc_values = self.bc_values_at(t_start + dt)
            self._bound_first_guess(start, bc_values, report)
            report.newton_iterations += self.solver.solve_step(bc_values)
        except SolverSetupError:
            self.state.roll_back(start)
            raise
        except SolverError as exc:
            self.state.roll_back(start)
            if depth >= self.max_halvings:
                raise StepFailure(
                    f"time step {report.step} (t = {report.time:.6g} s) failed after {depth} halvings of dt "
                    f"(dt = {dt:.3e} s): {exc}"
                ) from exc
            log.info("step %d: %s; halving dt to %.3e", report.step, exc, dt / 2)
            report.dt_halvings += 1
            report.substeps += 1
            self._advance(t_start, dt / 2, depth + 1, report)
            self._advance(t_start + dt / 2, dt / 2, depth + 1, report)
            return
        if self.contact is None:
            self.state.finish_step(start, dt)
            return
        contact, correction = self.contact.respond(start.position, self.state.position, t_start, dt)
        self.state.finish_step(start, dt, correction)
        report.contacts = max(report.contacts, contact.contacts)
        report.contact_rounds += contact.rounds
        report.earliest_toi = min(report.earliest_toi, contact.earliest_toi)
        report.collision_s += contact.detection_s + contact.response_s
        report.detection_s += contact.detection_s
        report.projections += contact.projections


@dataclass(frozen=True)
class PrescribedMotion:
    """Time-dependent values of a nodal constraint.

    Attributes:
        constraint: the constrained nodes, kinds and components (also passed to the model).
        values: callable ``t -> array`` broadcastable to ``(nodes, kinds, components)``, in
            parametric units.
        body: the index of the body whose constraint it moves (among a stepper's several).
    """

    constraint: NodalConstraint
    values: Callable[[float], np.ndarray]
    body: int = 0

    def at(self, t: float) -> NodalConstraint:
        c = self.constraint
        return NodalConstraint(c.nodes, c.kinds, c.components, np.asarray(self.values(t), dtype=float))

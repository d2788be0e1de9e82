"""The state of a shell model that a time stepper advances (no PETSc here).

:class:`ShellState` is the one writer of the model's position ``x`` (the Newton unknown), velocity
``v`` and the step's previous and predicted positions (the incremental potential's data): a step
begins (``x_prev = x_n``, ``x_pred = x_n + dt v_n``, the guess ``x = x_pred``), is rolled back, or
finishes (``v = (x - x_n) / dt``, then a contact correction added). Output and checkpoints read it.
Arrays are in the model's open layout, this rank's entries with ghosts.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bhem_hpc.model.shell import ShellModel


@dataclass(frozen=True)
class StepStart:
    """The state a step starts from (open layout): ``position`` x_n and ``velocity`` v_n."""

    position: np.ndarray
    velocity: np.ndarray


@dataclass(frozen=True)
class StateCorrection:
    """What a contact response changes at the end of a step (open layout): the velocity by
    ``delta_velocity`` and the position by ``delta_position`` (``dt dv`` plus push-outs)."""

    delta_velocity: np.ndarray
    delta_position: np.ndarray


class ShellState:
    """Position, velocity and the step's previous state of a :class:`ShellModel`.

    Args:
        model: the model whose Functions hold the state (static models have no velocity).
    """

    def __init__(self, model: ShellModel):
        self.model = model

    @property
    def position(self) -> np.ndarray:
        """x (open layout, read-only view)."""
        view = self.model.x.x.array.view()
        view.flags.writeable = False
        return view

    @property
    def velocity(self) -> np.ndarray:
        """v (open layout, read-only view; zeros for a static model)."""
        if self.model.dynamics is None:
            return np.zeros_like(self.model.x.x.array)
        view = self.model.velocity.x.array.view()
        view.flags.writeable = False
        return view

    def begin_step(self, dt: float) -> StepStart:
        """Set the step's data from the current state and the guess ``x = x_n + dt v_n``; returns x_n, v_n."""
        model = self.model
        start = StepStart(model.x.x.array.copy(), model.velocity.x.array.copy())
        model.time_step.value = dt
        model.x_previous.x.array[:] = start.position
        model.x_predicted.x.array[:] = start.position + dt * start.velocity
        model.x.x.array[:] = model.x_predicted.x.array  # the inertial prediction is the first guess
        return start

    def roll_back(self, start: StepStart) -> None:
        """Return the position to the step's start (a failed solve)."""
        self.model.x.x.array[:] = start.position

    def set_guess(self, position: np.ndarray) -> None:
        """Set the position (open layout) the step's solve starts from."""
        self.model.x.x.array[:] = position

    def finish_step(self, start: StepStart, dt: float, correction: StateCorrection | None = None) -> None:
        """``v = (x - x_n) / dt`` for the solved position, then the correction added to v and x."""
        model = self.model
        model.velocity.x.array[:] = (model.x.x.array - start.position) / dt
        if correction is not None:  # added after, so that a step without contact stays bit-exact
            model.velocity.x.array[:] += correction.delta_velocity
            model.x.x.array[:] = model.x.x.array + correction.delta_position

    def set_raw(self, position: np.ndarray, velocity: np.ndarray | None = None) -> None:
        """Set x (and v, dynamic models) from raw DOF arrays as checkpoints hold them (bit-exact)."""
        disc = self.model.discretization
        self.model.x.x.array[:] = disc.scatter_raw_dofs(position)
        if velocity is not None:
            self.model.velocity.x.array[:] = disc.scatter_raw_dofs(velocity)

    def raw_position(self) -> np.ndarray:
        """x as raw DOFs, gathered (collective)."""
        return self.model.discretization.gather_raw_dofs(self.model.x.x.array)

    def raw_velocity(self) -> np.ndarray:
        """v as raw DOFs, gathered (collective; zeros for a static model)."""
        return self.model.discretization.gather_raw_dofs(np.asarray(self.velocity))


class StackedState:
    """The states of several bodies stepped together, with the interface of :class:`ShellState`:
    arrays are the bodies' open arrays side by side (body after body, each this rank's entries with
    ghosts), as :class:`~bhem_hpc.bodies.petsc.StackedProblem` lays out its contributions' rows.

    Args:
        states: one state per body (a :class:`ShellState`, a solid's
            :class:`~bhem_hpc.solids.model.SolidState`), in the stacked order.
    """

    def __init__(self, states: list):
        self.states = list(states)
        #: where each body's entries start in the side-by-side arrays, ``(bodies + 1,)``
        self.offsets = np.cumsum([0] + [s.position.size for s in self.states])

    def _split(self, array: np.ndarray) -> list[np.ndarray]:
        return [array[a:b] for a, b in zip(self.offsets[:-1], self.offsets[1:], strict=True)]

    @property
    def position(self) -> np.ndarray:
        """x of every body (read-only copy)."""
        view = np.concatenate([s.position for s in self.states])
        view.flags.writeable = False
        return view

    @property
    def velocity(self) -> np.ndarray:
        """v of every body (read-only copy)."""
        view = np.concatenate([s.velocity for s in self.states])
        view.flags.writeable = False
        return view

    def begin_step(self, dt: float) -> StepStart:
        starts = [s.begin_step(dt) for s in self.states]
        return StepStart(np.concatenate([s.position for s in starts]), np.concatenate([s.velocity for s in starts]))

    def _body_starts(self, start: StepStart) -> list[StepStart]:
        return [StepStart(p, v) for p, v in zip(self._split(start.position), self._split(start.velocity), strict=True)]

    def roll_back(self, start: StepStart) -> None:
        for state, body_start in zip(self.states, self._body_starts(start), strict=True):
            state.roll_back(body_start)

    def set_guess(self, position: np.ndarray) -> None:
        for state, body_position in zip(self.states, self._split(position), strict=True):
            state.set_guess(body_position)

    def finish_step(self, start: StepStart, dt: float, correction: StateCorrection | None = None) -> None:
        corrections = [None] * len(self.states) if correction is None else [
            StateCorrection(dv, dx) for dv, dx in zip(self._split(correction.delta_velocity),
                                                      self._split(correction.delta_position), strict=True)]  # fmt: skip
        for state, body_start, body_correction in zip(self.states, self._body_starts(start), corrections, strict=True):
            state.finish_step(body_start, dt, body_correction)

"""The shell models one Newton solve advances together: one body, or several bodies in one global
state (no PETSc here).

:class:`ModelGroup` is what the Newton driver asks of its bodies besides their problem: whether
they are time-stepped and with which dt, whether their Jacobians are symmetric and they have a
potential, their sizes, the load factor, and the values of their constrained DOFs, body after
body (the order of the stacked problem's constraint rows,
:class:`~bhem_hpc.bodies.petsc.StackedProblem`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from mpi4py import MPI

from bhem_hpc.model.shell import ShellModel


class ModelGroup:
    """One model, or several solved as one problem.

    Args:
        models: a :class:`ShellModel` or a sequence of them, in the stacked order, on one
            communicator, all static or all time-stepped with one dt.

    Raises:
        ValueError: no model, models on different communicators, static and dynamic models mixed,
            different time steps, or several models of which one has no potential (a follower load:
            the energy line search of the bodies needs every body's potential).
    """

    def __init__(self, models: ShellModel | Sequence[ShellModel]):
        self.models = [models] if isinstance(models, ShellModel) else list(models)
        if not self.models:
            raise ValueError("a solve needs at least one shell model")
        first = self.models[0]
        if any(MPI.Comm.Compare(m.comm, first.comm) not in (MPI.IDENT, MPI.CONGRUENT) for m in self.models[1:]):
            raise ValueError("the bodies of one solve must share one communicator")
        kinds = {m.dynamics is None for m in self.models}
        if len(kinds) > 1:
            raise ValueError("the bodies of one solve must all be static or all be time-stepped")
        steps = {m.dynamics.time_step for m in self.models if m.dynamics is not None}
        if len(steps) > 1:
            raise ValueError(f"the bodies of one solve must share one time step, got {sorted(steps)}")
        if len(self.models) > 1 and any(m.potential_form is None for m in self.models):
            raise ValueError("several bodies are solved on their total potential: a follower load (effects.pressure) "
                             "is not supported on a body of several")  # fmt: skip

    def __len__(self) -> int:
        return len(self.models)

    @property
    def comm(self):
        return self.models[0].comm

    @property
    def dynamic(self) -> bool:
        return self.models[0].dynamics is not None

    @property
    def symmetric(self) -> bool:
        return all(m.symmetric for m in self.models)

    @property
    def has_potential(self) -> bool:
        return all(m.potential_form is not None for m in self.models)

    @property
    def time_step(self) -> float | None:
        """The current dt (halved steps change it), None for static models."""
        return float(self.models[0].time_step.value) if self.dynamic else None

    @property
    def closed_sizes(self) -> tuple[int, int]:
        """Closed DOFs (3 per block) this rank owns and in all, over every body."""
        discretizations = [m.discretization for m in self.models]
        return 3 * sum(d.num_owned_closed for d in discretizations), 3 * sum(d.num_closed for d in discretizations)

    @property
    def closed_is_open(self) -> bool:
        """One body without seams or ties (its closed DOFs are its open ones)."""
        return len(self.models) == 1 and self.models[0].discretization.closed_is_open

    def set_load_factor(self, value: float) -> None:
        for model in self.models:
            model.load_factor.value = value

    @property
    def constrained_target(self) -> np.ndarray:
        """Targets of the constrained DOFs, body after body, shape ``(constrained DOFs on this rank,)``."""
        return np.concatenate([m.constrained_target for m in self.models])

    @property
    def constrained_initial(self) -> np.ndarray:
        """Initial values of the constrained DOFs, body after body."""
        return np.concatenate([m.constrained_initial for m in self.models])

    def stiffest(self) -> ShellModel:
        """The model of the largest membrane force scale ``Y h`` times its largest patch size: its
        solver defaults (the residual's round-off floor) hold for every body."""

        def scale(model: ShellModel) -> float:
            grid = model.rest_surface.grid
            return model.material.young * model.material.thickness * max(grid.h1, grid.h2)

        return max(self.models, key=scale)

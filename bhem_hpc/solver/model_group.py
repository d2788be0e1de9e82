"""The bodies' models one Newton solve advances together: one body, or several bodies in one global
state (no PETSc here).

:class:`BodyModel` is what the driver asks of a body's model: a shell's
(:class:`~bhem_hpc.model.shell.ShellModel`) or an SEM solid's (:class:`~bhem_hpc.solids.model.SolidModel`).

:class:`ModelGroup` is what the Newton driver asks of its bodies besides their problem: whether
they are time-stepped and with which dt, whether their Jacobians are symmetric and they have a
potential, their sizes, the load factor, and the values of their constrained DOFs, body after
body (the order of the stacked problem's constraint rows,
:class:`~bhem_hpc.bodies.petsc.StackedProblem`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np
from mpi4py import MPI


@runtime_checkable
class BodyModel(Protocol):
    """A body's model as the Newton driver, its time stepper and its stacked problem see it.

    Attributes:
        comm: the communicator of the solve.
        dynamics: implicit Euler settings (with ``time_step`` [s]), None for statics.
        load_factor: a scalar the energy reads (``.value``), set by the driver; in dynamics
            ``time_step`` too.
        symmetric: whether the Jacobian is symmetric (conservative loads).
        constrained_target, constrained_initial: values of this rank's held DOFs.
    """

    comm: MPI.Comm
    dynamics: Any
    load_factor: Any
    symmetric: bool
    constrained_target: np.ndarray
    constrained_initial: np.ndarray

    @property
    def has_potential(self) -> bool: ...

    @property
    def closed_dofs(self) -> tuple[int, int]:
        """DOFs this rank owns and in all."""
        ...

    @property
    def closed_is_open(self) -> bool: ...

    @property
    def open_blocks(self) -> tuple[int, int]:
        """Blocks of 3 DOFs this rank owns and the others it holds (ghosts)."""
        ...

    @property
    def global_open_blocks(self) -> np.ndarray: ...

    @property
    def open_positions(self) -> np.ndarray:
        """``(open blocks, 3)`` the current position."""
        ...

    @property
    def force_scale(self) -> float:
        """The scale of the internal forces [N] (the residual's round-off floor)."""
        ...

    @property
    def linear_scales(self) -> tuple[float, float, float, float]:
        """Density, Young's modulus, Poisson's ratio and an element size [m]."""
        ...

    def point_basis(self, xi1: float, xi2: float) -> tuple[np.ndarray, np.ndarray]: ...

    def open_state(self) -> tuple[np.ndarray, np.ndarray | None]: ...

    def set_open_state(self, position: np.ndarray, previous: np.ndarray | None) -> None: ...

    def gather_raw(self, array: np.ndarray) -> np.ndarray: ...

    def scatter_raw(self, raw: np.ndarray) -> np.ndarray: ...


class ModelGroup:
    """One model, or several solved as one problem.

    Args:
        models: a :class:`BodyModel` or a sequence of them, in the stacked order, on one
            communicator, all static or all time-stepped with one dt.

    Raises:
        ValueError: no model, models on different communicators, static and dynamic models mixed,
            different time steps, or several models of which one has no potential (a follower load:
            the energy line search of the bodies needs every body's potential).
    """

    def __init__(self, models: BodyModel | Sequence[BodyModel]):
        self.models = [models] if isinstance(models, BodyModel) else list(models)
        if not self.models:
            raise ValueError("a solve needs at least one body's model")
        for model in self.models:
            if not isinstance(model, BodyModel):
                raise TypeError(f"{model!r} is not a body's model (bhem_hpc.solver.model_group.BodyModel)")
        first = self.models[0]
        if any(MPI.Comm.Compare(m.comm, first.comm) not in (MPI.IDENT, MPI.CONGRUENT) for m in self.models[1:]):
            raise ValueError("the bodies of one solve must share one communicator")
        kinds = {m.dynamics is None for m in self.models}
        if len(kinds) > 1:
            raise ValueError("the bodies of one solve must all be static or all be time-stepped")
        steps = {m.dynamics.time_step for m in self.models if m.dynamics is not None}
        if len(steps) > 1:
            raise ValueError(f"the bodies of one solve must share one time step, got {sorted(steps)}")
        if len(self.models) > 1 and not all(m.has_potential for m in self.models):
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
        return all(m.has_potential for m in self.models)

    @property
    def time_step(self) -> float | None:
        """The current dt (halved steps change it), None for static models."""
        return float(self.models[0].time_step.value) if self.dynamic else None

    @property
    def closed_sizes(self) -> tuple[int, int]:
        """Closed DOFs (3 per block) this rank owns and in all, over every body."""
        sizes = np.array([m.closed_dofs for m in self.models])
        return int(sizes[:, 0].sum()), int(sizes[:, 1].sum())

    @property
    def closed_is_open(self) -> bool:
        """One body without seams or ties (its closed DOFs are its open ones)."""
        return len(self.models) == 1 and self.models[0].closed_is_open

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

    def stiffest(self) -> BodyModel:
        """The model of the largest force scale (for a shell ``Y h`` times its largest patch size):
        its solver defaults (the residual's round-off floor) hold for every body."""
        return max(self.models, key=lambda model: model.force_scale)

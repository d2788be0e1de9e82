"""The solver's own stopping test on Newton's step (``solver.velocity_tolerance``): IPC's (Li et al.
2020, whose projected Newton the B-spline cloth paper follows): a time step's solve ends once its
Newton step moves no point by more than ``tolerance * dt``, i.e. once what is left to correct is a
velocity below the tolerance. ``"auto"`` is IPC's epsilon_d: 1e-2 of the rest surface's bounding-box
diagonal per second.

The step is measured on the open DOF blocks, the 3-vectors the shell's forms see: with B-splines
the surface's points at the Lagrange nodes (rational ones: the homogeneous blocks over ``W``), with
Hermite patches the nodes' positions and their derivatives scaled to the patches' lengths. No
PETSc here: the solver maps its step to these blocks.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # the communicator is passed in: contributions import this module without MPI
    from mpi4py import MPI

#: ``velocity_tolerance = "auto"``: this fraction of the rest bounding-box diagonal per second (IPC's
#: epsilon_d, Li et al. 2020, section 5)
AUTO_VELOCITY_FRACTION = 1e-2


def auto_velocity_tolerance(rest_diagonal: float) -> float:
    """IPC's epsilon_d [m/s] for bodies whose rest bounding box has the diagonal ``rest_diagonal`` [m]
    (``velocity_tolerance = "auto"``, the solver's test and the IPC barrier's alike)."""
    return AUTO_VELOCITY_FRACTION * rest_diagonal


@dataclass
class StepVelocityTest:
    """Whether a Newton step is small enough to end a time step's solve.

    Attributes:
        tolerance: the largest velocity [m/s] a step may leave to correct, > 0.
        comm: the communicator over which the blocks are spread.
        dt: the current time step [s] (set as each step, or half step, begins; 0: never passes).
    """

    tolerance: float
    comm: MPI.Comm
    dt: float = 0.0
    #: ``(open blocks,)`` what divides each block to give a point's motion (rational B-splines' ``W``), or None
    block_weights: np.ndarray | None = None

    def passes(self, blocks: np.ndarray) -> bool:
        """Collective: whether no block of the step ``(blocks, 3)`` (this rank's open blocks, ghosts
        included) moves by more than ``tolerance * dt`` (the same answer on every rank)."""
        moved = np.linalg.norm(np.asarray(blocks, dtype=float).reshape(-1, 3), axis=1)
        if self.block_weights is not None:
            moved = moved / self.block_weights
        largest = max(self.comm.allgather(float(moved.max()) if len(moved) else 0.0))
        return self.dt > 0 and largest <= self.tolerance * self.dt

"""The acceleration residual of a solid's time step (``solver.acceleration_tolerance``), as
:class:`~bhem_hpc.solver.acceleration.AccelerationResidual` gives a shell's: ``r^T M^-1 r`` with the
solid's consistent mass ``M`` (its held rows and columns the identity, their residual left out), so
that bodies of both kinds share one stopping test. numpy and SciPy only: a solid is small, its
residual gathered on every rank and ``M`` factored once on each."""

from __future__ import annotations

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from bhem_hpc.solids.model import SolidModel


class SolidAccelerationResidual:
    """``r^T M^-1 r`` of a :class:`SolidModel`'s residual (collective).

    Attributes:
        mass: the solid's mass [kg].
    """

    def __init__(self, model: SolidModel):
        self.comm = model.comm
        self.mass = float(model.solid.mass)
        if not self.mass > 0:
            raise ValueError(f"an acceleration residual needs a positive mass, got {self.mass!r} kg")
        self.held = np.asarray(model.constrained, dtype=np.int64)  # every rank's held DOFs
        matrix = model.solid.mass_matrix().tolil()
        matrix[self.held, :] = 0.0
        matrix[:, self.held] = 0.0
        matrix[self.held, self.held] = 1.0
        self._solve = scipy.sparse.linalg.factorized(scipy.sparse.csc_matrix(matrix))
        self.last = float("nan")

    def rms(self, residual) -> float:
        """Collective: ``a_rms`` [m/s^2] of a residual vector (a PETSc ``Vec`` of this rank's owned
        entries)."""
        self.last = float(np.sqrt(self.mass_norm_squared(residual.array_r) / self.mass))
        return self.last

    def mass_norm_squared(self, residual: np.ndarray) -> float:
        """Collective: ``r^T M^-1 r`` [N^2 / kg] of this rank's owned entries ``residual`` (the ranks'
        contiguous ranges in order)."""
        whole = np.concatenate(self.comm.allgather(np.asarray(residual, dtype=float)))
        whole[self.held] = 0.0
        return max(float(whole @ self._solve(whole)), 0.0)

    def close(self) -> None:
        """Nothing to release (scipy objects)."""

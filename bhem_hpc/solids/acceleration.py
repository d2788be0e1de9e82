"""The acceleration residual of a solid's time step (``solver.acceleration_tolerance``), as
:class:`~bhem_hpc.solver.acceleration.AccelerationResidual` gives a shell's: ``r^T M^-1 r`` with the
solid's lumped mass ``M`` (row sums of its consistent mass; its held DOFs' residual left out), so that
bodies of both kinds share one stopping test. The consistent mass of an SEM solid is singular (shape
matching has fewer modes than control points: rank 20 of 54 on a biquadratic cube), its row sums
positive. numpy only: a solid is small, its residual gathered on every rank."""

from __future__ import annotations

import numpy as np

from bhem_hpc.solids.model import SolidModel

#: The smallest lumped mass of a control point, as a fraction of the mean (a row sum need not be
#: positive for every shape matching).
MIN_LUMPED_FRACTION = 1e-6


class SolidAccelerationResidual:
    """``r^T M^-1 r`` of a :class:`SolidModel`'s residual with its lumped mass (collective).

    Attributes:
        mass: the solid's mass [kg].
    """

    def __init__(self, model: SolidModel):
        self.comm = model.comm
        self.mass = float(model.solid.mass)
        if not self.mass > 0:
            raise ValueError(f"an acceleration residual needs a positive mass, got {self.mass!r} kg")
        lumped = np.asarray(model.solid.mass_scalar.sum(axis=1)).ravel()
        lumped = np.maximum(lumped, MIN_LUMPED_FRACTION * lumped.mean())
        self.inverse_mass = np.repeat(1.0 / lumped, 3)  # per DOF, x y z of each control point
        self.held = np.asarray(model.constrained, dtype=np.int64)  # every rank's held DOFs
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
        return float(whole @ (self.inverse_mass * whole))

    def lower_bound_squared(self, residual: np.ndarray) -> float:
        """Collective: :meth:`mass_norm_squared` itself (the lumped mass needs no solve)."""
        return self.mass_norm_squared(residual)

    def close(self) -> None:
        """Nothing to release (numpy arrays)."""

"""The acceleration residual of a solid's time step (``solver.acceleration_tolerance``), as
:class:`~bhem_hpc.solver.acceleration.AccelerationResidual` gives a shell's: ``r^T M^-1 r`` with the
solid's lumped mass ``M`` (its held DOFs' residual left out), so that bodies of both kinds share one
stopping test. The consistent mass of an SEM solid is singular (shape matching has fewer modes than
control points: rank 20 of 54 on a biquadratic cube) and its row sums can be negative (70 of the
258 control points of the toy castle of ``jobs/toy-on-cloth.toml``), so the mass is lumped by
scaling its diagonal to the solid's mass (Hinton, Rock and Zienkiewicz 1976): positive wherever a
control point moves some mass. numpy only: a solid is small, its residual gathered on every rank."""

from __future__ import annotations

import numpy as np

from bhem_hpc.solids.model import SolidModel

#: The smallest lumped mass of a control point, as a fraction of the mean (a control point whose
#: shape matching moves no mass has a zero diagonal).
MIN_LUMPED_FRACTION = 1e-6


def lumped_masses(mass_scalar) -> np.ndarray:
    """``(n_q,)`` each control point's lumped mass [kg]: the consistent scalar mass's diagonal scaled
    to its total (HRZ lumping), at least :data:`MIN_LUMPED_FRACTION` of the mean."""
    diagonal = np.asarray(mass_scalar.diagonal(), dtype=float)
    lumped = diagonal * (float(mass_scalar.sum()) / diagonal.sum())
    return np.maximum(lumped, MIN_LUMPED_FRACTION * lumped.mean())


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
        self.inverse_mass = np.repeat(1.0 / lumped_masses(model.solid.mass_scalar), 3)  # x y z of each point
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

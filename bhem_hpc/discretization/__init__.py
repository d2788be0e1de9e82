"""Discretizations: the one owner of every DOF layout (surface data, flat entries, open and closed).

:mod:`.protocol` states what the model, solver, contact and output may ask of a discretization;
:mod:`.hermite` implements it with the bicubic Hermite element of :mod:`.element`.
"""

from bhem_hpc.discretization.hermite import HermiteDiscretization, shared_jacobian
from bhem_hpc.discretization.protocol import ConstrainedDofs, Discretization, DiscretizationError

__all__ = ["ConstrainedDofs", "Discretization", "DiscretizationError", "HermiteDiscretization", "shared_jacobian"]

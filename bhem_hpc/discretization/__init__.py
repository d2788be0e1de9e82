"""Discretizations: the one owner of every DOF layout (surface data, flat entries, open and closed).

:mod:`.protocol` states what the model, solver, contact and output may ask of a discretization;
:mod:`.hermite` implements it with the bicubic Hermite element of :mod:`.element`, :mod:`.bspline`
with B-splines of degree 2 and 3, :mod:`.rational` with rational ones; all sit on the knot-span
mesh of :mod:`.grid_mesh`.
"""

from __future__ import annotations

from mpi4py import MPI

from bhem_hpc.discretization.bspline import BSplineDiscretization
from bhem_hpc.discretization.grid_mesh import shared_jacobian
from bhem_hpc.discretization.hermite import HermiteDiscretization
from bhem_hpc.discretization.protocol import ConstrainedDofs, Discretization, DiscretizationError
from bhem_hpc.discretization.rational import RationalBSplineDiscretization
from bhem_hpc.geometry.bspline import BSplineSurface
from bhem_hpc.geometry.rational_bspline import RationalBSplineSurface
from bhem_hpc.geometry.surface import HermiteSurface

__all__ = [
    "BSplineDiscretization",
    "ConstrainedDofs",
    "Discretization",
    "DiscretizationError",
    "HermiteDiscretization",
    "RationalBSplineDiscretization",
    "create_discretization",
    "shared_jacobian",
]


def create_discretization(surface: HermiteSurface | BSplineSurface, comm: MPI.Comm) -> Discretization:
    """The discretization whose DOFs are the surface's data: Hermite nodal data or control points
    (with their weights for a rational surface)."""
    if isinstance(surface, RationalBSplineSurface):
        return RationalBSplineDiscretization(surface.grid, surface.degree, surface.weights, comm, surface.knots)
    if isinstance(surface, BSplineSurface):
        return BSplineDiscretization(surface.grid, surface.degree, comm)
    if isinstance(surface, HermiteSurface):
        return HermiteDiscretization(surface.grid, comm)
    raise DiscretizationError(f"no discretization for a {type(surface).__name__}")

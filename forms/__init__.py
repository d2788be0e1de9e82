"""UFL forms of the shell energies and loads, one term per module.

Every function is pure: it takes UFL objects (state ``x``, rest state ``x_rest``, material
constants, a measure with an explicit quadrature degree) and returns a UFL form. Nothing here
compiles, assembles or touches PETSc. Conventions: the mesh *is* the parameter domain, so
``x.dx(a)`` is dx/dxi_a; ``x`` is a 3-vector field.
"""

from bhem_hpc.forms.area_load import area_load_potential
from bhem_hpc.forms.baraff_witkin import baraff_witkin_energy, baraff_witkin_projected_hessian
from bhem_hpc.forms.bending import bending_energy, bending_pseudo_hessian
from bhem_hpc.forms.damping import mass_damping_potential, stiffness_damping_potential
from bhem_hpc.forms.edge_moment import edge_moment_work
from bhem_hpc.forms.gravity import gravity_potential
from bhem_hpc.forms.inertia import impulse_metric, inertia_potential, mass_matrix, total_mass
from bhem_hpc.forms.kinetic import kinetic_energy
from bhem_hpc.forms.line_load import line_load_work
from bhem_hpc.forms.membrane import membrane_energy, membrane_projected_hessian, membrane_stress
from bhem_hpc.forms.pressure import pressure_work
from bhem_hpc.forms.quadratic_bending import quadratic_bending_energy

__all__ = [
    "area_load_potential",
    "baraff_witkin_energy",
    "baraff_witkin_projected_hessian",
    "bending_energy",
    "bending_pseudo_hessian",
    "edge_moment_work",
    "gravity_potential",
    "impulse_metric",
    "inertia_potential",
    "mass_matrix",
    "total_mass",
    "kinetic_energy",
    "mass_damping_potential",
    "stiffness_damping_potential",
    "line_load_work",
    "membrane_energy",
    "membrane_projected_hessian",
    "membrane_stress",
    "pressure_work",
    "quadratic_bending_energy",
]

"""Kinetic energy (paper eq. 9), for reporting."""

from __future__ import annotations

import ufl

from bhem_hpc.forms.kinematics import area_density


def kinetic_energy(velocity, x_rest, density, thickness, dx: ufl.Measure) -> ufl.Form:
    """``int rho h / 2 |v|^2 dOmega_rest``."""
    return 0.5 * density * thickness * ufl.dot(velocity, velocity) * area_density(x_rest) * dx

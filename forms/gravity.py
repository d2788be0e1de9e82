"""Potential of gravity (a dead areal load ``rho h g``, paper §4.3)."""

from __future__ import annotations

import ufl

from bhem_hpc.forms.kinematics import area_density


def gravity_potential(x, x_rest, density, thickness, acceleration, dx: ufl.Measure) -> ufl.Form:
    """``-int rho h g . x dOmega_rest``; ``acceleration`` is a UFL 3-vector (e.g. (0, 0, -9.81))."""
    return -density * thickness * ufl.dot(acceleration, x) * area_density(x_rest) * dx

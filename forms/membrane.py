"""Membrane (stretching) energy of the Kirchhoff-Love St. Venant-Kirchhoff shell (eq. 7)."""

from __future__ import annotations

import ufl

from bhem_hpc.forms.kinematics import area_density, metric, plane_stress_lame, svk_density


def membrane_energy(x, x_rest, thickness, young, poisson, dx: ufl.Measure) -> ufl.Form:
    """``int h A_ab A_cd H^abcd dOmega_rest`` with membrane strain ``A = (a - a_rest) / 2``."""
    lmbda, mu = plane_stress_lame(young, poisson)
    a_rest = metric(x_rest)
    strain = 0.5 * (metric(x) - a_rest)
    return thickness * svk_density(strain, ufl.inv(a_rest), lmbda, mu) * area_density(x_rest) * dx

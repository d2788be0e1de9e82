"""Bending energy of the Kirchhoff-Love St. Venant-Kirchhoff shell (eq. 7) and its pseudo Hessian."""

from __future__ import annotations

import ufl

from bhem_hpc.forms.kinematics import (
    area_density,
    curvature,
    metric,
    plane_stress_lame,
    svk_bilinear,
    svk_density,
)


def _bending_strain(x, x_rest):
    return 0.5 * (curvature(x) - curvature(x_rest))


def bending_energy(x, x_rest, thickness, young, poisson, dx: ufl.Measure) -> ufl.Form:
    """``int h^3/3 B_ab B_cd H^abcd dOmega_rest`` with ``B = (b - b_rest) / 2``."""
    lmbda, mu = plane_stress_lame(young, poisson)
    strain = _bending_strain(x, x_rest)
    density = thickness**3 / 3 * svk_density(strain, ufl.inv(metric(x_rest)), lmbda, mu)
    return density * area_density(x_rest) * dx


def bending_pseudo_hessian(x, x_rest, thickness, young, poisson, dx: ufl.Measure, test, trial) -> ufl.Form:
    """The paper's pseudo Hessian of the bending energy (Appendix B).

    The exact Hessian is ``2 h^3/3 int (dB[v] H dB[w] + d2B[v, w] H B)``; the pseudo Hessian drops
    the second-derivative-of-curvature term ``d2B[v, w] H B`` and is positive semi-definite.
    """
    lmbda, mu = plane_stress_lame(young, poisson)
    strain = _bending_strain(x, x_rest)
    d_test = ufl.derivative(strain, x, test)
    d_trial = ufl.derivative(strain, x, trial)
    bilinear = svk_bilinear(d_test, d_trial, ufl.inv(metric(x_rest)), lmbda, mu)
    return 2 * thickness**3 / 3 * bilinear * area_density(x_rest) * dx

"""Inertia of implicit Euler written as an incremental potential (paper eqs. 20, 30)."""

from __future__ import annotations

import ufl

from bhem_hpc.forms.kinematics import area_density


def inertia_potential(x, x_predicted, x_rest, density, thickness, time_step, dx: ufl.Measure) -> ufl.Form:
    """``rho h / (2 dt^2) int |x - x_pred|^2 dOmega_rest`` with ``x_pred = x_n + dt v_n``.

    Its gradient ``M (x - x_n - dt v_n) / dt^2`` is the consistent-mass inertia force of implicit
    Euler (eq. 30): minimizing it plus the other potentials is one time step.
    """
    increment = x - x_predicted
    return density * thickness / (2 * time_step**2) * ufl.dot(increment, increment) * area_density(x_rest) * dx

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


def mass_matrix(trial, test, x_rest, density, thickness, dx: ufl.Measure) -> ufl.Form:
    """The consistent mass ``M``: ``rho h int u . w dOmega_rest`` (``dt^2`` times the inertia
    potential's Hessian)."""
    return density * thickness * ufl.dot(trial, test) * area_density(x_rest) * dx


def total_mass(x_rest, density, thickness, dx: ufl.Measure) -> ufl.Form:
    """``rho h int dOmega_rest``: the shell's mass [kg]."""
    return density * thickness * area_density(x_rest) * dx


def impulse_metric(trial, test, x_rest, density, thickness, patch_size, weights, dx: ufl.Measure) -> ufl.Form:
    """Metric of contact impulses: ``rho h int (m u . w + c sum_a h_a^2 u_,a . w_,a) dOmega_rest``,
    ``weights = (m, c)``.

    With ``m = 1, c = 0`` it is the consistent mass matrix. A point impulse through the bare mass
    matrix of C1 Hermite patches gives the L2-smallest velocity change: a spike narrower than a
    patch with huge derivative DOFs. The gradient term (parametric first derivatives scaled by the
    patch size ``(h1, h2)``) spreads it over about a patch; its Green's function is positive and
    decays monotonically, so stopping a set of points does not overshoot between them (a
    second-derivative term would: its kernel oscillates). It vanishes on rigid translations, so
    impulses still conserve linear momentum.
    """
    h = patch_size
    mass_weight, smoothing = weights
    gradient = sum(h[a] ** 2 * ufl.dot(ufl.grad(trial)[:, a], ufl.grad(test)[:, a]) for a in range(2))
    return density * thickness * (mass_weight * ufl.dot(trial, test) + smoothing * gradient) * area_density(x_rest) * dx

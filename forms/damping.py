"""Rayleigh damping as incremental potentials of an implicit Euler step.

With ``v = (x - x_n) / dt``, the damping force ``(alpha M + beta K(x_n)) v`` is the gradient of
``(x - x_n)^T (alpha M + beta K(x_n)) (x - x_n) / (2 dt)``; the stiffness is lagged at ``x_n``.
"""

from __future__ import annotations

import ufl
from ufl.algorithms.apply_algebra_lowering import apply_algebra_lowering
from ufl.algorithms.apply_derivatives import apply_derivatives

from bhem_hpc.forms.kinematics import area_density


def mass_damping_potential(
    x, x_previous, x_rest, density, thickness, coefficient, time_step, dx: ufl.Measure
) -> ufl.Form:
    """``alpha / (2 dt) (x - x_n)^T M (x - x_n)``; ``coefficient`` is alpha [1/s]."""
    increment = x - x_previous
    return (
        coefficient * density * thickness / (2 * time_step) * ufl.dot(increment, increment) * area_density(x_rest) * dx
    )


def stiffness_damping_potential(stiffness_at_previous: ufl.Form, x, x_previous, coefficient, time_step) -> ufl.Form:
    """``beta / (2 dt) (x - x_n)^T K(x_n) (x - x_n)``; ``coefficient`` is beta [s].

    ``stiffness_at_previous`` is the bilinear form of ``K(x_n)`` (the elastic Hessian, exact or
    positive semi-definite, written in terms of ``x_previous`` with a test and a trial function).
    UFL only differentiates in the direction of a Function or Argument, so the stiffness is formed
    with arguments, expanded, and then both arguments are replaced by ``x - x_n``.
    """
    test, trial = stiffness_at_previous.arguments()
    increment = x - x_previous
    expanded = apply_derivatives(apply_algebra_lowering(stiffness_at_previous))
    quadratic = ufl.replace(expanded, {test: increment, trial: increment})
    return coefficient / (2 * time_step) * quadratic

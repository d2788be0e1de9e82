"""Membrane (stretching) energy of the Kirchhoff-Love St. Venant-Kirchhoff shell (eq. 7) and its
projected Hessian."""

from __future__ import annotations

import ufl

from bhem_hpc.forms.kinematics import (
    area_density,
    metric,
    plane_stress_lame,
    positive_part_2x2,
    svk_bilinear,
    svk_density,
    unit_normal,
)


def _membrane_strain(x, x_rest):
    return 0.5 * (metric(x) - metric(x_rest))


def membrane_energy(x, x_rest, thickness, young, poisson, dx: ufl.Measure) -> ufl.Form:
    """``int h A_ab A_cd H^abcd dOmega_rest`` with membrane strain ``A = (a - a_rest) / 2``."""
    lmbda, mu = plane_stress_lame(young, poisson)
    strain = _membrane_strain(x, x_rest)
    return thickness * svk_density(strain, ufl.inv(metric(x_rest)), lmbda, mu) * area_density(x_rest) * dx


def membrane_stress(x, x_rest, young, poisson) -> ufl.core.expr.Expr:
    """The contravariant stress ``S^ab = d psi / d A_ab = lambda tr(a^-1 A) a^ab + 2 mu (a^-1 A a^-1)^ab``
    (2 x 2, indices of the parameter directions) of the density ``psi`` of :func:`membrane_energy`."""
    lmbda, mu = plane_stress_lame(young, poisson)
    inverse = ufl.inv(metric(x_rest))
    strain = _membrane_strain(x, x_rest)
    return lmbda * ufl.tr(inverse * strain) * inverse + 2 * mu * inverse * strain * inverse


def membrane_projected_hessian(
    x, x_rest, thickness, young, poisson, dx: ufl.Measure, test, trial, out_of_plane_only: bool = False
) -> ufl.Form:
    """A Hessian of :func:`membrane_energy` without the destabilizing part of compression.

    The exact Hessian is ``h int (2 dA[v] H dA[w] + S^ab v_,a . w_,b) dOmega_rest``: a material part,
    positive definite for every admissible Poisson ratio, and the geometric stiffness of the stress
    resultant ``S``, indefinite wherever the membrane is compressed (``S`` has a negative
    eigenvalue). The geometric term splits exactly into the tangential components of ``v_,a``,
    ``w_,b`` and their normal components ``n . v_,a``, ``n . w_,b`` (the material part sees no normal
    component). Compression's negative stiffness out of the plane is what makes cloth wrinkle.

    Args:
        out_of_plane_only: False: the positive part ``S+`` of ``S`` (closed form for 2 x 2) in both
            parts, which makes the Hessian positive semi-definite. True: ``S+`` out of the plane only,
            ``S`` in the plane (exact there): closer to the exact Hessian, so Newton converges faster
            where cloth is compressed, and positive definite unless the in-plane compression is
            large (a strain of order one), which the factorization's inertia tells.
    """
    lmbda, mu = plane_stress_lame(young, poisson)
    inverse = ufl.inv(metric(x_rest))
    strain = _membrane_strain(x, x_rest)
    d_test, d_trial = ufl.derivative(strain, x, test), ufl.derivative(strain, x, trial)
    material = 2 * svk_bilinear(d_test, d_trial, inverse, lmbda, mu)
    stress = membrane_stress(x, x_rest, young, poisson)
    tension = positive_part_2x2(stress)
    if not out_of_plane_only:
        geometric = sum(tension[a, b] * ufl.dot(test.dx(a), trial.dx(b)) for a in range(2) for b in range(2))
        return thickness * (material + geometric) * area_density(x_rest) * dx
    n = unit_normal(x)
    normal_test = [ufl.dot(n, test.dx(a)) for a in range(2)]
    normal_trial = [ufl.dot(n, trial.dx(a)) for a in range(2)]
    geometric = sum(
        stress[a, b] * (ufl.dot(test.dx(a), trial.dx(b)) - normal_test[a] * normal_trial[b])
        + tension[a, b] * normal_test[a] * normal_trial[b]
        for a in range(2)
        for b in range(2)
    )
    return thickness * (material + geometric) * area_density(x_rest) * dx

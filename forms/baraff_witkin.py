"""The FEM Baraff-Witkin membrane (Kim 2020, "A Finite Element Formulation of Baraff-Witkin Cloth"),
the B-spline cloth paper's membrane (§4.1), and its projected Hessian.

Warp and weft are the rest surface's parametric directions: ``u`` is the unit rest tangent along
``xi1`` and ``v`` the unit rest tangent orthogonal to it (Gram-Schmidt; along ``xi2`` on an
orthogonal grid). With the deformation gradient ``F`` of the mid-surface, ``F u`` and ``F v`` are the
current images of the yarn directions, and Kim's invariants are ``I5u = |F u|^2``, ``I5v = |F v|^2``
and ``I6 = (F u) . (F v)``. The energy per rest area is
``k / 2 ((sqrt(I5u) - 1)^2 + (sqrt(I5v) - 1)^2) + k_shear / 2 I6^2``: stretching of each yarn
family and shearing between them, with stiffnesses ``k`` and ``k_shear`` [N/m].
"""

from __future__ import annotations

import ufl

from bhem_hpc.forms.kinematics import area_density, metric


def yarn_directions(x, x_rest) -> tuple[ufl.core.expr.Expr, ufl.core.expr.Expr]:
    """``(F u, F v)``: the current images (3-vectors) of the unit warp and weft directions.

    ``u = A1 / |A1|``; ``v = (A2 - (A2 . u) u) / |...|`` in terms of the rest tangents ``A1, A2``;
    as combinations of the parametric directions, their images are the same combinations of the
    current tangents ``a1, a2`` (``F A_a = a_a``).
    """
    a_rest = metric(x_rest)
    length1 = ufl.sqrt(a_rest[0, 0])
    along = a_rest[0, 1] / length1  # A2 . u
    weft_length = ufl.sqrt(a_rest[1, 1] - along**2)
    warp = x.dx(0) / length1
    weft = (x.dx(1) - along * warp) / weft_length
    return warp, weft


def baraff_witkin_energy(x, x_rest, stretch_stiffness, shear_stiffness, dx: ufl.Measure) -> ufl.Form:
    """``int k/2 ((|Fu| - 1)^2 + (|Fv| - 1)^2) + k_shear/2 ((Fu).(Fv))^2 dOmega_rest``."""
    warp, weft = yarn_directions(x, x_rest)
    stretch = sum((ufl.sqrt(ufl.dot(d, d)) - 1) ** 2 for d in (warp, weft))
    shear = ufl.dot(warp, weft) ** 2
    return (0.5 * stretch_stiffness * stretch + 0.5 * shear_stiffness * shear) * area_density(x_rest) * dx


def baraff_witkin_projected_hessian(
    x, x_rest, stretch_stiffness, shear_stiffness, dx: ufl.Measure, test, trial
) -> ufl.Form:
    """A positive semi-definite Hessian of :func:`baraff_witkin_energy`, from Kim's closed-form
    eigen-analysis.

    Stretch along a yarn image ``d`` (length ``s``): its Hessian in ``d`` is
    ``k (d^ d^T + (1 - 1/s) (I - d^ d^T))``, whose transverse eigenvalue ``k (1 - 1/s)`` is negative
    under compression (``s < 1``) and is clamped at zero. Shear: ``k_shear (g g^T + I6 [[0, I], [I, 0]])``
    in ``(Fu, Fv)`` with ``g = (Fv, Fu)``; the second part has eigenvalues ``+-I6`` on ``(e, +-e)``
    and only its positive half ``|I6| / 2 (e + s e)(e + s e)^T``, ``s = sign(I6)``, is kept.
    """
    warp, weft = yarn_directions(x, x_rest)
    test_warp, test_weft = yarn_directions(test, x_rest)
    trial_warp, trial_weft = yarn_directions(trial, x_rest)
    stretch = 0
    for d, dv, dw in ((warp, test_warp, trial_warp), (weft, test_weft, trial_weft)):
        length = ufl.sqrt(ufl.dot(d, d))
        unit = d / length
        axial = ufl.dot(unit, dv) * ufl.dot(unit, dw)
        transverse = ufl.max_value(1 - 1 / length, 0) * (ufl.dot(dv, dw) - axial)
        stretch = stretch + axial + transverse
    invariant = ufl.dot(warp, weft)
    sign = ufl.sign(invariant)
    gauss_newton = (ufl.dot(weft, test_warp) + ufl.dot(warp, test_weft)) * (
        ufl.dot(weft, trial_warp) + ufl.dot(warp, trial_weft)
    )
    positive_half = 0.5 * abs(invariant) * ufl.dot(test_warp + sign * test_weft, trial_warp + sign * trial_weft)
    shear = gauss_newton + positive_half
    return (stretch_stiffness * stretch + shear_stiffness * shear) * area_density(x_rest) * dx

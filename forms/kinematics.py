"""Surface geometry of a UFL position field over the parameter domain (paper §3.1).

Helpers shared by the energy terms; each takes the position field ``x`` (a UFL 3-vector).
"""

from __future__ import annotations

import ufl


def tangents(x: ufl.core.expr.Expr) -> tuple[ufl.core.expr.Expr, ufl.core.expr.Expr]:
    """Covariant basis ``(a1, a2)`` = (dx/dxi1, dx/dxi2)."""
    return x.dx(0), x.dx(1)


def metric(x: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
    """First fundamental form ``a_ab = a_a . a_b`` as a 2x2 UFL matrix."""
    a1, a2 = tangents(x)
    return ufl.as_matrix([[ufl.dot(a1, a1), ufl.dot(a1, a2)], [ufl.dot(a2, a1), ufl.dot(a2, a2)]])


def area_normal(x: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
    """``a1 x a2``: normal scaled by the area density."""
    a1, a2 = tangents(x)
    return ufl.cross(a1, a2)


def area_density(x: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
    """``sqrt(a) = |a1 x a2|`` (paper eq. 12-13)."""
    n = area_normal(x)
    return ufl.sqrt(ufl.dot(n, n))


def unit_normal(x: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
    """``a3 = a1 x a2 / |a1 x a2|``."""
    return area_normal(x) / area_density(x)


def curvature(x: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
    """Second fundamental form ``b_ab = a_a,b . a3`` as a 2x2 UFL matrix."""
    n = unit_normal(x)
    return ufl.as_matrix([[ufl.dot(x.dx(a).dx(b), n) for b in range(2)] for a in range(2)])


def svk_density(strain: ufl.core.expr.Expr, metric_inverse: ufl.core.expr.Expr, lmbda, mu) -> ufl.core.expr.Expr:
    """``E_ab E_cd H^abcd`` with ``H = lambda/2 a^ab a^cd + mu a^bc a^ad`` (paper eq. 8)."""
    mixed = metric_inverse * strain
    return 0.5 * lmbda * ufl.tr(mixed) ** 2 + mu * ufl.tr(mixed * mixed)


def svk_bilinear(
    strain_a: ufl.core.expr.Expr, strain_b: ufl.core.expr.Expr, metric_inverse: ufl.core.expr.Expr, lmbda, mu
) -> ufl.core.expr.Expr:
    """The symmetric bilinear form ``A_ab H^abcd B_cd`` behind :func:`svk_density`."""
    ma = metric_inverse * strain_a
    mb = metric_inverse * strain_b
    return 0.5 * lmbda * ufl.tr(ma) * ufl.tr(mb) + mu * ufl.tr(ma * mb)


def positive_part_2x2(matrix: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
    """``S+ = (S + |S|) / 2`` of a symmetric 2 x 2 matrix: its eigenvalues clamped at zero.

    ``|S| = sqrt(S^2) = (S^2 + |det S| I) / (|s1| + |s2|)`` (the square root of a 2 x 2 matrix by
    Cayley-Hamilton), with ``|s1| + |s2| = sqrt(tr(S^2) + 2 |det S|)``: no eigenvectors, no branch.
    The smallest normal double in the denominator makes ``S = 0`` give ``S+ = 0``.
    """
    square = matrix * matrix
    determinant = abs(ufl.det(matrix))
    spread = ufl.sqrt(ufl.tr(square) + 2 * determinant) + 2.2250738585072014e-308
    absolute = (square + determinant * ufl.Identity(2)) / spread
    return 0.5 * (matrix + absolute)


def plane_stress_lame(young, poisson) -> tuple[ufl.core.expr.Expr, ufl.core.expr.Expr]:
    """Lame parameters of the paper: ``lambda = Y nu / (1 - nu^2)``, ``mu = Y / (2 (1 + nu))``."""
    return young * poisson / (1 - poisson**2), young / (2 * (1 + poisson))

"""The quadratic bending energy (Bergou et al. 2006) of the B-spline cloth paper (§4.2, eqs. 13-15).

For a flat rest surface and nearly isometric deformations, twice the mean curvature normal is the
rest surface's Laplace-Beltrami operator applied to the position, ``Delta x = 2 H n``, which is
linear in ``x``: the energy ``D / 2 int |Delta x|^2 dOmega_rest`` is quadratic, its Hessian constant
and positive semi-definite, and its bending forces linear. In the parameters (eq. 15),
``Delta x = 1 / sqrt(A) d_a (sqrt(A) A^ab d_b x)``; on a flat rest surface with an affine
parametrization (the project's rectangles) ``sqrt(A)`` and ``A^ab`` are constant, and
``Delta x = A^ab x_,ab``, which is what is integrated.
"""

from __future__ import annotations

import ufl

from bhem_hpc.forms.kinematics import area_density, metric


def laplace_beltrami(x, x_rest) -> ufl.core.expr.Expr:
    """``A^ab x_,ab``: the rest surface's Laplace-Beltrami operator on a 3-vector field (affine flat
    rest parametrization, where the first-derivative terms of eq. 15 vanish)."""
    inverse = ufl.inv(metric(x_rest))
    return sum(inverse[a, b] * x.dx(a).dx(b) for a in range(2) for b in range(2))


def quadratic_bending_energy(x, x_rest, bending_stiffness, dx: ufl.Measure) -> ufl.Form:
    """``D / 2 int |Delta x|^2 dOmega_rest`` with ``D = Y h^3 / (12 (1 - nu^2))``."""
    laplacian = laplace_beltrami(x, x_rest)
    return 0.5 * bending_stiffness * ufl.dot(laplacian, laplacian) * area_density(x_rest) * dx
